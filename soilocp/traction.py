"""Improved Brixius traction model (paper eqs. 2-6 and 9), vectorised over numpy arrays.

All coefficients are per unit normal load W (a force divided by W):

* gross traction  g(S, K)  = F_GT / W                      (eq. 3)
* motion resistance r(S, K) = F_MR / W                     (eq. 4)
* net (drawbar) traction mu(S, K) = F_DP / W = g - r       (eqs. 2, 5, 6)

Sign convention (method-notes, Conventions): S > 0 driving, S < 0 braking.  Eq. 6 as printed is
odd in S (mu(-S) = -mu(S)): braking is the mirror image of driving.  We keep that and make the
split consistent with it: g and r are odd as well, and for S > 0 they are exactly eqs. 3 and 4.
(The printed braking branches of eqs. 3 and 4 are not consistent with eq. 6 and eq. 2 at the same
time; the mirror keeps eq. 6 and eq. 2 exact, which is what the wheel torque balance, eq. 13,
needs: the wheel sees g = mu + r.)

Correction (method-notes §8): eq. 6 jumps from -C5/K to +C5/K at S = 0, so zero slip would not
give zero force.  Inside |S| < ``constants.bridge_slip`` every coefficient is the straight line
through the origin that meets the printed curve at +-bridge_slip.  bridge_slip = 0 gives the
print (with the jump).

With the paper's C5 = -5 the motion resistance is negative at low slip for K below ~125
(method-notes §8): this is the model, not a bug, so nothing here asserts r >= 0.
"""

from __future__ import annotations

import math

import numpy as np

from .checks import as_float_array, positive
from .constants import DEFAULT_CONSTANTS, ModelConstants


def _inputs(slip, soil_strength) -> tuple[np.ndarray, np.ndarray]:
    s = as_float_array("slip", slip)
    k = positive("soil_strength", soil_strength)
    try:
        s, k = np.broadcast_arrays(s, k)
    except ValueError as exc:
        raise ValueError(
            f"slip (shape {np.shape(slip)}) and soil_strength (shape {np.shape(soil_strength)}) "
            "do not broadcast together"
        ) from exc
    return s, k


