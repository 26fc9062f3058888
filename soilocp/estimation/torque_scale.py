"""The torque scale learnt online: one common scale k of the wheel torques (motor constant x 1 /
mass), a slow state, from the longitudinal force balance whenever the robot accelerates or brakes
(issue 27; docs/method.md §15).

Eq. TC (:func:`soilocp.model.force_balance.longitudinal_balance`, the function ``soilocp
calibrate-torque`` fits offline) holds for the means over a window: y = k x - F_MR with
x = sum T_log / R and y = m f_x + I_w sum omega_dot / R.  Per vehicle the state is (k, F_MR), a
Kalman filter stepped once per window (``window`` s of samples, trapezoid means as the offline
fit's, cut at stamp gaps), where the balance holds with a slow F_MR (moving at >= ``min_speed``,
straight, every wheel's slip within ``max_slip``, finite):

* k: prior N(1, ``SoilConfig.gross_scale_sigma``), a random walk of ``scale_walk`` per sqrt(s);
* b: the motion resistance the model does not give (and an accelerometer bias times m), a random walk
  of ``resistance_walk`` N per sqrt(s).  The resistance itself is modelled, not a state: eq. 4 at each
  sample's slips (eq. 1 from the readings), normal forces and the soil's K as the soil stage last
  reported it (:meth:`TorqueScaleBank.feed_soil`, the K fed back; a median reference soil until then),
  :func:`soilocp.model.force_balance.modelled_resistance`, averaged over the window like the other terms.

Only a window whose mean acceleration (f_x less the gravity reaction of the pitch, eq. 20) reaches
``min_accel`` informs k; any other window informs F_MR alone (a Schmidt update: k's gain is 0), so
at constant speed k stays at its prior, however long the drive, and a cruise fixes what F_MR is
at the current k.  The torques the observer sees are the logged ones times k's mean, and the soil
estimator's scale prior becomes k's relative posterior 1-sigma (:class:`soilocp.estimation.soil_strength.SoilBank`,
``scale_sigma``): K's band includes the scale's posterior.  Vectorised over N vehicles: the
single-vehicle stage and the batched path run the same kernel.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.force_balance import longitudinal_balance, modelled_resistance
from soilocp.model.normal_force import STANDARD_GRAVITY, gravity_from_attitude
from soilocp.model.slip import DEFAULT_FLOOR, slip_ratio_unchecked
from soilocp.model.vehicle import VehicleParams


class TorqueScaleConfig(BaseModel):
    """Settings of the online torque scale (module doc)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Learn the torque scale online (False: k = 1 +- soil.gross_scale_sigma always)")
    window: float = Field(1.0, gt=0, description="s: the force balance is taken over window means")
    min_speed: float = Field(0.2, gt=0, description="m/s: slower windows are left out (static friction, stall)")
    max_yaw_rate: float = Field(0.1, gt=0, description="rad/s: a skid turn spends torque on scrubbing the wheels sideways")
    max_gap: float = Field(0.25, gt=0, description="s: a larger step between stamps restarts the window")
    min_accel: float = Field(0.35, gt=0, description="m/s^2: the window's mean acceleration that informs k")
    max_slip: float = Field(
        0.15, gt=0, description="|slip| (eq. 1, from the readings) above which a window informs nothing: motion "
        "resistance grows with slip (eq. 4), and under a slip sweep its swings follow the torque's (the robust-mix "
        "traction test read k 0.84 for 1.00 with them)")
    scale_walk: float = Field(0.002, ge=0, description="Random walk of k, 1/sqrt(s)")
    resistance_walk: float = Field(2.0, ge=0, description="Random walk of F_MR, N/sqrt(s)")
    resistance_sigma: float = Field(60.0, gt=0, description="Prior 1-sigma of F_MR, N (prior mean 0)")
    force_sigma: float = Field(3.0, gt=0, description="1-sigma of a window's balance, N (unmodelled resistance changes)")
    model_resistance: bool = Field(
        False, description="Subtract eq. 4's motion resistance at the soil stage's K and slips from the balance "
        "(modelled_resistance), leaving b the unmodelled rest; False: b is the whole F_MR, a random walk.  Off by "
        "default: measured worse on the accelerate/brake drives (docs/robustness.md, 'ok means ok').  The K is fed "
        "back in the offline and batched paths only: the live observer service runs before the soil service and "
        "models the resistance at the median reference soil and the readings' slips")
    prior_sigma: Optional[float] = Field(
        0.10, gt=0, description="Prior 1-sigma of k (motor constant x 1 / mass) for the online state (None: "
        "soil.gross_scale_sigma, the torque constant's alone): a payload the vehicle file does not know is a scale "
        "error too (+25 %: k 0.80).  K's band combines the windows' information with soil.gross_scale_sigma "
        "(TorqueScaleBank.band_sigma); measured 0.05 / 0.10 / 0.15 in docs/robustness.md")


