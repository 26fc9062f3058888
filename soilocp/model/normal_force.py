"""Normal forces on the four wheels from the measured specific force, eqs. 16-25, for one specific
force or a bank (numpy arrays).  The per-vehicle matrix M = C (A^+)^T (A of eq. 23, C of eq. 24's
load vector, A^+ in closed form) and the per-sample product F = f M are the compiled core's
(``soilocp/_core/src/normal_force.rs``), one solver per vehicle from
:func:`soilocp.model.normal_force_map.core_solver` (whose numpy-free N = 1 call the normal-force
service runs).

Corrections (docs/method.md §2-3):

* The 4x4 matrix A of eq. 23 is singular (rank 3) for every geometry: A (1,-1,1,-1)^T = 0 is the
  warp mode of a rigid body on four wheels, which statics cannot fix.  Eq. 25's A^{-1} does not
  exist.  B is always orthogonal to the null vector, so A F = B is consistent, and we return the
  minimum-norm least-squares solution F = A^+ B (pseudo-inverse), which is the zero-warp solution
  F1 + F3 = F2 + F4 (equal corner stiffness).
* Only acceleration + gravity enters eqs. 16-19, i.e. the accelerometer's specific force
  f = (V_dot + g_R) (x forward, y left, z up; +9.81 on z at rest).  We use the measured f
  directly; eq. 20 (gravity from roll and pitch) is the zero-acceleration special case, provided
  by :func:`gravity_from_attitude` (the core's, which the torque scale's force balance uses too).
"""

from __future__ import annotations

import numpy as np

from soilocp import _core
from soilocp.model.checks import as_float_array, positive_scalar
from soilocp.model.constants import STANDARD_GRAVITY  # noqa: F401 (imported from here too)
from soilocp.model.normal_force_map import core_solver
from soilocp.model.vehicle import VehicleParams


def gravity_from_attitude(roll, pitch, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """Gravity reaction in the body frame from roll and pitch, eq. 20: (-g s(theta), g s(alpha) c(theta), g c(alpha) c(theta)).

    REP-103 angles: roll alpha > 0 = left side up, pitch theta > 0 = nose down.  This is the
    specific force an accelerometer at rest reads, so at rest on a climb (pitch < 0) f_x > 0.
    Vectorised: returns shape (..., 3).  The equation is the core's (``normal_force.rs``), which the
    torque scale's balance uses too.
    """
    al = as_float_array("roll", roll)
    th = as_float_array("pitch", pitch)
    g = positive_scalar("g", g)
    al, th = np.broadcast_arrays(al, th)
    return _core.gravity_from_attitude(al, th, g)


def normal_forces(vehicle: VehicleParams, specific_force) -> np.ndarray:
    """F_z per wheel (N), wheels 1 LR, 2 LF, 3 RF, 4 RR: zero-warp solution A^+ B of eqs. 21-25.

    ``specific_force`` is (3,) or (N, 3) in m/s^2; returns (4,) or (N, 4).  Satisfies A F = B
    exactly (B is in A's range), sum(F) = m f_z, and F1 + F3 = F2 + F4.  A wheel may come out
    negative (lift-off) under extreme specific force: that is reported, not clipped, so that a
    caller can flag it.
    """
    return NormalForceSolver(vehicle)(specific_force)


class NormalForceSolver:
    """:func:`normal_forces` for one vehicle, its matrix prepared once; the product runs in the core
    (``soilocp/_core/src/normal_force.rs``): one call per step for one specific force (3,) or a
    bank (N, 3)."""

    def __init__(self, vehicle: VehicleParams):
        self._core = core_solver(vehicle)

    def __call__(self, specific_force) -> np.ndarray:
        try:
            return self._core.solve(np.asarray(specific_force, dtype=float))
        except (TypeError, ValueError):
            _reject_specific_force(specific_force)
            raise


def _reject_specific_force(f) -> None:
    """Raise the ValueError naming ``specific_force`` (non-finite values first, then the shape)."""
    as_float_array("specific_force", f)
    raise ValueError(f"specific_force must have shape (..., 3), got shape {np.shape(f)}")


def static_normal_forces(vehicle: VehicleParams, roll=0.0, pitch=0.0, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """Normal forces at rest (or constant speed) on a slope: eq. 25 with eq. 20's gravity."""
    return normal_forces(vehicle, gravity_from_attitude(roll, pitch, g))
