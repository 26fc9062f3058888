"""Sensor models of the simulated rover: truth in, a noisy ``SensorSample``'s values out.

All noise levels live in :class:`SensorNoise` (documented defaults); every random draw comes from
one seeded ``numpy.random.Generator``, so the same seed gives the same log.  ``SensorNoise.noiseless()``
passes the truth through exactly (no noise, no bias, no gain error, no encoder quantisation).

Conventions (docs/method.md, Conventions): specific force in the body frame, x forward,
y left, z up, IMU at the CoM (+9.81 on z at rest); roll/pitch REP-103 (pitch > 0 = nose down);
wheel speeds may be encoder count differences over the last sample interval (quantised).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class SensorNoise:
    """Noise levels (1-sigma) of the rover's sensors.  Defaults are those of a small field rover."""

    accel_noise: float = 0.03  #: accelerometer white noise per axis, m/s^2
    accel_bias: float = 0.02  #: 1-sigma of the accelerometer's constant bias per axis (drawn once per run), m/s^2
    gyro_noise: float = 0.003  #: yaw-rate white noise, rad/s
    attitude_noise: float = 0.002  #: AHRS roll and pitch white noise, rad
    encoder_cpr: int | None = 16384  #: encoder counts per wheel revolution; None = exact wheel speed
    torque_noise: float = 0.05  #: wheel torque (from motor current) white noise, N m
    torque_gain_error: float = 0.01  #: 1-sigma of each wheel's torque gain error (drawn once per run), fraction
    ground_speed_noise: float = 0.01  #: GNSS / visual-odometry ground speed white noise, m/s

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "encoder_cpr":
                if v is not None and (not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1):
                    raise ValueError(f"encoder_cpr must be None or an integer >= 1, got {v!r}")
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{f.name} must be a finite noise level >= 0, got {v!r}")

    @classmethod
    def noiseless(cls) -> "SensorNoise":
        """Exact truth through the sensors (for tests)."""
        return cls(0.0, 0.0, 0.0, 0.0, None, 0.0, 0.0, 0.0)

    @property
    def is_noiseless(self) -> bool:
        return self == SensorNoise.noiseless()


class SensorSuite:
    """Turns the true state at one sample time into sensor readings.

    Stateful only where the real sensors are: the encoders remember their last count (speed is
    a count difference over the sample interval) and the bias / gain errors are drawn once.
    """

    def __init__(self, noise: SensorNoise, rng: np.random.Generator, interval: float):
        if not (math.isfinite(interval) and interval > 0):
            raise ValueError(f"sample interval must be > 0 s, got {interval!r}")
        self.noise = noise
        self.rng = rng
        self.interval = interval
        # Constant per run: drawn first so that they depend only on the seed.
        self.accel_bias = rng.normal(0.0, noise.accel_bias, 3) if noise.accel_bias > 0 else np.zeros(3)
        self.torque_gain = 1.0 + (rng.normal(0.0, noise.torque_gain_error, 4) if noise.torque_gain_error > 0 else 0.0)
        self._last_counts: np.ndarray | None = None

    def _white(self, sigma: float, n: int | None = None):
        if sigma == 0:
            return np.zeros(n) if n else 0.0
        return self.rng.normal(0.0, sigma, n) if n else float(self.rng.normal(0.0, sigma))

    def encoder_speed(self, wheel_angle: np.ndarray, wheel_speed: np.ndarray) -> np.ndarray:
        """Wheel speed from encoder counts: (count_now - count_before) * 2 pi / cpr / interval.

        ``wheel_angle`` is the true accumulated wheel angle (rad).  With ``encoder_cpr=None`` the
        true instantaneous ``wheel_speed`` is returned.  The first sample has no previous count
        and reads 0 (the rover starts at rest).
        """
        cpr = self.noise.encoder_cpr
        if cpr is None:
            return np.asarray(wheel_speed, dtype=float).copy()
        counts = np.floor(np.asarray(wheel_angle, dtype=float) * cpr / (2.0 * math.pi))
        prev = self._last_counts
        self._last_counts = counts
        if prev is None:
            return np.zeros(4)
        return (counts - prev) * (2.0 * math.pi / cpr) / self.interval

    def read(self, *, specific_force, roll, pitch, yaw_rate, wheel_angle, wheel_speed, wheel_torque, ground_speed) -> dict:
        """Sensor readings as the SensorSample fields (without vehicle_id, seq, stamp)."""
        n = self.noise
        f = np.asarray(specific_force, dtype=float) + self.accel_bias + self._white(n.accel_noise, 3)
        w = self.encoder_speed(wheel_angle, wheel_speed)
        t = np.asarray(wheel_torque, dtype=float) * self.torque_gain + self._white(n.torque_noise, 4)
        return {
            "specific_force": tuple(float(x) for x in f),
            "roll": float(roll + self._white(n.attitude_noise)),
            "pitch": float(pitch + self._white(n.attitude_noise)),
            "yaw_rate": float(yaw_rate + self._white(n.gyro_noise)),
            "wheel_speed": tuple(float(x) for x in w),
            "wheel_torque": tuple(float(x) for x in t),
            "ground_speed": float(ground_speed + self._white(n.ground_speed_noise)),
        }


def per_side_readings(read: dict) -> dict:
    """What a per-side drive measures: one encoder and one motor current per side.  Both wheels of
    a side read the side's speed (mean of the two) and half the side's total torque."""
    w, t = read["wheel_speed"], read["wheel_torque"]
    ws = (0.5 * (w[0] + w[1]), 0.5 * (w[2] + w[3]))
    ts = (0.5 * (t[0] + t[1]), 0.5 * (t[2] + t[3]))
    return {**read, "wheel_speed": (ws[0], ws[0], ws[1], ws[1]), "wheel_torque": (ts[0], ts[0], ts[1], ts[1])}