class TorqueScaleBank:
    """N vehicles' torque scales (module doc): :meth:`step` takes one sample per vehicle in ``ix``."""

    def __init__(self, vehicle: VehicleParams, cfg: TorqueScaleConfig, prior_sigma: float, n_vehicles: int,
                 constants: ModelConstants = DEFAULT_CONSTANTS):
        self.vehicle, self.cfg, self.prior_sigma, self.constants = vehicle, cfg, float(prior_sigma), constants
        # the state's own prior (wider where the mass is as uncertain as the motor constant); the soil estimator's
        # band keeps prior_sigma until a window informs k
        wider = cfg.enabled and cfg.prior_sigma is not None and prior_sigma > 0
        self.state_sigma = float(cfg.prior_sigma) if wider else self.prior_sigma
        n = n_vehicles
        # the soil's K for eq. 4's resistance: the soil stage's last report (feed_soil), until then the median
        # reference soil (the resistance of an unknown soil, within +-30 N of the truth on the reference soils)
        self.k_default = float(np.median(list(constants.soils.values())))
        self.soil_k = np.full(n, self.k_default)
        # the soil stage's slip per wheel (eq. 1 on the observer's filtered speeds), NaN: none yet (the readings')
        self.soil_slip = np.full((n, 4), np.nan)
        self.theta = np.tile([1.0, 0.0], (n, 1))  # (k, F_MR)
        self.P = np.tile(np.diag([self.state_sigma**2, cfg.resistance_sigma**2]), (n, 1, 1))
        self.t0 = np.full(n, np.nan)  # the open window's first stamp
        self.t_prev = np.full(n, np.nan)
        self.prev = np.zeros((n, 4))  # the previous sample's f_x, gravity reaction g_x, sum of torques, F_MR (eq. 4)
        self.area = np.zeros((n, 4))  # their integrals over the open window
        self.w0 = np.zeros(n)  # sum of wheel speeds at the window's start
        self.slow = np.zeros(n, dtype=bool)  # the window has a sample below min_speed, turning fast or not finite

    def apply(self, ix: np.ndarray, inputs):
        """The observer's inputs (:class:`soilocp.estimation.observer_bank.ObserverInputs`) for vehicles ``ix``
        after this sample has stepped the state: torques x k's mean; and k's relative posterior 1-sigma (k,),
        the soil estimator's scale prior, or None while the state is off (the prior stays the config's)."""
        if not self.cfg.enabled or self.prior_sigma <= 0:
            return inputs, None
        inputs.check()  # the observer's own named errors for a bad shape or value, before any arithmetic here
        m, sd = self.step(ix, inputs.stamp, inputs.specific_force_x, inputs.pitch, inputs.yaw_rate,
                          inputs.wheel_speed, inputs.wheel_torque, inputs.ground_speed, inputs.normal_force)
        if np.all(m == 1.0) and np.all(sd == self.state_sigma):  # never learnt: exactly the configured prior
            return inputs, None
        inputs = dataclasses.replace(inputs, wheel_torque=inputs.wheel_torque * m[:, None])
        return inputs, self.band_sigma(sd) / m

    def band_sigma(self, sd: np.ndarray) -> np.ndarray:
        """k's 1-sigma for K's band: the windows' information about k (the state's posterior precision less its
        prior's, ``state_sigma``) combined with the torque constant's prior ``prior_sigma``
        (``soil.gross_scale_sigma``).  With ``state_sigma`` = ``prior_sigma`` this is the state's posterior itself.
        A wider state prior lets the balance move k as far as the data say (a payload the vehicle file does not
        know: 0.80), while a start ramp's one window, which hardly informs k, leaves K's band at the torque
        constant's prior instead of widening it to the state's (sweep-3s-0.1: std/K 0.22 -> 0.44 with 0.15)."""
        if self.state_sigma == self.prior_sigma:
            return sd
        info = np.maximum(1.0 / np.maximum(sd, 1e-12) ** 2 - 1.0 / self.state_sigma**2, 0.0)
        return 1.0 / np.sqrt(1.0 / self.prior_sigma**2 + info)

    def feed_soil(self, ix: np.ndarray, soil_strength, slip=None) -> None:
        """The soil stage's K for vehicles ``ix`` after this sample (NaN or None: none reported, the last is kept):
        the next samples' modelled motion resistance (eq. 4) uses it."""
        k = np.array([np.nan if v is None else v for v in np.atleast_1d(soil_strength)], dtype=float)
        self.soil_k[ix] = np.where(np.isfinite(k) & (k > 0), k, self.soil_k[ix])
        if slip is not None:
            self.soil_slip[ix] = np.asarray(slip, dtype=float).reshape(-1, 4)

    def scale(self, ix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """k's posterior mean and 1-sigma for the vehicles ``ix``."""
        return self.theta[ix, 0].copy(), np.sqrt(self.P[ix, 0, 0])

    def step(self, ix: np.ndarray, stamp, f_x, pitch, yaw_rate, wheel_speed, torque, speed,
             normal_force=None) -> tuple[np.ndarray, np.ndarray]:
        """Add one sample per vehicle (stamps s, f_x m/s^2, pitch rad, yaw rate rad/s, wheel speeds (k, 4)
        rad/s, logged torques (k, 4), ground speed m/s (NaN: the rims' mean), normal forces (k, 4) N (None:
        no modelled resistance, b is the whole F_MR)); close the windows that are full and update their
        vehicles' state.  Returns k's mean and 1-sigma after this sample."""
        cfg, v = self.cfg, self.vehicle
        if not cfg.enabled or self.prior_sigma <= 0:
            return self.scale(ix)
        stamp = np.asarray(stamp, dtype=float)
        w_sum = np.asarray(wheel_speed, dtype=float).sum(axis=1)
        t_sum = np.asarray(torque, dtype=float).sum(axis=1)
        g_x = gravity_from_attitude(0.0, np.asarray(pitch, dtype=float), STANDARD_GRAVITY)[..., 0]
        spd = np.asarray(speed, dtype=float)
        spd = np.where(np.isnan(spd), w_sum / 4.0 * v.wheel_radius, spd)
        slip = slip_ratio_unchecked(np.asarray(wheel_speed, dtype=float) * v.wheel_radius, spd[:, None], 1.0, 0.0,
                                    DEFAULT_FLOOR).slip
        if normal_force is None or not cfg.model_resistance:
            f_mr = np.zeros(stamp.shape)
        else:  # eq. 4 is even in S: the body-frame slip's magnitude is the travel frame's
            s_mr = np.where(np.isfinite(self.soil_slip[ix]), self.soil_slip[ix], slip)
            f_mr = modelled_resistance(np.where(np.isfinite(s_mr), s_mr, 0.0), self.soil_k[ix],
                                       np.asarray(normal_force, dtype=float), np.where(spd < 0, -1.0, 1.0),
                                       self.constants)
        cur = np.stack([np.asarray(f_x, dtype=float), np.broadcast_to(g_x, stamp.shape), t_sum, f_mr], axis=1)
        bad = (~np.isfinite(cur).all(axis=1) | ~np.isfinite(w_sum) | (np.abs(spd) < cfg.min_speed)
               | ~(np.abs(np.asarray(yaw_rate, dtype=float)) <= cfg.max_yaw_rate) | ~(np.abs(slip) <= cfg.max_slip).all(axis=1))
        t_prev = self.t_prev[ix]
        with np.errstate(invalid="ignore"):
            dt = stamp - t_prev
            cont = np.isfinite(dt) & (dt > 0) & (dt <= cfg.max_gap)
        # integrate the open windows (trapezoid, as the offline fit's means)
        area = self.area[ix] + np.where(cont[:, None], 0.5 * (self.prev[ix] + cur) * np.where(cont, dt, 0.0)[:, None], 0.0)
        slow = self.slow[ix] | bad
        span = stamp - self.t0[ix]
        full = cont & (span >= cfg.window - 1e-9)
        if full.any():
            j = np.flatnonzero(full)
            means = area[j] / span[j, None]
            omega_dot = (w_sum[j] - self.w0[ix[j]]) / span[j]
            x, y = longitudinal_balance(means[:, 0], omega_dot, means[:, 2], v, means[:, 3])
            valid = ~slow[j]
            if valid.any():
                jj = j[valid]
                accel = np.abs(means[valid, 0] - means[valid, 1]) >= cfg.min_accel
                self._update(ix[jj], span[jj], x[valid], y[valid], accel)
        restart = ~cont | full  # a new window starts at this sample (a full one closes on it)
        self.t0[ix] = np.where(restart, stamp, self.t0[ix])
        self.w0[ix] = np.where(restart, w_sum, self.w0[ix])
        self.area[ix] = np.where(restart[:, None], 0.0, area)
        self.slow[ix] = np.where(restart, bad, slow)
        self.prev[ix] = cur
        self.t_prev[ix] = stamp
        return self.scale(ix)

    def _update(self, iv: np.ndarray, span: np.ndarray, x: np.ndarray, y: np.ndarray, accel: np.ndarray) -> None:
        """One window's Kalman step per vehicle iv: predict by its span, then y = k x - F_MR, H = (x, -1);
        a window without acceleration updates F_MR only (Schmidt: k's gain 0, Joseph form)."""
        cfg = self.cfg
        th, P = self.theta[iv], self.P[iv]
        P[:, 0, 0] += cfg.scale_walk**2 * span * accel  # k drifts only where it can be seen again
        P[:, 1, 1] += cfg.resistance_walk**2 * span
        H = np.stack([x, -np.ones_like(x)], axis=1)  # (m, 2)
        PH = np.einsum("mij,mj->mi", P, H)
        S = np.einsum("mi,mi->m", H, PH) + cfg.force_sigma**2
        K = PH / S[:, None]
        K[:, 0] = np.where(accel, K[:, 0], 0.0)
        innov = y - np.einsum("mi,mi->m", H, th)
        th = th + K * innov[:, None]
        A = np.eye(2)[None] - K[:, :, None] * H[:, None, :]
        P = np.einsum("mij,mjk,mlk->mil", A, P, A) + cfg.force_sigma**2 * K[:, :, None] * K[:, None, :]
        self.theta[iv], self.P[iv] = th, P
