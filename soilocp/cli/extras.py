"""Which extra a missing optional dependency belongs to, and the message that says how to install it.

The core install runs estimation, import and the services; plots, the fleet soil map, Foxglove, the
dashboard, certificates and DataFrames are extras (pyproject.toml).  A command that reaches for one
that is not installed gets a one-line message naming the extra, not a traceback.
"""

from __future__ import annotations

from typing import Optional

#: top-level module -> (extra, what it is for)
EXTRA_OF: dict[str, tuple[str, str]] = {
    "matplotlib": ("plot", "PNG plots"),
    "h3": ("map", "the fleet soil map's WGS84 cells"),
    "psycopg": ("map", "the fleet soil map's PostgreSQL store"),
    "foxglove": ("foxglove", "Foxglove channels"),
    "starlette": ("dashboard", "the dashboard"),
    "uvicorn": ("dashboard", "the dashboard"),
    "cryptography": ("certs", "certificates"),
    "pandas": ("pandas", "DataFrames"),
}


def missing_extra(exc: BaseException) -> Optional[str]:
    """The install hint for ``exc`` when it is a missing optional dependency (None otherwise)."""
    if not isinstance(exc, ModuleNotFoundError) or not exc.name:
        return None
    top = exc.name.split(".")[0]
    hit = EXTRA_OF.get(top)
    if hit is None:
        return None
    extra, what = hit
    return (f"this needs {what}, from the optional dependency {top!r}, which is not installed: "
            f"pip install 'soilocp[{extra}]' (or 'soilocp[all]')")
