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

The law itself is written once, in the compiled core (``soilocp/_core/src/traction.rs``); these
functions check their arguments, broadcast them and call it, so that the simulator, the
estimators and the analysis tools share one definition.
"""

from __future__ import annotations

import numpy as np

from soilocp import _core
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


def _scalar(a: np.ndarray):
    """A 0-d result as a numpy float, as numpy's own arithmetic on 0-d arrays returns it."""
    return a[()] if a.ndim == 0 else a


def _curve(kind: str, s: np.ndarray, k: np.ndarray, c: ModelConstants):
    """(value, d/dS, d/dK) of one curve for float arrays that broadcast together, from the core."""
    return tuple(_scalar(a) for a in _core.traction_curve(kind, s, k, c.kernel))


def net_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Net (drawbar) traction coefficient mu(S, K) = F_DP / W, eq. 6 (both slip signs).

    mu = +-[C1 (1 - e^{-C2 K}) (1 - e^{-+C3 S}) - (C5/K +- C6 S / sqrt(K))]  (upper sign S > 0).
    Departs from the print only inside |S| < bridge_slip (docs/method.md §8, linear bridge).
    """
    s, k = _inputs(slip, soil_strength)
    return _scalar(_core.traction_value("net", s, k, constants.kernel))


def gross_traction(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Gross traction coefficient F_GT / W = mu + r (eq. 2): eq. 3 for S > 0; for a braking wheel
    -mu(|S|) + r(|S|) (docs/method.md §11, not eq. 3's printed lower branch); bridged near S = 0."""
    s, k = _inputs(slip, soil_strength)
    return _scalar(_core.traction_value("gross", s, k, constants.kernel))


def motion_resistance(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """Motion-resistance coefficient F_MR / W, eq. 4 with |S| (docs/method.md §11): even in S, it
    opposes travel for both slip signs, so that g = mu + r (eq. 2); bridged near S = 0."""
    s, k = _inputs(slip, soil_strength)
    return _scalar(_core.traction_value("resistance", s, k, constants.kernel))


def net_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """eq. 6 and its partial derivatives: (mu, d mu/dS, d mu/dK).  Used by the estimators."""
    return _curve("net", *_inputs(slip, soil_strength), constants)


def gross_traction_with_derivatives(slip, soil_strength, constants: ModelConstants = DEFAULT_CONSTANTS):
    """g = mu + r (eq. 2, §11) and its partial derivatives: (g, d g/dS, d g/dK).  For S > 0 this is
    eq. 3 and d g/dK > 0 (monotone in K); for a braking wheel d g/dK can take either sign."""
    return _curve("gross", *_inputs(slip, soil_strength), constants)


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
    return _scalar(_core.tractive_efficiency(s, k, constants.kernel))


def curve_unchecked(kind: str, slip: np.ndarray, soil_strength: np.ndarray, constants: ModelConstants):
    """(value, d/dS, d/dK) of the ``gross`` (eq. 3) or ``net`` (eq. 6) curve, for validated float
    arrays that already broadcast: the estimators' hot loop, which checks its inputs once."""
    return _curve(kind, np.asarray(slip, dtype=float), np.asarray(soil_strength, dtype=float), constants)
