"""The whole ``soilocp`` command: every area's commands, registered by plain imports.

The long-running processes (``soilocp service NAME``, ``soilocp router``) start through
:mod:`soilocp.cli.process` instead (``soilocp.cli.entry`` chooses), so that the six processes of a
deployment do not carry the offline tools' imports (each process's resident memory).
"""

from __future__ import annotations

import sys

import click

from soilocp.services import commands as services_commands
from soilocp.services.bench import run as bench_commands
from soilocp.services.fleet import commands as fleet_commands
from soilocp.services.io import foxglove_live as foxglove_commands
from soilocp.services.io import record as record_commands
from soilocp.services.map import commands as map_commands
from soilocp.services.security import commands as certs_commands
from soilocp import __version__
from soilocp.commands import control, io, offline, physics, sim

AREAS = (
    physics,  # ocp, curves, calibrate, calibrate-torque
    sim,  # simulate
    offline,  # estimate, evaluate, plot, accuracy
    control,  # control compare
    io,  # import (ROS 2 bags, CSV logs)
    services_commands,  # run, schemas (+ service, router below)
    fleet_commands,  # fleet, dashboard
    bench_commands,  # bench
    record_commands,  # record
    foxglove_commands,  # foxglove
    certs_commands,  # certs
    map_commands,  # map (query, export); the service is `soilocp service map`
)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="soilocp")
def main() -> None:
    """Soil strength K and optimal control parameters (mu_T, S_T, S_E) for wheeled robots."""


for _area in AREAS:
    for _cmd in _area.COMMANDS:
        main.add_command(_cmd)
for _cmd in services_commands.PROCESS_COMMANDS:
    main.add_command(_cmd)

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
