"""What a wheel's readings mean to the observer (docs/method.md §14): the skid-steer torque
split (one motor, one speed and one torque per side, two chained wheels) and the lag of an
encoder speed that is a count difference over its interval.  Inputs of the observer kernel
(:mod:`soilocp.estimation.observer_bank`) and of its filterpy reference, one implementation."""

from __future__ import annotations

import numpy as np


def split_side_torque(torque: np.ndarray, fz: np.ndarray, inertia_torque: np.ndarray | None = None) -> np.ndarray:
    """Per-wheel torque (k, 4) of a skid-steer robot: each side's motor torque T_s (logged as half on
    each of its wheels 1+2 left, 3+4 right) shared by its two chained wheels so that both see the
    same gross traction coefficient g (same slip, same soil) in eq. 13.

    Eq. 13 for the pair (one speed): 2 I_w omega_dot = T_s - R_w g (Fz_a + Fz_b), and for wheel a
    alone T_a = I_w omega_dot + R_w g Fz_a, hence
        T_a = T_s Fz_a / (Fz_a + Fz_b) + I_w omega_dot (1 - 2 Fz_a / (Fz_a + Fz_b)).
    ``inertia_torque`` (k, 4) is I_w omega_dot per wheel (the side's mean is used); None = 0, the
    pure split by normal force, which is exact only at constant wheel speed: under a hard
    acceleration (load moved off the front) it hands the unloaded wheel a share of the inertia
    torque in proportion to its small load, and its g comes out ~0.1-0.3 low (docs/method.md §14)."""
    out = np.empty_like(torque)
    for a, b in ((0, 1), (2, 3)):
        side = torque[:, a] + torque[:, b]
        total = fz[:, a] + fz[:, b]
        share_a, share_b = fz[:, a] / total, fz[:, b] / total
        out[:, a] = side * share_a
        out[:, b] = side * share_b
        if inertia_torque is not None:
            inert = 0.5 * (inertia_torque[:, a] + inertia_torque[:, b])
            out[:, a] += inert * (1.0 - 2.0 * share_a)
            out[:, b] += inert * (1.0 - 2.0 * share_b)
    return out


def wheel_acceleration(prev: np.ndarray, now: np.ndarray, interval: np.ndarray, fresh: np.ndarray,
                       max_gap: float) -> np.ndarray:
    """omega_dot per wheel (k, 4) from two consecutive encoder readings, (now - prev) / interval:
    each is the mean speed over its interval, so this is the acceleration about one interval ago.
    Held readings (not ``fresh``), a first reading and intervals beyond ``max_gap`` give 0 (no
    inertia term, no lead).  From the readings and not from the filter's state, so that no filter
    output feeds back into its own inputs."""
    ok = fresh & (interval > 0) & (interval <= max_gap) & np.isfinite(prev)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = (now - prev) / np.where(ok, interval, 1.0)
    return np.where(ok, rate, 0.0)


def encoder_lead(interval: np.ndarray, omega_rate: np.ndarray) -> np.ndarray:
    """What to add to an encoder wheel speed (k, 4) (vehicle ``wheel_speed_reading``
    "interval_mean") to read it as the speed at its stamp: a count difference over the interval tau
    since the previous reading is the mean speed over that interval, omega(t - tau/2) + O(tau^2),
    so it lags by omega_dot tau / 2.  tau is the interval since the reading last changed: at a
    quantised steady speed a full-rate encoder repeats its count difference, and those repeats are
    readings (:mod:`soilocp.estimation.readings`) with no acceleration and so no lead; the change
    that follows takes the whole interval, so the lead is right on average and off by at most
    half a count between (0.019 rad/s at 16384 counts and 100 Hz, under the wheel-speed noise).  At 0.01 s and the ~50 rad/s^2 of a hard skid-steer
    acceleration that is 0.23 rad/s, a slip error of ~0.02 at 1.5 m/s: enough to read firm soil
    (K 300) as K > 1000 (docs/method.md §14).  ``omega_rate`` from :func:`wheel_acceleration` (the
    readings, not the model: the model's omega_dot carries the lag of its traction states)."""
    return 0.5 * interval * omega_rate
