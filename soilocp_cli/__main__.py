"""``python -m soilocp_cli``: the ``soilocp`` command (how every spawned process starts)."""

from soilocp_cli.entry import run

run()
