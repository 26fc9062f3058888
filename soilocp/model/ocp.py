"""Optimal control parameters from soil strength K: S_T (eq. 7, corrected), mu_T (eq. 8) and
S_E (eq. 10).  Vectorised over K.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from soilocp.model.checks import positive, positive_scalar
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import net_traction_unchecked, tractive_efficiency_unchecked


def optimal_slip_traction(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """S_T(K): the slip of maximum net traction, eq. 7 with its sign corrected (docs/method.md §1).

    Setting d mu/dS = 0 in eq. 6 (S > 0) gives
        S_T = (1/C3) ln( C1 C3 sqrt(K) (1 - e^{-C2 K}) / C6 ),
    the reciprocal of the printed ln argument (the print is negative for every soil).

    For very weak soil (K below about 9 with the paper's constants) the argument is < 1: the curve
    falls from S = 0 on and has no interior peak; S_T is then 0 (the peak is at the origin).
    """
    st = _slip_traction(positive("soil_strength", soil_strength), constants)
    return st if st.ndim else float(st)


def _slip_traction(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """Eq. 7 (sign corrected, floored at 0) for a validated K array: :func:`optimal_slip_traction`."""
    arg = c.C1 * c.C3 * np.sqrt(k) * -np.expm1(-c.C2 * k) / c.C6
    return np.maximum(np.log(arg) / c.C3, 0.0)


def max_traction(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """mu_T(K) = mu(S_T(K), K): eq. 8 (eq. 6 evaluated at the corrected S_T of eq. 7)."""
    mu = _max_traction(positive("soil_strength", soil_strength), constants)
    return mu if np.ndim(mu) else float(mu)


def _max_traction(k: np.ndarray, c: ModelConstants, st: np.ndarray | None = None) -> np.ndarray:
    """Eq. 8 for a validated K array (``st``: its S_T if already computed): :func:`max_traction`."""
    st = _slip_traction(k, c) if st is None else st
    if c.bridge_slip > 0:
        # at the origin the peak is the bridge's end point, where the printed curve starts
        st = np.maximum(st, c.bridge_slip)
    return net_traction_unchecked(st, k, c)  # eq. 6 at S_T


def optimal_slip_efficiency(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """S_E(K) = (K - alpha) / beta, eq. 10 (alpha = 677.4, beta = -5242.9 by default).

    The paper's empirical line (docs/method.md §5: eq. 9 with the printed constants has no interior
    efficiency peak for K <= 120, so the line is the model).  It reaches 0 at K = alpha; above that
    the most efficient slip is the smallest one, so S_E is clamped at 0 rather than going negative.
    """
    se = _slip_efficiency(positive("soil_strength", soil_strength), constants)
    return se if se.ndim else float(se)


def _slip_efficiency(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """Eq. 10 clamped at 0 for a validated K array: :func:`optimal_slip_efficiency`."""
    return np.maximum((k - c.alpha) / c.beta, 0.0)


@dataclass(frozen=True)
class OCP:
    """The optimal control parameters of one soil strength K: mu_T (eq. 8), S_T (eq. 7 corrected,
    docs/method.md §5) and S_E (eq. 10), all dimensionless."""

    soil_strength: float
    mu_T: float
    S_T: float
    S_E: float

    def as_dict(self) -> dict[str, float]:
        return {"soil_strength": self.soil_strength, "mu_T": self.mu_T, "S_T": self.S_T, "S_E": self.S_E}


def ocp_arrays(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS) -> dict[str, np.ndarray]:
    """mu_T (eq. 8), S_T (eq. 7, sign corrected), S_E (eq. 10) and TE at S_E (eq. 9) for an array
    of K (shape (k,)); NaN where K is NaN (no estimate) and TE NaN where S_E is not a driving slip
    in (0, 1).  The one OCP kernel of the single-vehicle stage and the batched service."""
    k = np.asarray(soil_strength, dtype=float).reshape(-1)
    have = ~np.isnan(k)
    every = have.all()  # the usual case: no masks, no NaN-filled copies
    if not every and not have.any():
        return {name: np.full(k.shape, np.nan) for name in _OCP_NAMES}
    kk = k if every else k[have]
    if not (kk > 0).all() or not np.isfinite(kk).all():
        positive("soil_strength", kk)  # raises, describing the bad value
    with np.errstate(over="ignore", divide="ignore"):
        evaluable = np.isfinite(constants.C5 / kk).all()
    if not evaluable:
        raise ValueError(f"soil_strength must be Ks the model can evaluate (>~1e-300), got {kk!r}")
    # K checked once above; the per-sample path runs the unchecked single definitions
    st = _slip_traction(kk, constants)
    se = _slip_efficiency(kk, constants)
    vals = {"mu_T": _max_traction(kk, constants, st), "S_T": st, "S_E": se}
    drive = (se > 0) & (se < 1)
    if drive.all():
        vals["te_at_S_E"] = tractive_efficiency_unchecked(se, kk, constants)
    else:
        te = np.full(kk.shape, np.nan)
        if drive.any():
            te[drive] = tractive_efficiency_unchecked(se[drive], kk[drive], constants)
        vals["te_at_S_E"] = te
    if every:
        return vals
    out = {}
    for name in _OCP_NAMES:
        out[name] = np.full(k.shape, np.nan)
        out[name][have] = vals[name]
    return out


_OCP_NAMES = ("mu_T", "S_T", "S_E", "te_at_S_E")


def ocp_from_soil_strength(soil_strength: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> OCP:
    """All three OCPs for one K: eq. 7 (sign corrected), eq. 8, eq. 10 (:func:`ocp_arrays`)."""
    k = positive_scalar("soil_strength", soil_strength)
    o = ocp_arrays(np.array([k]), constants)
    return OCP(soil_strength=k, mu_T=float(o["mu_T"][0]), S_T=float(o["S_T"][0]), S_E=float(o["S_E"][0]))
