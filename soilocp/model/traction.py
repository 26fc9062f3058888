"""Improved Brixius traction model (paper eqs. 2-6 and 9), vectorised over numpy arrays.

All coefficients are per unit normal load W (a force divided by W):

* gross traction  g(S, K)  = F_GT / W                      (eq. 3)
* motion resistance r(S, K) = F_MR / W                     (eq. 4)
* net (drawbar) traction mu(S, K) = F_DP / W = g - r       (eqs. 2, 5, 6)

Sign convention (docs/method.md, Conventions and §11): S > 0 driving, S < 0 braking, for a wheel
travelling forward.  Eq. 6 is odd in S (mu(-S) = -mu(S)): braking is the mirror image of driving.
Motion resistance (eq. 4 with |S|) is EVEN in S: it opposes travel whatever the sign of the slip,
and does not flip when the wheel brakes.  The wheel's torque balance (eq. 13) sees gross traction
g = mu + r (eq. 2), so for S > 0 g is exactly eq. 3 and for S < 0 it is -mu(|S|) + r(|S|), with
|g| < |mu|: the resistance itself slows the vehicle, so less brake torque is needed.
Correction (§11): the printed lower branch of eq. 3 (which flips C4 with the torque) cannot hold
together with eqs. 2, 4 and 6; we keep eq. 6 (net, odd) and eq. 4 (resistance, even) and derive g.
A wheel travelling backwards is the mirror image of all of this (S -> -S, every force negated).

Correction (docs/method.md §8): eq. 6 jumps from -C5/K to +C5/K at S = 0, so zero slip would not
give zero force.  Inside |S| < ``constants.bridge_slip`` every coefficient is the straight line
through the origin that meets the printed curve at +-bridge_slip.  bridge_slip = 0 gives the
print (with the jump).

With the paper's C5 = -5 the motion resistance is negative at low slip for K below ~125
(docs/method.md §8): this is the model, not a bug, so nothing here asserts r >= 0.
"""

from __future__ import annotations


import numpy as np

from soilocp.model.checks import as_float_array, positive
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants


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


# One-sided (s >= 0) printed curves and their derivatives.  Each returns (value, d/ds, d/dK), or
# (value, None, None) with ``derivs=False`` (the OCPs need values only: issue 11's hot path).
def _gross_pos(s, k, c, derivs=True):
    amp = _amplitude(k, c)
    e = np.exp(-c.C3 * s)
    val = amp * (1.0 - e) + c.C4
    if not derivs:
        return val, None, None
    d_s = amp * c.C3 * e
    d_k = c.C1 * c.C2 * np.exp(-c.C2 * k) * (1.0 - e)
    return val, d_s, d_k


def _resist_pos(s, k, c, derivs=True):
    sq = np.sqrt(k)
    val = c.C5 / k + c.C4 + c.C6 * s / sq
    if not derivs:
        return val, None, None
    d_s = np.full_like(val, 0.0) + c.C6 / sq
    d_k = -c.C5 / k**2 - 0.5 * c.C6 * s / (k * sq)
    return val, d_s, d_k


def _net_pos(s, k, c, derivs=True):
    g, gs, gk = _gross_pos(s, k, c, derivs)
    r, rs, rk = _resist_pos(s, k, c, derivs)
    if not derivs:
        return g - r, None, None
    return g - r, gs - rs, gk - rk


def _odd_bridged(one_sided, slip, soil_strength, c: ModelConstants):
    """Odd extension of a one-sided curve, with the linear bridge of docs/method.md §8 near S=0."""
    s, k = _inputs(slip, soil_strength)
    return _odd_bridged_unchecked(one_sided, s, k, c)


def _odd_bridged_unchecked(one_sided, s: np.ndarray, k: np.ndarray, c: ModelConstants, derivs: bool = True):
    sign = np.where(s < 0, -1.0, 1.0)
    a = np.abs(s)
    b = c.bridge_slip
    val, d_s, d_k = one_sided(a, k, c, derivs)
    if b > 0:
        inside = a < b
        if np.any(inside):
            vb, _, kb = one_sided(np.full_like(a, b), k, c, derivs)
            frac = a / b
            val = np.where(inside, vb * frac, val)
            if derivs:
                d_s = np.where(inside, vb / b, d_s)
                d_k = np.where(inside, kb * frac, d_k)
    if not derivs:
        return sign * val, None, None
    return sign * val, d_s, sign * d_k


def _even_bridged_unchecked(one_sided, s: np.ndarray, k: np.ndarray, c: ModelConstants):
    """Even extension of a one-sided curve (docs/method.md §11), with the same linear bridge as
    :func:`_odd_bridged_unchecked` inside |S| < bridge_slip, so that it vanishes at zero slip
    (a wheel at rest feels no resistance torque).  Returns (value, d/dS, d/dK)."""
    sign = np.where(s < 0, -1.0, 1.0)
    val, d_s, d_k = _odd_bridged_unchecked(one_sided, np.abs(s), k, c)
    return val, sign * d_s, d_k


