"""The vehicle's longitudinal force balance with the torque channel's scale (docs/method.md §15):
one definition for the offline calibration (``soilocp calibrate-torque``,
:mod:`soilocp.analysis.torque_constant`) and the online torque-scale state
(:mod:`soilocp.estimation.torque_scale`)."""

from __future__ import annotations

import numpy as np

from soilocp.model.vehicle import VehicleParams


def longitudinal_balance(f_x, omega_dot_sum, torque_sum, vehicle: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """Eq. TC: summed over the wheels, eq. 13 gives T_i / R = F_GT,i + I_w omega_dot_i / R, and the
    body's longitudinal balance (eq. 29, docs/method.md §3: only the specific force f_x enters, so
    no grade term) gives m f_x = sum_i (F_GT,i - F_MR,i).  With the logged torque T_log = T / k:

        m f_x + (I_w / R) sum_i omega_dot_i  =  k sum_i T_log,i / R  -  F_MR

    Returns (x, y) = (sum T_log / R, m f_x + I_w sum omega_dot / R) in N, so that y = k x - F_MR.  m is the
    vehicle file's mass: a payload it does not know (true mass m') reads as k m / m' (the common scale of
    gross traction, motor constant x 1 / mass).  Arguments broadcast (window means or samples)."""
    r = vehicle.wheel_radius
    x = np.asarray(torque_sum, dtype=float) / r
    y = vehicle.mass * np.asarray(f_x, dtype=float) + vehicle.wheel_inertia * np.asarray(omega_dot_sum, dtype=float) / r
    return x, y
