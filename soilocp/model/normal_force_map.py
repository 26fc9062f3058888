"""The normal-force map of one vehicle, F = f M (eqs. 16-25), without numpy: the stage service of the
normal forces, which runs only this, loads none (tests/test_lean_processes.py).

M = C (A^+)^T (3 x 4) is computed once per vehicle by the compiled core from the geometry and the
mass, in closed form: the 4x4 A of eq. 23 has rank 3 (its null vector (1, -1, 1, -1) is the warp
mode), so eq. 25's A^{-1} does not exist and the solution is the zero-warp pseudo-inverse A^+ B, and
only the measured specific force enters B (eq. 24): docs/method.md §2-3;
``soilocp/_core/src/normal_force.rs`` (``zero_warp_map``) derives A^+ from A's Hadamard
eigenvectors.  Every caller takes its solver from :func:`core_solver`: this module's N = 1 call,
:class:`soilocp.model.normal_force.NormalForceSolver` (banks, the batched service, the offline
estimate) and the simulator.
"""

from __future__ import annotations

from functools import lru_cache

from soilocp import _core
from soilocp.model.vehicle import VehicleParams


@lru_cache(maxsize=64)
def core_solver(vehicle: VehicleParams) -> _core.NormalForceSolver:
    """The core's solver of one vehicle: F = f M with M = C (A^+)^T (eqs. 21-25, zero warp), M in
    closed form from a, b, c, d, h and the mass (ValueError naming a value that is not finite and > 0)."""
    return _core.NormalForceSolver(vehicle.a, vehicle.b, vehicle.c, vehicle.d, vehicle.h, vehicle.mass)


def solve_one(solver: _core.NormalForceSolver, specific_force) -> tuple[float, float, float, float]:
    """F_z per wheel (N; wheels 1 LR, 2 LF, 3 RF, 4 RR) for one specific force (f_x, f_y, f_z) in
    m/s^2 (x forward, y left, z up; +9.81 on z at rest), as four floats: the zero-warp solution of
    eqs. 21-25, not clipped (<= 0 is a lifted wheel).  ValueError naming ``specific_force`` and its
    value if it is not three finite numbers."""
    try:
        fx, fy, fz = specific_force
        return solver.solve_one(fx, fy, fz)
    except (TypeError, ValueError):
        raise ValueError(f"specific_force must be three finite numbers, got {_describe(specific_force)}") from None


def _describe(value) -> str:
    try:
        return repr(tuple(float(v) for v in value))
    except (TypeError, ValueError):
        return repr(value)


__all__ = ["core_solver", "solve_one"]
