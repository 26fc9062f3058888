"""Reading the product's JSON and JSON Lines files (vehicle, constants, pipeline config, bench
reports, logs) with errors that name the file, the line and the reason."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def read_json(path: str | Path, what: str) -> Any:
    """The parsed contents of JSON file ``path``.  ValueError ``"<what> '<path>' does not exist"``
    or ``"... is not valid JSON: <why>"``."""
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ValueError(f"{what} {str(p)!r} does not exist") from exc
    except json.JSONDecodeError as exc:
        raise ValueError(f"{what} {str(p)!r} is not valid JSON: {exc}") from exc


def read_jsonl(path: str | Path) -> list[Any]:
    """Every non-blank line of JSON Lines file ``path``, parsed; ValueError ``"<path>:<line>: not
    valid JSON: <why>"`` on the first bad line."""
    out = []
    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, 1):
            if line.strip():
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError as exc:
                    raise ValueError(f"{path}:{lineno}: not valid JSON: {exc}") from None
    return out
