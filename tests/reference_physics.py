"""A plain numpy reference of the equations the compiled core holds (soilocp/_core): the traction
law (eqs. 2-6, 9 with docs/method.md §8 and §11), the OCPs (eqs. 7, 8, 10) and the normal forces
(eqs. 16-25, zero-warp pseudo-inverse, §2-3).  It is the product's numpy code as it was before the
port (main at d7e1115), kept here only so that the tests can hold the core to it; the product never
imports it.
"""

from __future__ import annotations

import numpy as np

from soilocp.model.constants import ModelConstants
from soilocp.model.vehicle import VehicleParams

def _amplitude(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """C1 * (1 - exp(-C2 K)): the soil-strength factor shared by eqs. 3, 5, 6, 8."""
    return c.C1 * -np.expm1(-c.C2 * k)


# One-sided (s >= 0) printed curves and their derivatives.  Each returns (value, d/ds, d/dK), or
# (value, None, None) with ``derivs=False`` (the OCPs need values only, on the hot path).
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


def curve(kind: str, s: np.ndarray, k: np.ndarray, c: ModelConstants):
    """(value, d/dS, d/dK) of the ``net`` (eq. 6), ``gross`` (eq. 2/3) or ``resistance`` (eq. 4) curve."""
    s, k = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(k, dtype=float))
    if kind == "gross":
        return _gross_unchecked(s, k, c)
    if kind == "resistance":
        return _even_bridged_unchecked(_resist_pos, s, k, c)
    return _odd_bridged_unchecked(_net_pos, s, k, c)


def tractive_efficiency(s: np.ndarray, k: np.ndarray, constants: ModelConstants) -> np.ndarray:
    """Eq. 9, TE = (mu / g)(1 - S), for 0 < S < 1."""
    s, k = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(k, dtype=float))
    g = _odd_bridged_unchecked(_gross_pos, s, k, constants, False)[0]
    r = _odd_bridged_unchecked(_resist_pos, s, k, constants, False)[0]
    return (g - r) / g * (1.0 - s)


def _slip_traction(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """Eq. 7 (sign corrected, floored at 0) for a validated K array: :func:`optimal_slip_traction`."""
    arg = c.C1 * c.C3 * np.sqrt(k) * -np.expm1(-c.C2 * k) / c.C6
    return np.maximum(np.log(arg) / c.C3, 0.0)


def _max_traction(k: np.ndarray, c: ModelConstants, st: np.ndarray | None = None) -> np.ndarray:
    """Eq. 8 for a validated K array (``st``: its S_T if already computed): :func:`max_traction`."""
    st = _slip_traction(k, c) if st is None else st
    if c.bridge_slip > 0:
        # at the origin the peak is the bridge's end point, where the printed curve starts
        st = np.maximum(st, c.bridge_slip)
    return _odd_bridged_unchecked(_net_pos, st, k, c, False)[0]  # eq. 6 at S_T


def _slip_efficiency(k: np.ndarray, c: ModelConstants) -> np.ndarray:
    """Eq. 10 clamped at 0 for a validated K array: :func:`optimal_slip_efficiency`."""
    return np.maximum((k - c.alpha) / c.beta, 0.0)


def ocp(k: np.ndarray, c: ModelConstants) -> dict[str, np.ndarray]:
    """mu_T, S_T, S_E and TE at S_E (NaN unless 0 < S_E < 1) for an array of valid K > 0."""
    k = np.asarray(k, dtype=float)
    st = _slip_traction(k, c)
    se = _slip_efficiency(k, c)
    te = np.full(k.shape, np.nan)
    drive = (se > 0) & (se < 1)
    te[drive] = tractive_efficiency(se[drive], k[drive], c)
    return {"mu_T": _max_traction(k, c, st), "S_T": st, "S_E": se, "te_at_S_E": te}


def system_matrix(vehicle: VehicleParams) -> np.ndarray:
    """A of eq. 23 (rank 3: A (1,-1,1,-1)^T = 0)."""
    a, b, c, d, _ = _geometry(vehicle)
    L, W = a + b, c + d
    return np.array(
        [
            [0.0, L, L + W, W],
            [L, 0.0, W, L + W],
            [L + W, W, 0.0, L],
            [W, L + W, L, 0.0],
        ]
    )


def load_vector(vehicle: VehicleParams, specific_force) -> np.ndarray:
    """B of eq. 24 with (V_dot + g) replaced by the measured specific force f; shape (..., 4)."""
    a, b, c, d, h = _geometry(vehicle)
    f = np.asarray(specific_force, dtype=float)
    m = vehicle.mass
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return m * np.stack(
        [
            -fx * h + fy * h + fz * (a + c),
            fx * h + fy * h + fz * (b + c),
            fx * h - fy * h + fz * (b + d),
            -fx * h - fy * h + fz * (a + d),
        ],
        axis=-1,
    )


def _geometry(v: VehicleParams) -> tuple[float, float, float, float, float]:
    return v.a, v.b, v.c, v.d, v.h


def normal_forces(vehicle: VehicleParams, specific_force) -> np.ndarray:
    """F_z = A^+ B (eqs. 21-25, zero-warp), with numpy's SVD pseudo-inverse."""
    return load_vector(vehicle, specific_force) @ np.linalg.pinv(system_matrix(vehicle)).T
