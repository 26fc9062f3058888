"""Reading the product's JSON files (vehicle, constants, pipeline config, bench reports) with
errors that name the file and the reason."""

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
