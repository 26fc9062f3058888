"""Optimal control parameters from soil strength K: S_T (eq. 7, corrected), mu_T (eq. 8) and
S_E (eq. 10).  Vectorised over K.

The equations are written once, in the compiled core (``soilocp/_core/src/ocp.rs``, one call for
a bank of K); these functions check their arguments and shape the results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from soilocp import _core
from soilocp.model.checks import positive, positive_scalar
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.ocp_values import OCP_NAMES


def _bank(k: np.ndarray, constants: ModelConstants) -> tuple[np.ndarray, ...]:
    """The core's (mu_T, S_T, S_E, TE at S_E) of a 1-D float array of K (NaN = no estimate).

    A K the core refuses is described here: the argument check's message if it is not a finite
    K > 0, else the model's limit (C5 / K must be finite)."""
    try:
        return _core.ocp_bank(k, constants.kernel)
    except ValueError:
        kk = k[~np.isnan(k)]
        positive("soil_strength", kk)  # raises, describing the bad value
        raise ValueError(f"soil_strength must be Ks the model can evaluate (>~1e-300), got {kk!r}") from None


def _one(index: int, soil_strength, constants: ModelConstants):
    """One of the OCPs of checked K (a scalar or an array of any shape)."""
    k = positive("soil_strength", soil_strength)
    out = _bank(np.ascontiguousarray(k, dtype=float).reshape(-1), constants)[index].reshape(k.shape)
    return out if out.ndim else float(out)


def optimal_slip_traction(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """S_T(K): the slip of maximum net traction, eq. 7 with its sign corrected (docs/method.md §1).

    Setting d mu/dS = 0 in eq. 6 (S > 0) gives
        S_T = (1/C3) ln( C1 C3 sqrt(K) (1 - e^{-C2 K}) / C6 ),
    the reciprocal of the printed ln argument (the print is negative for every soil).

    For very weak soil (K below about 9 with the paper's constants) the argument is < 1: the curve
    falls from S = 0 on and has no interior peak; S_T is then 0 (the peak is at the origin).
    """
    return _one(1, soil_strength, constants)


def max_traction(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """mu_T(K) = mu(S_T(K), K): eq. 8 (eq. 6 evaluated at the corrected S_T of eq. 7; a peak at the
    origin is taken at the zero-slip bridge's end point, docs/method.md §1, §8)."""
    return _one(0, soil_strength, constants)


def optimal_slip_efficiency(soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """S_E(K) = (K - alpha) / beta, eq. 10 (alpha = 677.4, beta = -5242.9 by default).

    The paper's empirical line (docs/method.md §5: eq. 9 with the printed constants has no interior
    efficiency peak for K <= 120, so the line is the model).  It reaches 0 at K = alpha; above that
    the most efficient slip is the smallest one, so S_E is clamped at 0 rather than going negative.
    """
    return _one(2, soil_strength, constants)


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
    in (0, 1).  The one OCP kernel of the single-vehicle stage and the batched service: one call
    of the core for the whole bank."""
    k = np.ascontiguousarray(soil_strength, dtype=float).reshape(-1)
    return dict(zip(OCP_NAMES, _bank(k, constants)))


def ocp_from_soil_strength(soil_strength: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> OCP:
    """All three OCPs for one K: eq. 7 (sign corrected), eq. 8, eq. 10 (:func:`ocp_arrays`)."""
    k = positive_scalar("soil_strength", soil_strength)
    o = ocp_arrays(np.array([k]), constants)
    return OCP(soil_strength=k, mu_T=float(o["mu_T"][0]), S_T=float(o["S_T"][0]), S_E=float(o["S_E"][0]))
