"""The lean ``soilocp`` of the long-running processes: only ``service`` and ``router``.

Loaded by :func:`soilocp.cli.entry.run` when the first argument is one of them, so that each of a
deployment's six processes imports only what it runs (the full command set adds up to ~20 MiB per
process).
"""

from __future__ import annotations

import click

from soilocp.services.commands import PROCESS_COMMANDS
from soilocp import __version__


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="soilocp")
def main() -> None:
    """Soil strength K and optimal control parameters: the long-running processes."""


for _cmd in PROCESS_COMMANDS:
    main.add_command(_cmd)
