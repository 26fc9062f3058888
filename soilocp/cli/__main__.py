"""``python -m soilocp.cli``: the ``soilocp`` command (how every spawned process starts)."""

from soilocp.cli.entry import run

run()
