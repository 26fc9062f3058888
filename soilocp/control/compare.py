"""``soilocp control compare``: every controller on every closed-loop scenario; table, JSON, plots.

JSON shape (the issue's contract; extra keys allowed)::

    {"scenarios": [{"name": "drawbar-sand", "description": ..., "controllers": {
        "speed": {"drawbar_pull_n": ..., "energy_per_m_j": ..., "max_grade_deg": ..., "distance_m": ...,
                  "duration_s": ..., "estimate_share": ..., "k_error_median": ...}, ...}}],
     "gains": {...}, "fallback": {...}}

``estimate_share`` is the fraction of samples whose set-point came from the live estimate (not
the fallback); ``k_error_median`` the median |K_est / K_true - 1| of the chain while it had a K.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable, Optional, Sequence

from soilocp.control.controllers import CONTROLLER_NAMES
from soilocp.control.loop import DEFAULT_GAINS
from soilocp.control.rig import RIG_SCENARIOS, Trace, get_rig_scenario, run_closed_loop
from soilocp.control.setpoints import fallback_slip

METRICS = ("drawbar_pull_n", "energy_per_m_j", "max_grade_deg", "distance_m")


def compare(scenarios: Optional[Sequence[str]] = None, controllers: Sequence[str] = CONTROLLER_NAMES, *,
            seed: int = 0, duration: Optional[float] = None,
            progress: Optional[Callable[[str, str], None]] = None) -> tuple[dict, dict[str, dict[str, Trace]]]:
    """Run the comparison; returns (the JSON document, traces by scenario and controller)."""
    names = list(scenarios) if scenarios else list(RIG_SCENARIOS)
    rigs = [get_rig_scenario(n) for n in names]  # every name checked before anything runs
    doc: dict = {"scenarios": [], "gains": dataclasses.asdict(DEFAULT_GAINS),
                 "fallback": {"S_T": fallback_slip("S_T"), "S_E": fallback_slip("S_E")}}
    traces: dict[str, dict[str, Trace]] = {}
    for rig in rigs:
        entry = {"name": rig.name, "description": rig.description, "kind": rig.kind, "controllers": {}}
        traces[rig.name] = {}
        for c in controllers:
            if progress:
                progress(rig.name, c)
            scores, tr = run_closed_loop(rig, c, seed=seed, duration=duration)
            entry["controllers"][c] = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                       for k, v in scores.items()}
            traces[rig.name][c] = tr
        doc["scenarios"].append(entry)
    return doc, traces


def gains_over_fixed(entry: dict) -> dict[str, Optional[float]]:
    """Relative gain of the OCP controllers over the best fixed baseline, by the scenario's metric:
    pull (drawbar), max grade (climb), energy per metre (drive; > 0 = less energy)."""
    ctl = entry["controllers"]
    fixed = [c for c in ctl if c.startswith("fixed_")]
    out: dict[str, Optional[float]] = {}
    if not fixed:
        return out
    metric = {"drawbar": "drawbar_pull_n", "climb": "max_grade_deg", "drive": "energy_per_m_j"}[entry["kind"]]
    vals = [ctl[c][metric] for c in fixed if ctl[c][metric] is not None]
    if not vals:
        return out
    best = min(vals) if metric == "energy_per_m_j" else max(vals)
    for c in ("ocp_traction", "ocp_efficiency"):
        if c in ctl and ctl[c][metric] is not None and best:
            v = ctl[c][metric]
            out[c] = (best - v) / best if metric == "energy_per_m_j" else (v - best) / best
    return out


def table_rows(doc: dict) -> list[list[str]]:
    """Rows: scenario, controller, pull N, energy J/m, max grade deg, distance m, estimate share, K error."""
    rows = []
    for entry in doc["scenarios"]:
        for c, m in entry["controllers"].items():
            f = lambda k, spec: "-" if m.get(k) is None else format(m[k], spec)  # noqa: E731
            rows.append([entry["name"], c, f("drawbar_pull_n", ".1f"), f("energy_per_m_j", ".1f"),
                         f("max_grade_deg", ".1f"), f("distance_m", ".1f"), f("estimate_share", ".2f"),
                         "-" if m.get("k_error_median") is None else f"{100 * m['k_error_median']:.1f} %"])
    return rows


TABLE_HEADER = ["scenario", "controller", "pull N", "energy J/m", "max grade deg", "distance m", "on estimate",
                "K med err"]


def markdown_table(doc: dict) -> str:
    lines = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "---|" * len(TABLE_HEADER)]
    lines += ["| " + " | ".join(r) + " |" for r in table_rows(doc)]
    return "\n".join(lines)


def plot_traces(traces: dict[str, dict[str, Trace]], out_dir: str | Path) -> list[Path]:
    """One PNG per scenario: slip, set-point, K estimate (and truth) and pull against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, by_ctl in traces.items():
        fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
        for c, tr in by_ctl.items():
            t = np.asarray(tr.t)
            line, = axes[0].plot(t, tr.slip, lw=0.8, label=c)
            axes[1].plot(t, tr.setpoint, lw=1.0, color=line.get_color(), label=c)
            axes[2].plot(t, tr.k_est, lw=0.8, color=line.get_color(), label=c)
            axes[3].plot(t, tr.pull, lw=0.8, color=line.get_color(), label=c)
        first = next(iter(by_ctl.values()), None)
        if first is not None:
            axes[2].plot(first.t, first.k_true, "k--", lw=1.0, label="true K")
        axes[0].set_ylabel("slip (mean of 4)")
        axes[0].set_ylim(-0.1, 1.0)
        axes[1].set_ylabel("slip set-point")
        axes[2].set_ylabel("K estimate")
        axes[3].set_ylabel("pull sum(mu Fz), N")
        axes[3].set_xlabel("time, s")
        axes[0].set_title(f"{name}: closed loop, estimation chain in the loop")
        axes[0].legend(fontsize=7, ncol=3)
        axes[2].legend(fontsize=7, ncol=3)
        for ax in axes:
            ax.grid(alpha=0.3)
        fig.tight_layout()
        p = out / f"control-{name}.png"
        fig.savefig(p, dpi=90)
        plt.close(fig)
        paths.append(p)
    return paths
