"""What every bench report is made of and written as: the machine it ran on, its figures as text, its JSON
(strict: an empty statistic is null) and the console it prints to."""

from __future__ import annotations

import json
import math
import os
import platform
import sys
from pathlib import Path
from typing import Any


def machine_info() -> dict[str, Any]:
    """The machine a report was measured on: CPUs, their model, the load, Python and Zenoh versions."""
    model = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        from importlib.metadata import version

        zv = version("eclipse-zenoh")
    except Exception:  # pragma: no cover - not installed as a distribution
        zv = None
    return {"nproc": os.cpu_count(), "cpu_model": model, "load_start": list(os.getloadavg()),
            "python": platform.python_version(), "zenoh": zv, "platform": platform.platform()}


def fmt(x: Any, spec: str = ".2f") -> str:
    """``x`` formatted by ``spec``; "-" for none or a non-finite number."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def json_safe(obj: Any) -> Any:
    """The report with NaN / inf (an empty statistic) as null: strict JSON for other tools."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def write_report(report: dict[str, Any], path: str, console=None) -> None:
    """The report as strict JSON (:func:`json_safe`) at ``path``; said on ``console`` when given."""
    Path(path).write_text(json.dumps(json_safe(report), indent=1, allow_nan=False))
    if console is not None:
        console.print(f"report written to {path}")


def console():
    """The console the bench prints to: 200 columns when the output is not a terminal (a log, a pipe)."""
    from rich.console import Console

    return Console(width=200) if not sys.stdout.isatty() else Console()
