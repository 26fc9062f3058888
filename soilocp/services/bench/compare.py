"""``soilocp bench --compare BASE.json``: every figure of a bench report next to a baseline's.

A report (the JSON of ``soilocp bench --json``) is flattened into named figures, each with the
direction that is better (lower latency, higher replay rate ...).  The comparison gives base,
now, the ratio now / base and the gain (> 1 is better whatever the direction), so every
optimisation is shown as a ratio measured by one command against a report kept in the repository
(``scripts/baselines/bench-full.json``).  Figures missing on either side are listed with "-".
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional

from soilocp.model.files import read_json

LOWER, HIGHER = "lower", "higher"
#: the processes of a pipeline (the bench process and the ping-pong echo are not part of it)
NOT_PIPELINE = ("bench", "echo")


def _num(x: Any) -> Optional[float]:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def pipeline_rss_mib(processes: dict[str, Any], field: str = "rss_mib") -> Optional[float]:
    """Resident memory of a pipeline's processes (router + services) in all, MiB (``field``
    "pss_mib": proportional set size, shared pages counted once)."""
    vals = [_num(v.get(field)) for n, v in processes.items() if n not in NOT_PIPELINE]
    vals = [v for v in vals if v is not None]
    return sum(vals) if vals else None


def figures(report: dict[str, Any]) -> dict[str, tuple[Optional[float], str]]:
    """Named figures of a report: name -> (value or None, which direction is better)."""
    out: dict[str, tuple[Optional[float], str]] = {}
    for name, st in (report.get("stages") or {}).items():
        out[f"stage {name} CPU median, us"] = (_num(st.get("cpu_p50")), LOWER)
        out[f"stage {name} wall median, us"] = (_num(st.get("p50")), LOWER)
    rp = report.get("replay") or {}
    out["offline replay, x real time (wall)"] = (_num(rp.get("x_real_time")), HIGHER)
    out["offline replay, x real time (per CPU s)"] = (_num(rp.get("x_real_time_cpu")), HIGHER)
    for n, st in (report.get("batch_stages") or {}).items():
        out[f"batched step, {n} vehicles, CPU median per vehicle-sample, us"] = (_num(st.get("cpu_p50")), LOWER)
        out[f"estimation math (normal forces + chain call), {n} vehicles, CPU median per vehicle-sample, us"] = (
            _num(st.get("math_cpu_p50")), LOWER)
    for row in report.get("latency") or []:
        tag = f"{row['pipeline']} {row['rate_hz']:.0f} Hz"
        r = row.get("result") or {}
        for k in ("p50", "p99"):
            out[f"latency {tag} {k}, ms"] = (_num(r.get(k)), LOWER)
        out[f"latency {tag} drops"] = (_num(r.get("drops")), LOWER)
        out[f"ping-pong {tag} p50, ms"] = (_num((row.get("baseline") or {}).get("p50")), LOWER)
        if row["rate_hz"] == 100.0:
            procs = row.get("processes") or {}
            out[f"RSS {row['pipeline']} router + services, MiB"] = (pipeline_rss_mib(procs), LOWER)
            out[f"PSS {row['pipeline']} router + services, MiB"] = (pipeline_rss_mib(procs, "pss_mib"), LOWER)
    cl = report.get("control_loop") or {}
    if "error" not in cl:
        out["control loop p50, ms"] = (_num(cl.get("p50")), LOWER)
        out["control loop p99, ms"] = (_num(cl.get("p99")), LOWER)
    for pipe, sc in (report.get("scale") or {}).items():
        out[f"scale {pipe}: vehicles x 100 Hz passing"] = (_num(sc.get("max_vehicles")), HIGHER)
        out[f"scale {pipe}: vehicles x 100 Hz without a drop"] = (_num(sc.get("max_vehicles_no_drop")), HIGHER)
    return out


def compare(base: dict[str, Any], now: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per figure of either report: base, now, ratio now/base and gain (> 1 = better)."""
    fb, fn = figures(base), figures(now)
    rows = []
    for name in list(fn) + [n for n in fb if n not in fn]:
        b, better = fb.get(name, (None, fn.get(name, (None, LOWER))[1]))
        v = fn.get(name, (None, better))[0]
        ratio = gain = None
        if b is not None and v is not None:
            if b != 0:
                ratio = v / b
            if better == LOWER and v != 0:
                gain = b / v
            elif better == HIGHER and b != 0:
                gain = v / b
        rows.append({"figure": name, "better": better, "base": b, "now": v, "ratio": ratio, "gain": gain})
    return rows


def load_report(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    data = read_json(p, "baseline")
    if not isinstance(data, dict) or "stages" not in data or "machine" not in data:
        raise ValueError(f"baseline {str(p)!r} is not a bench report (no 'stages' / 'machine'): "
                         "write one with `soilocp bench --json FILE`")
    return data


def render_compare(rows: list[dict[str, Any]], console, base_label: str) -> None:
    from rich.table import Table

    def f(x, spec=".3g"):
        return "-" if x is None else format(x, spec)

    t = Table(title=f"before / after: this run against {base_label} (gain > 1 = better; ratio = now / base)",
              title_justify="left")
    for c in ("figure", "better", "base", "now", "ratio", "gain"):
        t.add_column(c, justify="left" if c in ("figure", "better") else "right", no_wrap=c != "figure")
    for r in rows:
        t.add_row(r["figure"], r["better"], f(r["base"]), f(r["now"]), f(r["ratio"], ".2f"), f(r["gain"], ".2f"))
    console.print(t)