def _gross_unchecked(s: np.ndarray, k: np.ndarray, c: ModelConstants):
    """g = mu + r (eq. 2 with docs/method.md §11): net traction odd (eq. 6), resistance even (eq. 4).

    Written as eq. 3's odd extension plus 2 r(|S|) on the braking side, which is the same sum
    (-mu(|S|) + r(|S|) = -g(|S|) + 2 r(|S|)) but keeps eq. 3 and its d/dK exact for S > 0, where
    d g/dK is a tiny difference of large terms at high K."""
    g, g_s, g_k = _odd_bridged_unchecked(_gross_pos, s, k, c)
    braking = s < 0
    if np.any(braking):
        r, r_s, r_k = _even_bridged_unchecked(_resist_pos, s, k, c)
        g = np.where(braking, g + 2.0 * r, g)
        g_s = np.where(braking, g_s + 2.0 * r_s, g_s)
        g_k = np.where(braking, g_k + 2.0 * r_k, g_k)
    return g, g_s, g_k


def net_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Net (drawbar) traction coefficient mu(S, K) = F_DP / W, eq. 6 (both slip signs).

    mu = +-[C1 (1 - e^{-C2 K}) (1 - e^{-+C3 S}) - (C5/K +- C6 S / sqrt(K))]  (upper sign S > 0).
    Departs from the print only inside |S| < bridge_slip (docs/method.md §8, linear bridge).
    """
    return _odd_bridged(_net_pos, slip, soil_strength, constants)[0]


def gross_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Gross traction coefficient F_GT / W = mu + r (eq. 2): eq. 3 for S > 0; for a braking wheel
    -mu(|S|) + r(|S|) (docs/method.md §11, not eq. 3's printed lower branch); bridged near S = 0."""
    return _gross_unchecked(*_inputs(slip, soil_strength), constants)[0]


def motion_resistance(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Motion-resistance coefficient F_MR / W, eq. 4 with |S| (docs/method.md §11): even in S, it
    opposes travel for both slip signs, so that g = mu + r (eq. 2); bridged near S = 0."""
    s, k = _inputs(slip, soil_strength)
    return _even_bridged_unchecked(_resist_pos, s, k, constants)[0]


def net_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """eq. 6 and its partial derivatives: (mu, d mu/dS, d mu/dK).  Used by the estimators."""
    return _odd_bridged(_net_pos, slip, soil_strength, constants)


def gross_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """g = mu + r (eq. 2, §11) and its partial derivatives: (g, d g/dS, d g/dK).  For S > 0 this is
    eq. 3 and d g/dK > 0 (monotone in K); for a braking wheel d g/dK can take either sign."""
    return _gross_unchecked(*_inputs(slip, soil_strength), constants)


def tractive_efficiency(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Tractive efficiency TE = (F_DP / F_GT) (1 - S), eq. 9, for driving slip 0 < S < 1.

    Defined only while driving: for S <= 0 no power is delivered to the ground and for S >= 1 the
    vehicle stands still, so such slip raises ValueError rather than returning a meaningless
    number.  With the paper's C5 = -5, TE exceeds 1 near S = 0 for K <= 120 (docs/method.md §5):
    that is the printed model, reproduced as is; eq. 10 is the S_E model we use.
    """
    s, k = _inputs(slip, soil_strength)
    if np.any((s <= 0) | (s >= 1)):
        bad = s[(s <= 0) | (s >= 1)].ravel()[:4].tolist()
        raise ValueError(f"slip must be in (0, 1) for tractive efficiency (eq. 9), got {bad}")
    return tractive_efficiency_unchecked(s, k, constants)


def tractive_efficiency_unchecked(s: np.ndarray, k: np.ndarray, constants: ModelConstants) -> np.ndarray:
    """Eq. 9, TE = (mu / g)(1 - S), for validated float arrays (0 < S < 1, K > 0) that broadcast:
    the one definition behind :func:`tractive_efficiency` and the OCP kernel's hot path.  While
    driving, g is eq. 3 and mu = g - r (eq. 6 = eq. 3 - eq. 4), so eq. 3 is evaluated once."""
    g = _odd_bridged_unchecked(_gross_pos, s, k, constants, False)[0]
    r = _odd_bridged_unchecked(_resist_pos, s, k, constants, False)[0]
    return (g - r) / g * (1.0 - s)


def curve_unchecked(kind: str, slip: np.ndarray, soil_strength: np.ndarray, constants: ModelConstants):
    """(value, d/dS, d/dK) of the ``gross`` (eq. 3) or ``net`` (eq. 6) curve, for validated float
    arrays that already broadcast: the estimators' hot loop, which checks its inputs once."""
    if kind == "gross":
        return _gross_unchecked(slip, soil_strength, constants)
    return _odd_bridged_unchecked(_net_pos, slip, soil_strength, constants)


def net_traction_unchecked(slip: np.ndarray, soil_strength: np.ndarray, constants: ModelConstants) -> np.ndarray:
    """Eq. 6's value alone (no derivatives) for validated float arrays: the OCPs' mu_T (eq. 8)."""
    return _odd_bridged_unchecked(_net_pos, slip, soil_strength, constants, False)[0]
