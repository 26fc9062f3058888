"""The filterpy reference of the traction observer, for one vehicle: the tests' oracle, not the product.

The product's observer is :mod:`soilocp.estimation.observer_bank`, whose filter runs in the compiled
core (``soilocp._core.ObserverCore``, soilocp/_core/src/observer).  This class runs the model of
:func:`soilocp.estimation.observer.model`, the same gating rule (:func:`outlier_variance`), the same
low-speed re-anchoring (:func:`anchor_wheel_speeds`) and the same conditioning (:func:`condition`),
written here in numpy, on filterpy's ``KalmanFilter`` (its ``predict`` and its ``update`` on the kept
rows), so that the tests check the core's predict / update against a well-kept implementation, step
by step, on real drives (``tests/test_batch.py``, ``tests/test_observer_core.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from soilocp.estimation.observer import (N_MEAS, ObserverConfig, StateLayout, continuous_process_noise, discretize, initial_covariance,
                       model, path_acceleration, resistance_map, travel_direction)
from soilocp.estimation.observer_bank import LIFT_OFF_FORCE
from soilocp.estimation.wheel_inputs import encoder_lead, split_side_torque, wheel_acceleration
from soilocp.model.vehicle import VehicleParams
from soilocp.estimation.ground_speed_latency import GroundSpeedLatency
from soilocp.estimation.readings import ReadingClock


def _diag(M: np.ndarray) -> np.ndarray:
    """The diagonals of a C-contiguous stack of square matrices M (k, n, n) as a writable (k, n) view."""
    n = M.shape[-1]
    return M.reshape(M.shape[0], n * n)[:, :: n + 1]


def outlier_variance(innov: np.ndarray, hph: np.ndarray, r: np.ndarray, gate_sigma: float, keep: np.ndarray):
    """Measurement variance of each row (k, m) for the update of eq. 35 (docs/method.md §12): R
    where the row passes its gate (``keep``);
    for a row beyond it, the variance that puts its innovation exactly on the gate
    (nu^2 / gate^2 - H P H^T, Huber's weighting): a sensor spike moves the state by at most a
    gate's worth, and a model that is off (a traction change faster than the random walk) is
    still followed, instead of coasting on a prediction that runs away."""
    return np.where(keep, r, np.maximum(r, innov**2 / gate_sigma**2 - hph))


def condition(x: np.ndarray, P: np.ndarray, lower: np.ndarray, upper: np.ndarray, floor: float, ceiling: float):
    """Keep P (k, n, n) symmetric positive semi-definite (symmetrise, clamp variances to [floor,
    ceiling] and correlations to +-0.9999) and project x (k, n) into the physical box [lower,
    upper] (each (n,)): the state bounds of docs/method.md §12 (|mu| <= 1.5, resistance within its
    physical range).  Returns x, P (new arrays)."""
    # minimum / maximum in place of np.clip: the same values, without np.clip's dispatch overhead
    P = P + P.transpose(0, 2, 1)
    P /= 2.0
    var = np.minimum(np.maximum(_diag(P), floor), ceiling)
    sd = np.sqrt(var)
    lim = (0.9999 * sd)[:, :, None] * sd[:, None, :]
    np.minimum(P, lim, out=P)
    np.negative(lim, out=lim)
    np.maximum(P, lim, out=P)
    np.copyto(_diag(P), var)
    return np.minimum(np.maximum(x, lower), upper), P


def anchor_wheel_speeds(x: np.ndarray, P: np.ndarray, z: np.ndarray, rejected: np.ndarray, available: np.ndarray,
                        layout, wheel_radius: float, anchor_speed: float, r_speed: float) -> int:
    """At low speed a rejected wheel-speed reading re-anchors its wheel's speed state (in place, x (k, n),
    P (k, n, n), readings z (k, 7), rejected rows (k, 7)): the state takes the reading, its variance the
    reading's (``r_speed``, rad^2/s^2), its correlations none.  So does the last reading of a wheel whose
    reading is not new now (``available`` (k, 7) False: a repeat) when the state has left it by more than
    ``anchor_speed`` / 3 in rim speed (the closed-loop stall on firm soil: single samples of 3.7 rad/s against
    an encoder's 1.19).  Returns how many wheels were re-anchored (docs/method.md §17).

    Below ``anchor_speed`` (m/s, rim and ground) the wheel equation (eq. 13) is stiff (docs/method.md §10)
    and the traction state that balances the torque is itself poorly known (a stall: slip ~1, any soil):
    the prediction leaves the encoder within a step, the gate rejects the encoder, and the filtered speed
    ran away (7 rad/s against 0.48, issue 27) and fed K a wrong slip.  The encoder is the one measurement
    of the wheel's speed; the gate protects against its outliers at speed, not at a stall."""
    L = layout
    away = np.abs(x[:, L.omega] - z[:, 2:6]) * wheel_radius > anchor_speed / 3.0
    wheels = rejected[:, 2:6] | (~available[:, 2:6] & away)
    if not wheels.any():
        return 0
    low = (np.abs(z[:, 2:6]) * wheel_radius < anchor_speed) & (np.abs(x[:, L.v]) < anchor_speed)[:, None]
    rows, w = np.nonzero(wheels & low)
    if rows.size == 0:
        return 0
    col = L.omega.start + w
    x[rows, col] = z[rows, 2 + w]
    P[rows, col, :] = 0.0
    P[rows, :, col] = 0.0
    P[rows, col, col] = r_speed
    return int(rows.size)


@dataclass
class ObserverEstimate:
    """One vehicle's estimate: arrays (4,) per wheel."""

    mu: np.ndarray
    mu_var: np.ndarray
    resistance: np.ndarray
    gross: np.ndarray
    gross_var: np.ndarray
    wheel_speed: np.ndarray
    ground_speed: float
    yaw_rate: float
    rejected: int
    reset: bool


class TractionObserver:
    """One vehicle's traction observer on filterpy's KalmanFilter (the kernel's reference)."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None = None):
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        self.layout = L = StateLayout.of(cfg.structure)
        self._Qc = continuous_process_noise(L, cfg)
        r_speed = cfg.r_wheel_speed**2 * (2.0 if vehicle.drive == "per_side" else 1.0)
        self._R_diag = np.array([cfg.r_specific_force**2, cfg.r_yaw_rate**2, *([r_speed] * 4), cfg.r_ground_speed**2])
        self._R = np.diag(self._R_diag)
        self.kf = KalmanFilter(dim_x=L.n, dim_z=N_MEAS)
        self._last_stamp: float | None = None
        self._rejections = np.zeros(N_MEAS, dtype=int)
        self._readings = ReadingClock(1, 5, cfg.full_rate_share, cfg.repeat_window)  # wheel speeds, ground speed
        self._latency = (GroundSpeedLatency(1, cfg.latency_window, cfg.ground_speed_latency_max)
                         if cfg.ground_speed_latency_max > 0 else None)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._lower, self._upper = L.bounds(cfg)
        self.steps = 0

    def _initialise(self, wheel_speed, ground_speed, yaw_rate) -> None:
        L = self.layout
        x = np.zeros(L.n)
        x[L.omega] = wheel_speed
        x[L.v] = ground_speed if not np.isnan(ground_speed) else float(np.mean(wheel_speed)) * self.vehicle.wheel_radius
        x[L.psi] = yaw_rate
        self.kf.x = np.clip(x, self._lower, self._upper)
        self.kf.P = initial_covariance(L, self.cfg)
        self._rejections[:] = 0

    def _map(self) -> np.ndarray:
        L, x, v = self.layout, self.kf.x, self.vehicle
        rim = x[L.omega] * v.wheel_radius
        ground = x[L.v] - x[L.psi] * self._wheel_y
        slip = (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)
        return resistance_map(L, slip, travel_direction(ground, self.cfg.travel_speed), self.cfg.bridge_slip)

    def step(self, stamp: float, specific_force_x: float, yaw_rate: float, pitch: float,
             wheel_speed, wheel_torque, ground_speed: float, normal_force) -> ObserverEstimate:
        """One predict/update cycle (eq. 35, standard form) for a sample at ``stamp``."""
        fz = np.maximum(np.asarray(normal_force, dtype=float), LIFT_OFF_FORCE)
        torque = np.asarray(wheel_torque, dtype=float)
        omega = np.asarray(wheel_speed, dtype=float)
        ground_speed = float("nan") if ground_speed is None else float(ground_speed)
        dt = None if self._last_stamp is None else stamp - self._last_stamp
        reset = dt is None or dt < 0 or dt > self.cfg.max_gap
        speeds = np.array([*omega, ground_speed])
        last = np.nan if self._last_stamp is None else self._last_stamp
        fresh, changed, prev, changed_before, _, _ = (
            a[0] for a in self._readings.step(slice(None), np.array([stamp]), np.array([last]), speeds[None],
                                              np.array([dt is None or dt < 0])))
        interval = np.where(changed[:4], stamp - changed_before[:4], 0.0)  # a count difference's interval
        interval = np.where(interval <= self.cfg.max_gap, interval, 0.0)
        omega_rate = wheel_acceleration(prev[None, :4], omega[None], interval[None], changed[None, :4],
                                        self.cfg.max_gap)[0]
        if self.vehicle.drive == "per_side":
            torque = split_side_torque(torque[None], fz[None], self.vehicle.wheel_inertia * omega_rate[None])[0]
        lead = encoder_lead(interval, omega_rate) if self.vehicle.wheel_speed_reading == "interval_mean" else 0.0
        read_speed = ground_speed
        if self._latency is not None:
            read_speed = float(self._latency.step(slice(None), np.array([np.nan if reset else dt]),
                                                  np.array([path_acceleration(specific_force_x, pitch, self.cfg.gravity)]),
                                                  np.array([ground_speed]), np.array([bool(fresh[4])]))[0])
        if reset:
            self._initialise(omega, ground_speed, yaw_rate)
        A, b, H = (m[0] for m in model(self.layout, self.vehicle, fz[None], torque[None], np.array([pitch]),
                                       self._map()[None], self.cfg.gravity))
        if not reset and dt > 0:  # a repeated stamp (dt == 0) is a second measurement of the same instant
            F, G, Qd = discretize(A, b, self._Qc, dt, self.cfg.discretization)
            self.kf.predict(u=np.ones(1), B=G[:, None], F=F, Q=Qd)
        self._last_stamp = stamp
        omega_now = omega + lead
        z = np.array([specific_force_x, yaw_rate, *omega_now, np.nan_to_num(read_speed)])
        rejected = 0
        if not reset:
            innov = z - H @ self.kf.x
            hph = np.einsum("ij,jk,ik->i", H, self.kf.P, H)
            keep = (innov**2 <= (self.cfg.gate_sigma**2) * (hph + self._R_diag)) | (self._rejections >= self.cfg.gate_patience)
            available = np.ones(N_MEAS, dtype=bool)
            available[2:7] = fresh  # held wheel / ground speeds are no new measurement
            available[6] &= not np.isnan(ground_speed)
            self._rejections = np.where(available, np.where(keep, 0, self._rejections + 1), self._rejections)
            keep &= available
            rejected = int(np.count_nonzero(available & ~keep))
            idx = np.flatnonzero(available)
            r = outlier_variance(innov, hph, self._R_diag, self.cfg.gate_sigma, keep)
            self.kf.update(z[idx], R=np.diag(r[idx]), H=H[idx])
            if self.cfg.anchor_speed > 0:  # the kernel's low-speed re-anchoring (docs/method.md §17)
                xa, Pa = self.kf.x[None].copy(), self.kf.P[None].copy()
                if anchor_wheel_speeds(xa, Pa, z[None], (available & ~keep)[None], available[None], self.layout,
                                       self.vehicle.wheel_radius, self.cfg.anchor_speed, self._R_diag[2]):
                    self.kf.x, self.kf.P = xa[0], Pa[0]
            x, P = condition(self.kf.x[None], self.kf.P[None], self._lower, self._upper,
                             self.cfg.variance_floor, self.cfg.variance_ceiling)
            self.kf.x, self.kf.P = x[0], P[0]
        self.steps += 1
        return self.estimate(rejected, reset)

    def estimate(self, rejected: int = 0, reset: bool = False) -> ObserverEstimate:
        L = self.layout
        x, P = self.kf.x, self.kf.P
        M = self._map()
        res = M @ x[L.res] if L.n_res else np.zeros(4)
        J = np.zeros((4, L.n))
        J[:, L.mu] = np.eye(4)
        if L.n_res:
            J[:, L.res] = M
        return ObserverEstimate(
            mu=x[L.mu].copy(),
            mu_var=np.diag(P)[L.mu].copy(),
            resistance=res,
            gross=x[L.mu] + res,
            gross_var=np.maximum(np.einsum("ij,jk,ik->i", J, P, J), self.cfg.variance_floor),
            wheel_speed=x[L.omega].copy(),
            ground_speed=float(x[L.v]),
            yaw_rate=float(x[L.psi]),
            rejected=rejected,
            reset=reset,
        )
