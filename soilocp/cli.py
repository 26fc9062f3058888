"""The ``soilocp`` console command.

Each area registers its subcommands from its own module (listed in ``COMMAND_MODULES``), so the
pure library never imports Zenoh: the service commands import it only when they run.
"""

from __future__ import annotations

import importlib
import sys

import click

from soilocp import __version__

# module path -> attribute holding a list of click commands
COMMAND_MODULES = (
    "soilocp.commands.physics",  # ocp, curves, calibrate
    "soilocp.commands.sim",  # simulate
    "soilocp.commands.offline",  # estimate, evaluate, plot
    "soilocp.commands.control",  # control compare
    "soilocp.commands.io",  # import (ROS 2 bags, CSV logs)
    "services.commands",  # service, router, run, schemas, fleet, dashboard, bench
)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="soilocp")
def main() -> None:
    """Soil strength K and optimal control parameters (mu_T, S_T, S_E) for wheeled robots."""


#: The long-running processes of a deployment load only the services area's commands: the other
#: areas' imports would otherwise sit in the memory of each of the six processes (issue 11).
PROCESS_COMMANDS = ("service", "router")


def _register() -> None:
    light = len(sys.argv) > 1 and sys.argv[1] in PROCESS_COMMANDS
    for modname in ("services.commands",) if light else COMMAND_MODULES:
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name == modname:  # area not built (yet); anything else is a real error
                continue
            raise
        for cmd in getattr(mod, "COMMANDS", ()):
            main.add_command(cmd)


_register()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
