"""The console script ``soilocp`` and ``python -m soilocp_cli``: the lean command set for the
long-running processes, the whole one otherwise."""

from __future__ import annotations

import sys

PROCESS_COMMAND_NAMES = ("service", "router")


def run() -> None:
    if len(sys.argv) > 1 and sys.argv[1] in PROCESS_COMMAND_NAMES:
        from soilocp_cli.process import main
    else:
        from soilocp_cli.main import main
    main(prog_name="soilocp")
