"""Writes soilocp/schemas/codes.json, the records' statuses and reason codes as the compiled core
defines them (soilocp/_core/src/codes.rs, ``soilocp._core.status_codes()`` and ``reason_codes()``).

``python -m soilocp.cli.generate_codes`` rewrites the file; ``--check`` writes nothing and exits 1
when the committed file differs from the core's tables (tests/test_codes.py runs the same check).
The schemas (:mod:`soilocp.schemas.codes`) read the file rather than the core itself: the message
contracts load in processes that do not load the compiled core (the gateway).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

TARGET = Path(__file__).resolve().parents[1] / "schemas" / "codes.json"
REGENERATE = "python -m soilocp.cli.generate_codes"


def _table(rows) -> list[str]:
    """A table's rows, [name, who sets it, meaning], one line each."""
    return [f"    {json.dumps([code, set_by, meaning])}" for code, set_by, meaning in rows]


def render() -> str:
    """The file's text, from the core's tables: {"statuses": rows, "reasons": rows}, in code order."""
    from soilocp import _core

    tables = [(name, ",\n".join(_table(rows))) for name, rows in
              (("statuses", _core.status_codes()), ("reasons", _core.reason_codes()))]
    return "{\n" + ",\n".join(f'  "{name}": [\n{rows}\n  ]' for name, rows in tables) + "\n}\n"


@click.command()
@click.option("--check", is_flag=True, help="Write nothing; exit 1 when the file differs from the core's tables.")
def main(check: bool) -> None:
    text = render()
    if check:
        if TARGET.read_text() != text:
            click.echo(f"{TARGET} differs from the core's tables: run {REGENERATE}", err=True)
            sys.exit(1)
        return
    TARGET.write_text(text)
    click.echo(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
