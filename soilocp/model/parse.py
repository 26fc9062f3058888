"""Numbers read from text (CSV cells, query parameters) with errors that say where (no numpy:
the gateway and the OCP service import it)."""

from __future__ import annotations

import math


def parse_finite(text: str, where: str) -> float:
    """``text`` as a finite float; ValueError ``"<where>: '<text>' is not a (finite) number"``."""
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{where}: {text!r} is not a finite number")
    return v