def _amplitude(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """C1 * (1 - exp(-C2 K)): the soil-strength factor shared by eqs. 3, 5, 6, 8."""
    return c.C1 * -np.expm1(-c.C2 * k)


# One-sided (s >= 0) printed curves and their derivatives.  Each returns (value, d/ds, d/dK).
def _gross_pos(s, k, c):
    amp = _amplitude(k, c)
    e = np.exp(-c.C3 * s)
    val = amp * (1.0 - e) + c.C4
    d_s = amp * c.C3 * e
    d_k = c.C1 * c.C2 * np.exp(-c.C2 * k) * (1.0 - e)
    return val, d_s, d_k


def _resist_pos(s, k, c):
    sq = np.sqrt(k)
    val = c.C5 / k + c.C4 + c.C6 * s / sq
    d_s = np.full_like(val, 0.0) + c.C6 / sq
    d_k = -c.C5 / k**2 - 0.5 * c.C6 * s / (k * sq)
    return val, d_s, d_k


def _net_pos(s, k, c):
    g, gs, gk = _gross_pos(s, k, c)
    r, rs, rk = _resist_pos(s, k, c)
    return g - r, gs - rs, gk - rk


def _odd_bridged(one_sided, slip, soil_strength, c: ModelConstants):
    """Odd extension of a one-sided curve, with the linear bridge of method-notes §8 near S=0."""
    s, k = _inputs(slip, soil_strength)
    return _odd_bridged_unchecked(one_sided, s, k, c)


def _odd_bridged_unchecked(one_sided, s: np.ndarray, k: np.ndarray, c: ModelConstants):
    sign = np.where(s < 0, -1.0, 1.0)
    a = np.abs(s)
    b = c.bridge_slip
    val, d_s, d_k = one_sided(a, k, c)
    if b > 0:
        inside = a < b
        if np.any(inside):
            vb, _, kb = one_sided(np.full_like(a, b), k, c)
            frac = a / b
            val = np.where(inside, vb * frac, val)
            d_s = np.where(inside, vb / b, d_s)
            d_k = np.where(inside, kb * frac, d_k)
    return sign * val, d_s, sign * d_k


def net_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Net (drawbar) traction coefficient mu(S, K) = F_DP / W, eq. 6 (both slip signs).

    mu = +-[C1 (1 - e^{-C2 K}) (1 - e^{-+C3 S}) - (C5/K +- C6 S / sqrt(K))]  (upper sign S > 0).
    Departs from the print only inside |S| < bridge_slip (method-notes §8, linear bridge).
    """
    return _odd_bridged(_net_pos, slip, soil_strength, constants)[0]


def gross_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Gross traction coefficient F_GT / W, eq. 3; odd in S (see module docstring) and bridged."""
    return _odd_bridged(_gross_pos, slip, soil_strength, constants)[0]


def motion_resistance(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Motion-resistance coefficient F_MR / W, eq. 4 for S > 0, so that g = mu + r (eq. 2).

    For S < 0 it is the mirror image -r(|S|) (eq. 6's odd symmetry); bridged near S = 0.
    """
    return _odd_bridged(_resist_pos, slip, soil_strength, constants)[0]


def net_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """eq. 6 and its partial derivatives: (mu, d mu/dS, d mu/dK).  Used by the estimators."""
    return _odd_bridged(_net_pos, slip, soil_strength, constants)


def gross_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """eq. 3 and its partial derivatives: (g, d g/dS, d g/dK).  d g/dK > 0 for S != 0 (monotone in K)."""
    return _odd_bridged(_gross_pos, slip, soil_strength, constants)


def tractive_efficiency(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Tractive efficiency TE = (F_DP / F_GT) (1 - S), eq. 9, for driving slip 0 < S < 1.

    Defined only while driving: for S <= 0 no power is delivered to the ground and for S >= 1 the
    vehicle stands still, so such slip raises ValueError rather than returning a meaningless
    number.  With the paper's C5 = -5, TE exceeds 1 near S = 0 for K <= 120 (method-notes §5):
    that is the printed model, reproduced as is; eq. 10 is the S_E model we use.
    """
    s, k = _inputs(slip, soil_strength)
    if np.any((s <= 0) | (s >= 1)):
        bad = s[(s <= 0) | (s >= 1)].ravel()[:4].tolist()
        raise ValueError(f"slip must be in (0, 1) for tractive efficiency (eq. 9), got {bad}")
    mu = net_traction(s, k, constants)
    g = gross_traction(s, k, constants)
    return mu / g * (1.0 - s)


def curve_unchecked(kind: str, slip: np.ndarray, soil_strength: np.ndarray, constants: ModelConstants):
    """(value, d/dS, d/dK) of the ``gross`` (eq. 3) or ``net`` (eq. 6) curve, for validated float
    arrays that already broadcast: the estimators' hot loop, which checks its inputs once."""
    one_sided = _gross_pos if kind == "gross" else _net_pos
    return _odd_bridged_unchecked(one_sided, slip, soil_strength, constants)


def tractive_efficiency_scalar(slip: float, soil_strength: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> float:
    """Eq. 9 for one driving slip outside the zero-slip bridge (bridge_slip <= S < 1), with ``math``:
    the OCP stage's per-sample path.  Equal to :func:`tractive_efficiency` there (tested)."""
    c = constants
    if not (c.bridge_slip <= slip < 1 and slip > 0) or not soil_strength > 0:
        raise ValueError(f"slip must be in [bridge_slip, 1) and soil_strength > 0, got {slip!r}, {soil_strength!r}")
    amp = c.C1 * -math.expm1(-c.C2 * soil_strength)
    rise = amp * (1.0 - math.exp(-c.C3 * slip))
    gross = rise + c.C4  # eq. 3
    net = rise - (c.C5 / soil_strength + c.C6 * slip / math.sqrt(soil_strength))  # eq. 6
    return net / gross * (1.0 - slip)
