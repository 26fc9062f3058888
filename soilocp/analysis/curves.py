"""The paper's model figures as PNG files: Fig. 3 (traction-slip curves, eq. 6), Fig. 4 (tractive
efficiency, eq. 9) and Fig. 5 (the OCP models mu_T, S_T, S_E against K, eqs. 7 corrected, 8, 10).

Every curve is computed by the physics functions of :mod:`soilocp.model.traction` and :mod:`soilocp.model.ocp`
from one :class:`~soilocp.model.constants.ModelConstants`, so a calibrated constants file draws the
calibrated model.  Uses matplotlib's non-interactive Agg backend (no display needed).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.ocp import max_traction, optimal_slip_efficiency, optimal_slip_traction
from soilocp.model.traction import net_traction, tractive_efficiency

#: The soils of the paper's Figs. 3 and 4 (sand, gravel, the "expected soil type", grass).
PAPER_SOILS: tuple[str, ...] = ("sand", "gravel", "EST", "grass")

FIGURE_FILES = {
    "fig3": "fig3_traction_slip.png",
    "fig4": "fig4_tractive_efficiency.png",
    "fig5": "fig5_ocp_vs_soil_strength.png",
}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)  # files only; never open a window
    import matplotlib.pyplot as plt

    return plt


def figure_soils(constants: ModelConstants, names: list[str] | None = None) -> dict[str, float]:
    """Soils to draw: ``names`` (each must be in ``constants.soils``), else the paper's four that the
    constants know, else every soil of the constants."""
    if names:
        unknown = [n for n in names if n not in constants.soils]
        if unknown:
            raise ValueError(f"soil(s) {unknown} are not in the constants' soils {sorted(constants.soils)}")
        return {n: constants.soils[n] for n in names}
    paper = {n: constants.soils[n] for n in PAPER_SOILS if n in constants.soils}
    return paper if len(paper) >= 2 else dict(constants.soils)


def plot_traction_slip(path: Path, soils: Mapping[str, float], constants: ModelConstants = DEFAULT_CONSTANTS) -> Path:
    """Fig. 3: net traction coefficient mu(S, K) of eq. 6 for S in [-1, 1], peaks (S_T, mu_T) marked."""
    plt = _pyplot()
    s = np.linspace(-1.0, 1.0, 2001)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    for name, k in soils.items():
        (line,) = ax.plot(s, net_traction(s, k, constants), label=f"{name} (K = {k:.4g})")
        st, mt = optimal_slip_traction(k, constants), max_traction(k, constants)
        ax.plot([st, -st], [mt, -mt], "o", color=line.get_color(), ms=6)
        ax.annotate(f"S_T={st:.3f}\nμ_T={mt:.3f}", (st, mt), textcoords="offset points", xytext=(6, 4), fontsize=7)
    ax.axhline(0, color="0.6", lw=0.8)
    ax.axvline(0, color="0.6", lw=0.8)
    ax.set_xlabel("slip ratio S [-] (S > 0 driving, S < 0 braking)")
    ax.set_ylabel("net traction coefficient μ = F_DP / W [-]")
    ax.set_title("Fig. 3: traction-slip curves, eq. 6 (dots: peaks S_T, μ_T of eqs. 7-8)")
    ax.set_xlim(-1, 1)
    ax.margins(y=0.12)  # room for the peak labels under the title
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    return _save(plt, fig, path)


def plot_tractive_efficiency(
    path: Path, soils: Mapping[str, float], constants: ModelConstants = DEFAULT_CONSTANTS
) -> Path:
    """Fig. 4: tractive efficiency TE(S) of eq. 9 for 0 < S < 1, eq. 10's S_E marked on each curve.

    The printed constants give TE > 1 near S = 0 for K <= 120 (docs/method.md §5); the plot shows the
    model as it is and says so, with the TE = 1 bound drawn.
    """
    plt = _pyplot()
    s = np.linspace(max(constants.bridge_slip, 1e-3), 0.99, 1000)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    top, bottom = 1.05, -0.05
    for name, k in soils.items():
        te = tractive_efficiency(s, k, constants)
        top = max(top, float(np.max(te)) * 1.05)
        bottom = min(bottom, float(np.min(te)))
        (line,) = ax.plot(s, te, label=f"{name} (K = {k:.4g})")
        se = optimal_slip_efficiency(k, constants)
        if 0 < se < 1:
            ax.plot([se], [float(tractive_efficiency(se, k, constants))], "D", color=line.get_color(), ms=6)
            ax.axvline(se, color=line.get_color(), ls=":", lw=0.8)
    ax.axhline(1.0, color="k", ls="--", lw=0.8, label="TE = 1 (output = input power)")
    ax.set_ylim(max(bottom, -0.5), min(top, 3.0))  # clip the S -> 0 branches, keep the peaks in view
    ax.set_xlim(0, 1)
    ax.set_xlabel("slip ratio S [-]")
    ax.set_ylabel("tractive efficiency TE = (F_DP / F_GT)(1 - S) [-]")
    ax.set_title(
        "Fig. 4: tractive efficiency, eq. 9 (diamonds: S_E of eq. 10)\n"
        "caveat (docs/method.md §5): eq. 9 is meaningful only where 0 < TE <= 1; with C5 < 0, TE > 1 near S = 0\n"
        "and weak soils have no interior peak, so eq. 10 is an empirical line, not eq. 9's argmax",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    return _save(plt, fig, path)


def _save(plt, fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_ocp_vs_soil_strength(
    path: Path,
    soils: Mapping[str, float],
    constants: ModelConstants = DEFAULT_CONSTANTS,
    k_range: tuple[float, float] = (10.0, 1000.0),
) -> Path:
    """Fig. 5: mu_T (eq. 8), S_T (eq. 7 corrected) and S_E (eq. 10) against K on a log axis."""
    lo, hi = k_range
    if not (0 < lo < hi and np.isfinite(hi)):
        raise ValueError(f"k_range must satisfy 0 < low < high < inf, got {k_range!r}")
    plt = _pyplot()
    k = np.logspace(np.log10(lo), np.log10(hi), 400)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    ax.semilogx(k, max_traction(k, constants), label="μ_T, maximum traction coefficient (eq. 8)")
    ax.semilogx(k, optimal_slip_traction(k, constants), label="S_T, slip of maximum traction (eq. 7, corrected)")
    ax.semilogx(k, optimal_slip_efficiency(k, constants), label="S_E, slip of maximum efficiency (eq. 10)")
    for name, ks in soils.items():
        if lo <= ks <= hi:
            ax.axvline(ks, color="0.5", ls=":", lw=0.8)
            ax.text(ks, 0.02, f" {name}", rotation=90, fontsize=8, color="0.3", va="bottom")
    ax.set_xlabel("soil strength K [-] (log scale)")
    ax.set_ylabel("optimal control parameter [-]")
    ax.set_title("Fig. 5: OCP models against soil strength K")
    ax.set_xlim(lo, hi)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper left", fontsize=8)
    return _save(plt, fig, path)


def write_figures(
    out_dir: str | Path, constants: ModelConstants = DEFAULT_CONSTANTS, soil_names: list[str] | None = None
) -> dict[str, Path]:
    """Write Figs. 3, 4 and 5 as PNGs into ``out_dir`` (created if needed); returns their paths."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {str(out)!r} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    soils = figure_soils(constants, soil_names)
    return {
        "fig3": plot_traction_slip(out / FIGURE_FILES["fig3"], soils, constants),
        "fig4": plot_tractive_efficiency(out / FIGURE_FILES["fig4"], soils, constants),
        "fig5": plot_ocp_vs_soil_strength(out / FIGURE_FILES["fig5"], soils, constants),
    }
