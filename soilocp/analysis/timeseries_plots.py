"""Time-series PNGs of a drive, like the paper's Figs. 8-18: normal forces, slip, traction
coefficient (with / without motion-resistance compensation), soil strength K with its
uncertainty against the soil classes, and the OCPs; estimate against truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from soilocp.model.constants import REFERENCE_SOILS  # noqa: E402

WHEELS = ("1 LR", "2 LF", "3 RF", "4 RR")


def _read(path) -> list[dict]:
    with open(path, encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]


def _col(recs, key, width=None):
    vals = []
    for r in recs:
        v = r.get(key)
        if v is None:
            vals.append([np.nan] * width if width else np.nan)
        else:
            vals.append(v)
    return np.array(vals, dtype=float)


def plot_run(truth_path: Optional[str], estimate_paths: list[str], labels: Optional[list[str]], out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    truth = _read(truth_path) if truth_path else None
    runs = [_read(p) for p in estimate_paths]
    labels = labels or [Path(p).stem for p in estimate_paths]
    written: list[Path] = []

    def save(fig, name):
        p = out / name
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        written.append(p)

    t_est = [_col(r, "stamp") for r in runs]
    tt = _col(truth, "stamp") if truth else None

    # Fig. 8: normal forces (estimated when the records carry them, else truth)
    fig, ax = plt.subplots(figsize=(9, 4))
    for i, w in enumerate(WHEELS):
        if truth:
            ax.plot(tt, _col(truth, "normal_force", 4)[:, i], lw=1, label=f"truth {w}")
        if runs and "normal_force" in runs[0][0]:
            ax.plot(t_est[0], _col(runs[0], "normal_force", 4)[:, i], lw=0.6, ls="--", label=f"estimated {w}")
    ax.set(xlabel="time (s)", ylabel="normal force F_z (N)", title="Normal forces (eqs. 16-25, zero-warp)")
    ax.legend(ncol=2, fontsize=7)
    save(fig, "normal_forces.png")

    # Fig. 9: slip
    fig, ax = plt.subplots(figsize=(9, 4))
    for i, w in enumerate(WHEELS):
        ax.plot(t_est[0], _col(runs[0], "slip", 4)[:, i], lw=0.8, label=f"estimated {w}")
        if truth:
            ax.plot(tt, _col(truth, "slip", 4)[:, i], lw=0.6, ls=":", color="k")
    ax.set(xlabel="time (s)", ylabel="slip ratio S (-)", title="Slip ratio per wheel (eq. 1); dotted: truth")
    ax.legend(ncol=4, fontsize=7)
    save(fig, "slip.png")

    # Figs. 10-11: mu per wheel, each run (e.g. with / without compensation)
    fig, axes = plt.subplots(len(runs), 1, figsize=(9, 3.2 * len(runs)), squeeze=False)
    for ax, recs, t, lab in zip(axes[:, 0], runs, t_est, labels):
        for i, w in enumerate(WHEELS):
            ax.plot(t, _col(recs, "mu", 4)[:, i], lw=0.8, label=f"estimated {w}")
            if truth:
                ax.plot(tt, _col(truth, "mu", 4)[:, i], lw=0.6, ls=":", color="k")
        ax.set(xlabel="time (s)", ylabel="traction coefficient mu (-)", title=f"Net traction coefficient: {lab}; dotted: truth")
        ax.legend(ncol=4, fontsize=7)
    save(fig, "traction_coefficient.png")

    # Figs. 12-13, 15: K with uncertainty, against the soil classes
    fig, ax = plt.subplots(figsize=(9, 4.2))
    for name, k in REFERENCE_SOILS.items():
        ax.axhline(k, color="0.85", lw=0.8)
        ax.text(0.0, k, f" {name}", va="bottom", fontsize=7, color="0.4", transform=ax.get_yaxis_transform())
    for recs, t, lab in zip(runs, t_est, labels):
        k = _col(recs, "soil_strength")
        s = _col(recs, "soil_strength_std")
        line, = ax.plot(t, k, lw=1.1, label=f"estimated K: {lab}")
        ax.fill_between(t, np.maximum(k - s, 1), k + s, color=line.get_color(), alpha=0.2, lw=0)
    if truth:
        ax.plot(tt, _col(truth, "soil_strength"), color="k", lw=1.2, ls="--", label="truth")
    ax.set_yscale("log")
    ax.set(xlabel="time (s)", ylabel="soil strength K (-)", title="Soil strength K (±1σ band)")
    ax.legend(fontsize=7)
    save(fig, "soil_strength.png")

    # Figs. 14, 16-18: OCPs
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for ax, key, ylabel in zip(axes, ("mu_T", "S_T", "S_E"),
                               ("max traction coeff. mu_T (-)", "slip for max traction S_T (-)", "slip for max efficiency S_E (-)")):
        for recs, t, lab in zip(runs, t_est, labels):
            ax.plot(t, _col(recs, key), lw=1, label=f"estimated: {lab}")
        if truth:
            ax.plot(tt, _col(truth, key), color="k", ls="--", lw=1.1, label="truth")
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
    axes[0].set_title("Optimal control parameters (eqs. 7 corrected, 8, 10)")
    axes[-1].set_xlabel("time (s)")
    save(fig, "ocp.png")
    return written
