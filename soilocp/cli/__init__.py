"""The composition root: the ``soilocp`` command line, wired by plain imports from the library's
command modules (``soilocp.commands``) and the services' (``services``).  Nothing below imports it."""
