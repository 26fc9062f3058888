"""The console script ``soilocp`` and ``python -m soilocp.cli``: the lean command set for the
long-running processes, the whole one otherwise."""

from __future__ import annotations

import sys

import click

PROCESS_COMMAND_NAMES = ("service", "router")


def command_group(args: list[str]) -> click.Group:
    """The group that serves ``args`` (the command line without the program name)."""
    if args[:2] == ["service", "map"]:  # the fleet soil map service: its own options (docs/map.md)
        from soilocp.services.map.commands import process_main as main
    elif args[:1] == ["router"]:  # forwards bytes only: no pydantic, no message models
        from soilocp.services.router import process_main as main
    elif args and args[0] in PROCESS_COMMAND_NAMES:
        from soilocp.cli.process import main
    else:
        from soilocp.cli.main import main
    return main


def run() -> None:
    """Run the command line; a missing optional dependency ends it with the extra to install (exit 1)."""
    try:
        command_group(sys.argv[1:])(prog_name="soilocp")
    except ModuleNotFoundError as exc:
        from soilocp.cli.extras import missing_extra

        hint = missing_extra(exc)
        if hint is None:
            raise
        name = " ".join(a for a in sys.argv[1:3] if not a.startswith("-"))
        print(f"soilocp {name}: error: {hint}", file=sys.stderr, flush=True)
        sys.exit(1)
