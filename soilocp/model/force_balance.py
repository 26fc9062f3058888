"""The vehicle's longitudinal force balance with the torque channel's scale (eq. TC, docs/method.md §15)
and the motion resistance the model gives it (eq. 4 summed): one definition, the compiled core's
(``soilocp/_core/src/torque_scale/balance.rs``), for the offline calibration (``soilocp
calibrate-torque``, :mod:`soilocp.analysis.torque_constant`) and the online torque-scale state
(:mod:`soilocp.estimation.torque_scale`, which runs it inside the core).  These are its array bindings."""

from __future__ import annotations

import numpy as np

from soilocp import _core
from soilocp.model.checks import as_float_array, positive
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.vehicle import VehicleParams


def _broadcast(**arrays) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """The arrays' common shape and each as a flat float array of it; ValueError naming them otherwise."""
    try:
        parts = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in arrays.values()))
    except ValueError:
        shapes = ", ".join(f"{k} {np.shape(a)}" for k, a in arrays.items())
        raise ValueError(f"the arrays do not broadcast together: {shapes}") from None
    return parts[0].shape, [np.ascontiguousarray(p).reshape(-1) for p in parts]


def longitudinal_balance(f_x, omega_dot_sum, torque_sum, vehicle: VehicleParams,
                         resistance=None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. TC: summed over the wheels, eq. 13 gives T_i / R = F_GT,i + I_w omega_dot_i / R, and the
    body's longitudinal balance (eq. 29, docs/method.md §3: only the specific force f_x enters, so
    no grade term) gives m f_x = sum_i (F_GT,i - F_MR,i).  With the logged torque T_log = T / k:

        m f_x + (I_w / R) sum_i omega_dot_i  =  k sum_i T_log,i / R  -  F_MR

    Returns (x, y) = (sum T_log / R, m f_x + I_w sum omega_dot / R + F_MR,model) in N, so that
    y = k x - b with b = F_MR - F_MR,model: the motion resistance the model does not give.
    ``resistance``: F_MR,model in N (:func:`modelled_resistance`, eq. 4 at the wheels' slips and a K);
    None: 0, b is the whole F_MR (``soilocp calibrate-torque``, which knows no soil, fits it as a constant).
    m is the vehicle file's mass: a payload it does not know (true mass m') reads as k m / m' (the common
    scale of gross traction, motor constant x 1 / mass), up to the wheel-inertia term, which does not
    carry the payload (docs/method.md §15, "The wheels' inertia under an unknown payload").  Arguments broadcast (window means or samples)."""
    arrays = dict(f_x=f_x, omega_dot_sum=omega_dot_sum, torque_sum=torque_sum)
    if resistance is not None:
        arrays["resistance"] = resistance
    shape, flat = _broadcast(**arrays)
    x, y = _core.longitudinal_balance(*flat[:3], vehicle.mass, vehicle.wheel_inertia, vehicle.wheel_radius,
                                      flat[3] if resistance is not None else None)
    return x.reshape(shape), y.reshape(shape)


def modelled_resistance(slip, soil_strength, normal_force, direction,
                        constants: ModelConstants = DEFAULT_CONSTANTS) -> np.ndarray:
    """F_MR,model = d sum_i F_z,i r(S_i, K) in N, the body-frame motion resistance that eq. TC subtracts:
    eq. 4 with |S| (docs/method.md §11: even in S, it opposes travel for both slip signs) at each wheel's
    slip (eq. 1), the soil's K and the wheel's normal force; d = +-1 the direction of travel (§17: in
    reverse the resistance pushes the body forwards).  Why modelled and not a slow state: eq. 4's C5 / K
    term makes it negative below K ~ 125 (about -30 N on sand, +10 N on grass for the 100 kg rover) and
    at small slip it grows with |S|, i.e. with the acceleration that identifies k (a random-walk F_MR read
    k 2-7 % low on the accelerate/brake drives, docs/robustness.md).  slip, normal_force (k, 4);
    soil_strength, direction (k,)."""
    s = as_float_array("slip", slip)
    fz = np.asarray(normal_force, dtype=float)
    if s.ndim < 1 or s.shape[-1] != 4 or fz.shape != s.shape:
        raise ValueError(f"slip and normal_force must have one shape (..., 4), got {s.shape} and {fz.shape}")
    lead = s.shape[:-1]
    k = np.broadcast_to(positive("soil_strength", soil_strength), lead)
    d = np.broadcast_to(np.asarray(direction, dtype=float), lead)
    out = _core.modelled_resistance(np.ascontiguousarray(s.reshape(-1, 4)), np.ascontiguousarray(k.reshape(-1)),
                                    np.ascontiguousarray(fz.reshape(-1, 4)), np.ascontiguousarray(d.reshape(-1)),
                                    constants.kernel)
    return out.reshape(lead)
