"""Normal forces on the four wheels from the measured specific force, eqs. 16-25.

Corrections (docs/method.md §2-3):

* The 4x4 matrix A of eq. 23 is singular (rank 3) for every geometry: A (1,-1,1,-1)^T = 0 is the
  warp mode of a rigid body on four wheels, which statics cannot fix.  Eq. 25's A^{-1} does not
  exist.  B is always orthogonal to the null vector, so A F = B is consistent, and we return the
  minimum-norm least-squares solution F = A^+ B (pseudo-inverse), which is the zero-warp solution
  F1 + F3 = F2 + F4 (equal corner stiffness).
* Only acceleration + gravity enters eqs. 16-19, i.e. the accelerometer's specific force
  f = (V_dot + g_R) (x forward, y left, z up; +9.81 on z at rest).  We use the measured f
  directly; eq. 20 (gravity from roll and pitch) is the zero-acceleration special case, provided
  by :func:`gravity_from_attitude`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from soilocp.model.checks import as_float_array, positive_scalar
from soilocp.model.vehicle import VehicleParams

STANDARD_GRAVITY = 9.80665


def gravity_from_attitude(roll, pitch, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """Gravity reaction in the body frame from roll and pitch, eq. 20: (-g s(theta), g s(alpha) c(theta), g c(alpha) c(theta)).

    REP-103 angles: roll alpha > 0 = left side up, pitch theta > 0 = nose down.  This is the
    specific force an accelerometer at rest reads, so at rest on a climb (pitch < 0) f_x > 0.
    Vectorised: returns shape (..., 3).
    """
    al = as_float_array("roll", roll)
    th = as_float_array("pitch", pitch)
    g = positive_scalar("g", g)
    al, th = np.broadcast_arrays(al, th)
    return np.stack([-g * np.sin(th), g * np.sin(al) * np.cos(th), g * np.cos(al) * np.cos(th)], axis=-1)


def _geometry(v: VehicleParams) -> tuple[float, float, float, float, float]:
    vals = {name: getattr(v, name) for name in ("a", "b", "c", "d", "h")}
    for name, val in vals.items():
        if not np.isfinite(val) or val <= 0:
            raise ValueError(f"vehicle geometry {name} must be a finite length > 0, got {val!r}")
    return vals["a"], vals["b"], vals["c"], vals["d"], vals["h"]


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
    f = as_float_array("specific_force", specific_force)
    if f.shape[-1:] != (3,):
        raise ValueError(f"specific_force must have shape (..., 3), got shape {f.shape}")
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


@lru_cache(maxsize=64)
def _pinv_cached(vehicle: VehicleParams) -> np.ndarray:
    return np.linalg.pinv(system_matrix(vehicle))


def normal_forces(vehicle: VehicleParams, specific_force) -> np.ndarray:
    """F_z per wheel (N), wheels 1 LR, 2 LF, 3 RF, 4 RR: zero-warp solution A^+ B of eqs. 21-25.

    ``specific_force`` is (3,) or (N, 3) in m/s^2; returns (4,) or (N, 4).  Satisfies A F = B
    exactly (B is in A's range), sum(F) = m f_z, and F1 + F3 = F2 + F4.  A wheel may come out
    negative (lift-off) under extreme specific force: that is reported, not clipped, so that a
    caller can flag it.
    """
    B = load_vector(vehicle, specific_force)
    return B @ _pinv_cached(vehicle).T


class NormalForceSolver:
    """:func:`normal_forces` for one vehicle with A^+ and the load-vector coefficients prepared
    once: the per-sample hot path of the normal-force stage (same numbers, tested)."""

    def __init__(self, vehicle: VehicleParams):
        a, b, c, d, h = _geometry(vehicle)
        m = vehicle.mass
        # B = m * (fx * [-h, h, h, -h] + fy * [h, h, -h, -h] + fz * [a+c, b+c, b+d, a+d])  (eq. 24)
        coeff = m * np.array([[-h, h, h, -h], [h, h, -h, -h], [a + c, b + c, b + d, a + d]])
        self._map = coeff @ _pinv_cached(vehicle).T  # F = f @ (coeff @ A^+T)

    def __call__(self, specific_force) -> np.ndarray:
        f = np.asarray(specific_force, dtype=float)
        if f.shape[-1:] != (3,) or not np.all(np.isfinite(f)):
            _reject_specific_force(f)
        return f @ self._map


def _reject_specific_force(f) -> None:
    """Raise the ValueError naming ``specific_force`` (non-finite values first, then the shape)."""
    as_float_array("specific_force", f)
    raise ValueError(f"specific_force must have shape (..., 3), got shape {np.shape(f)}")


def static_normal_forces(vehicle: VehicleParams, roll=0.0, pitch=0.0, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """Normal forces at rest (or constant speed) on a slope: eq. 25 with eq. 20's gravity."""
    return normal_forces(vehicle, gravity_from_attitude(roll, pitch, g))
