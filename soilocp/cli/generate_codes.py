"""Writes :mod:`soilocp.schemas.codes`, the records' statuses and reason codes as the compiled core
defines them (soilocp/_core/src/codes.rs, ``soilocp._core.status_codes()`` and ``reason_codes()``).

``python -m soilocp.cli.generate_codes`` rewrites the module; ``--check`` writes nothing and exits 1
when the committed module differs from the core's tables (tests/test_codes.py runs the same check).
The schemas read the generated module rather than the core itself: the message contracts load in
processes that do not load the compiled core (the gateway).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

TARGET = Path(__file__).resolve().parents[1] / "schemas" / "codes.py"
REGENERATE = "python -m soilocp.cli.generate_codes"


def _table(name: str, rows) -> list[str]:
    lines = [f"{name}: dict[str, tuple[str, str]] = {{"]
    for code, set_by, meaning in rows:
        lines.append(f"    {code!r}: ({set_by!r}, {meaning!r}),")
    return lines + ["}"]


def render() -> str:
    """The module's text, from the core's tables."""
    from soilocp import _core

    head = [
        '"""The statuses and reason codes of a soil / OCP record: name -> (who sets it, its meaning), in code',
        "order.  Generated from the compiled core's tables (soilocp/_core/src/codes.rs) by",
        f"``{REGENERATE}``: do not edit by hand (tests/test_codes.py fails when this module and",
        'the core differ).  Who sets it: "soil" (the soil stage), "publisher" (the live publisher), "ocp" (the',
        'OCP stage)."""',
        "",
        "from __future__ import annotations",
        "",
    ]
    body = _table("STATUSES", _core.status_codes()) + [""] + _table("REASONS", _core.reason_codes())
    return "\n".join(head + body) + "\n"


@click.command()
@click.option("--check", is_flag=True, help="Write nothing; exit 1 when the module differs from the core's tables.")
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
