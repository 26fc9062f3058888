"""The fleet soil map service (``soilocp service map``): a thin Zenoh adapter around
:mod:`soilocp.map`.  docs/map.md."""
