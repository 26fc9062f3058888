"""The traction observer: N vehicles' Kalman filters, stepped together, k of them at a time.

One implementation serves every caller: the single-vehicle stage (:mod:`soilocp.estimation.pipeline`, N = 1)
and the batched service (:mod:`soilocp.estimation.batch`, N = many).  The filter itself (the model below,
predict, the gated update, re-anchoring, conditioning, resets, the divergence guard; state x (N, n), P (N, n, n)
and gate counters) runs in the compiled core, ``soilocp._core.ObserverCore`` (soilocp/_core/src/observer/),
one call per step for the k vehicles stepped; this module runs the readings clock, the per-side torque split,
the encoder lead, the ground-speed latency and the refresh intervals around that call, and words the reset
reasons from the core's codes.  The tests check it against filterpy's KalmanFilter
(:class:`soilocp.estimation.observer_reference.TractionObserver`), step by step.

Model (paper eqs. 11-15, 26-35, corrected; the state layout is :class:`soilocp.estimation.observer.StateLayout`)
-------------------------------------------------------------------------------------------------
    omega_i_dot = (T_i - R_w (mu_i + mu_xR_i) Fz_i) / I_w      (eqs. 13-15; mu + mu_xR = gross)
    V_dot       = sum(mu_i Fz_i) / m + g sin(pitch) - bias       (longitudinal; REP-103 pitch)
    psi_ddot    = [d(Fx3 + Fx4) - c(Fx1 + Fx2) - M_zR] / I_z      (eqs. 11-12), Fx_i = mu_i Fz_i
    z = [f_x = sum(mu_i Fz_i)/m (eq. 29, docs/method.md §3), psi_dot, omega_1..4, V]

* Motion resistance (docs/method.md §11): eq. 4 is even in slip, so the ``slip`` structure models
  mu_xR_i = d_i (r0 b(S_i) + r1 |S_i|), with b the zero-slip bridge of :mod:`soilocp.model.traction` and
  d_i the wheel's travel direction (smoothed over ``travel_speed``).  The old form
  r0 sgn(S) + r1 S flipped the resistance on braking wheels and biased K 20-30 % low.
* ZOH (eq. 34): A is nilpotent (A @ A = 0), so F = I + A dt, G = b dt + A b dt^2/2 and
  Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3 exactly.
* Update (eq. 35 misprints its indices): standard Kalman update in Joseph form; a measurement row
  whose innovation exceeds ``gate_sigma`` is removed by zeroing its H row and innovation (its gain
  column is then exactly zero), and is taken again after ``gate_patience`` rejections in a row.
* Conditioning and bounds (docs/method.md §12: a net traction coefficient of 3 is not a soil):
  P is symmetrised, its variances clamped and its correlations kept inside (-1, 1); the traction
  and resistance states are projected into physical bounds (``ObserverConfig.mu_bound`` ...).
* Divergence: a non-finite or out-of-physics state resets that vehicle's filter with a counted
  reason (``resets_by_reason``); the next samples are processed normally.
* Skid-steer (``VehicleParams.drive == "per_side"``): the two wheels of a side share one motor, so
  the side's torque (logged as half on each wheel) is split between them by normal force, each
  keeping its own inertia torque, and each side's one speed measurement counts once (its two rows
  carry twice the variance).  Encoder speeds that are interval means (vehicle
  ``wheel_speed_reading``) are led by omega_dot tau / 2 (:mod:`soilocp.estimation.wheel_inputs`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from soilocp._core import ObserverCore
from soilocp.estimation.observer import (N_MEAS, ObserverConfig, StateLayout, continuous_process_noise,
                                         initial_covariance, path_acceleration)
from soilocp.model.checks import check_count, check_index
from soilocp.model.vehicle import VehicleParams
from soilocp.estimation.ground_speed_latency import GroundSpeedLatency
from soilocp.estimation.readings import ReadingClock
from soilocp.estimation.refresh_traction import IntervalTraction, RefreshIntervals, merge
from soilocp.estimation.wheel_inputs import encoder_lead, split_side_torque, wheel_acceleration  # noqa: F401 (re-exported)

#: Normal force (N) below which a wheel is treated as lifted off: no traction information.
LIFT_OFF_FORCE = 1.0

RESET_REASONS = ("start", "time_gap", "stamp_backwards", "non_finite_state", "state_out_of_physics")


_FIELDS_K = ("stamp", "specific_force_x", "yaw_rate", "pitch", "ground_speed")
_FIELDS_K4 = ("wheel_speed", "wheel_torque", "normal_force")


@dataclass
class ObserverInputs:
    """One sensor sample per stepped vehicle, stacked: shapes (k,) or (k, 4)."""

    stamp: np.ndarray
    specific_force_x: np.ndarray
    yaw_rate: np.ndarray
    pitch: np.ndarray
    wheel_speed: np.ndarray
    wheel_torque: np.ndarray
    ground_speed: np.ndarray  # NaN: no independent ground-speed sensor (slip and K not identifiable)
    normal_force: np.ndarray  # as computed by the normal-force stage (clamped to LIFT_OFF_FORCE here)

    def check(self) -> int:
        """k, the number of vehicles, after checking every field's shape ((k,) or (k, 4)), dtype and
        finiteness (the ground speed may be NaN: absent); ValueError naming the field otherwise."""
        st = self.stamp
        k = st.shape[0] if type(st) is np.ndarray and st.ndim == 1 else -1
        # happy path: float arrays of the right shapes, all finite but the ground speed's NaN, in
        # one test; anything else takes the field-by-field check below, which names the field
        flat = (st, self.specific_force_x, self.yaw_rate, self.pitch, self.ground_speed)
        quads = (self.wheel_speed, self.wheel_torque, self.normal_force)
        if k >= 0 and all(type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (k,) for a in flat) \
                and all(type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (k, 4) for a in quads):
            if np.isfinite(np.concatenate([*flat[:4], *quads], axis=None)).all() \
                    and not np.isinf(flat[4]).any():
                return k
        for name in _FIELDS_K:
            a = np.asarray(getattr(self, name), dtype=float)
            # a NaN ground speed means "no independent sensor" (the log's null); nothing else may be NaN
            ok = np.isfinite(a) | (np.isnan(a) if name == "ground_speed" else False)
            if a.shape != (k,) or not np.all(ok):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k},), got {a!r}")
            setattr(self, name, a)
        for name in _FIELDS_K4:
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (k, 4) or not np.all(np.isfinite(a)):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k}, 4), got {a!r}")
            setattr(self, name, a)
        return k


@dataclass
class ObserverBankOutput:
    """The observer's estimate for k vehicles: arrays (k,) or (k, 4)."""

    mu: np.ndarray  # net traction per wheel (eq. 6's mu), inside [-mu_bound, mu_bound]
    mu_var: np.ndarray
    mu_determined: np.ndarray  # bool: the data determine mu_i (posterior 1-sigma <= mu_std_determined)
    resistance: np.ndarray
    gross: np.ndarray  # mu + mu_xR: what the wheel torque balance measures (eq. 13)
    gross_var: np.ndarray
    wheel_speed: np.ndarray
    ground_speed: np.ndarray
    yaw_rate: np.ndarray
    rejected: np.ndarray
    reset: np.ndarray
    reset_reason: list[str]  # "" when no reset
    normal_force: np.ndarray
    speed_age: np.ndarray  # s since the wheel's speed reading was last new (readings.ReadingClock)
    ground_speed_age: np.ndarray  # (k,) s since the ground speed reading was last new
    torque_age: np.ndarray  # s since the wheel's torque reading was last new
    ground_speed_measured: np.ndarray  # (k,) bool: an independent ground speed came with the sample
    ground_speed_latency: np.ndarray  # (k,) s the ground speed was led by (ground_speed_latency; 0: none)
    # a slow stream's refresh at this sample, the pair from the readings (refresh_traction; interval 0: none)
    interval: np.ndarray
    interval_gross: np.ndarray
    interval_gross_var: np.ndarray
    interval_rim_start: np.ndarray
    interval_rim_end: np.ndarray
    interval_ground_start: np.ndarray
    interval_ground_end: np.ndarray
    interval_rim_sigma: np.ndarray
    interval_learning: np.ndarray  # bool: one stream slow, the other at the sample rate: K learns at the refreshes


class ObserverBank:
    """N traction observers stepped together (see the module doc).  ``step(idx, inputs)`` steps
    the vehicles ``idx`` (any subset, each at most once; None: all, in order); vehicles need not
    be in step.  The filter (x, P, gate counters, resets, re-anchoring, the model, predict, update
    and conditioning) runs in the compiled core (``soilocp._core.ObserverCore``, one call per
    step); this class runs the readings clock, the torque split, the encoder lead, the ground-speed
    latency and the refresh intervals around it, and words the reset reasons."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None, n_vehicles: int):
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        if cfg.discretization != "series":
            raise ValueError(f"discretization {cfg.discretization!r}: the observer kernel implements 'series' only")
        self.n_vehicles = n = check_count(n_vehicles)
        self.layout = L = StateLayout.of(cfg.structure)
        r_speed = cfg.r_wheel_speed**2 * (2.0 if vehicle.drive == "per_side" else 1.0)
        r = [cfg.r_specific_force**2, cfg.r_yaw_rate**2, *([r_speed] * 4), cfg.r_ground_speed**2]
        lower, upper = L.bounds(cfg)
        v = vehicle
        self._core = ObserverCore(
            cfg.structure, n, [v.mass, v.wheel_radius, v.wheel_inertia, v.yaw_inertia, v.a, v.b, v.c, v.d],
            [float(y) for y in v.wheel_y], cfg.gate_sigma, cfg.gate_patience, cfg.max_gap, cfg.anchor_speed,
            cfg.variance_floor, cfg.variance_ceiling, cfg.travel_speed, cfg.bridge_slip, cfg.gravity, r,
            np.diagonal(continuous_process_noise(L, cfg)).tolist(), np.diagonal(initial_covariance(L, cfg)).tolist(),
            lower.tolist(), upper.tolist(), [cfg.max_wheel_speed] * 4 + [cfg.max_ground_speed])
        self.last_stamp = np.full(n, np.nan)
        # the raw readings (wheel speeds, ground speed, torques): which are new measurements, and when
        self._readings = ReadingClock(n, 9, cfg.full_rate_share, cfg.repeat_window)
        self._latency = (GroundSpeedLatency(n, cfg.latency_window, cfg.ground_speed_latency_max)
                         if cfg.ground_speed_latency_max > 0 else None)
        self._intervals = RefreshIntervals(n, vehicle.wheel_inertia, vehicle.wheel_radius, cfg.refresh_jerk,
                                           cfg.refresh_min_interval, cfg.refresh_max_interval, cfg.variance_floor,
                                           cfg.r_wheel_speed)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._all = np.arange(n)
        self._all.flags.writeable = False
        self._no_lead = np.zeros((n, 4))

    @property
    def x(self) -> np.ndarray:
        """The states (N, n) (a copy)."""
        return self._core.x

    @property
    def P(self) -> np.ndarray:
        """The covariances (N, n, n) (a copy)."""
        return self._core.P

    @property
    def rejections(self) -> np.ndarray:
        """Consecutive gate rejections of each measurement row (N, 7) (a copy)."""
        return self._core.rejections

    @property
    def resets_by_reason(self) -> dict[str, int]:
        """Resets so far, by reason (RESET_REASONS)."""
        return dict(zip(RESET_REASONS, self._core.resets))

    @property
    def anchored(self) -> int:
        """Wheel-speed states re-anchored to their reading at low speed (docs/method.md §17)."""
        return self._core.anchored

    def step(self, idx, inputs: ObserverInputs) -> ObserverBankOutput:
        """One predict / gated update (eq. 35, standard form) for the vehicles ``idx`` (None: all)."""
        ix = self._all if idx is None else check_index(idx, self.n_vehicles)
        k = inputs.check()
        if k != ix.size:
            raise ValueError(f"inputs hold {k} samples for {ix.size} vehicle indices")
        cfg, L = self.cfg, self.layout
        fz = np.maximum(inputs.normal_force, LIFT_OFF_FORCE)
        # every vehicle in order (idx None, e.g. N = 1): basic slices instead of fancy indexing
        sel = slice(None) if idx is None else ix
        last = self.last_stamp[sel].copy()
        dt = inputs.stamp - last  # NaN at a vehicle's first sample (quiet NaN: no FP warning)
        first = np.isnan(last)
        raw = np.empty((k, 9))
        raw[:, :4] = inputs.wheel_speed
        raw[:, 4] = inputs.ground_speed
        raw[:, 5:] = inputs.wheel_torque
        rd = self._readings.step(sel, inputs.stamp, last, raw, first | (dt < 0))
        fresh, changed, prev = rd.fresh, rd.changed, rd.prev
        per_side = self.vehicle.drive == "per_side"
        interval_mean = self.vehicle.wheel_speed_reading == "interval_mean"
        wheel_z = inputs.wheel_speed
        torque = inputs.wheel_torque
        if per_side or interval_mean:  # otherwise the wheel acceleration is not used
            # a changed encoder speed is a count difference: the mean over the interval since the last
            # change (a quantised repeat in between is the same count rate, and adds no acceleration)
            interval = np.where(changed[:, :4], inputs.stamp[:, None] - rd.changed_before[:, :4], 0.0)
            interval = np.where(interval <= cfg.max_gap, interval, 0.0)
            omega_rate = wheel_acceleration(prev[:, :4], inputs.wheel_speed, interval, changed[:, :4], cfg.max_gap)
            if per_side:
                torque = split_side_torque(inputs.wheel_torque, fz, self.vehicle.wheel_inertia * omega_rate)
            if interval_mean:
                wheel_z = inputs.wheel_speed + encoder_lead(interval, omega_rate)
        age = rd.age
        # dt == 0 (a repeated stamp) is no reset: only the update runs
        restart = first | (dt < 0) | (dt > cfg.max_gap)
        gs = inputs.ground_speed
        if self._latency is not None:  # a late ground speed, led by its measured latency (ground_speed_latency)
            gs = self._latency.step(sel, np.where(restart, np.nan, dt) if restart.any() else dt,
                                    path_acceleration(inputs.specific_force_x, inputs.pitch, cfg.gravity), gs,
                                    fresh[:, 4])
        # the filter, in the core: restarts, model, predict, gated update, re-anchoring, conditioning,
        # divergence guard; dt**3 by numpy's power, whose last bit the port keeps
        x, mu_var, res, gross, gross_var, rejected, codes = self._core.step(
            ix, dt, dt**3, inputs.specific_force_x, inputs.yaw_rate, inputs.pitch, inputs.wheel_speed,
            inputs.ground_speed, wheel_z, gs, torque, fz, np.ascontiguousarray(fresh[:, :5]))
        reasons = [RESET_REASONS[c - 1] if c else "" for c in codes.tolist()]
        self.last_stamp[sel] = inputs.stamp
        latency = self._latency.latency[sel] if self._latency is not None else np.zeros(k)
        ground = x[:, L.v, None] - x[:, L.psi, None] * self._wheel_y
        intervals = self._intervals.step(sel, dt, restart, changed[:, :4], rd.full_rate[:, :4], prev[:, :4],
                                         inputs.wheel_speed, torque, fresh[:, 5:9], fz, ground)
        torque_pairs = self._intervals.torque_refresh(
            sel, dt, restart, changed[:, 5:9], rd.full_rate[:, 5:9], inputs.stamp[:, None] - rd.changed_before[:, 5:9],
            rd.full_rate[:, :4], inputs.stamp[:, None] - rd.changed_before[:, :4], prev[:, :4], inputs.wheel_speed,
            torque, fz, ground)
        intervals = merge(intervals, torque_pairs)
        return ObserverBankOutput(
            mu=x[:, L.mu],
            mu_var=mu_var,
            mu_determined=mu_var <= self.cfg.mu_std_determined**2,
            resistance=res,
            gross=gross,
            gross_var=gross_var,
            wheel_speed=x[:, L.omega],
            ground_speed=x[:, L.v],
            yaw_rate=x[:, L.psi],
            rejected=rejected,
            reset=codes > 0,
            reset_reason=reasons,
            normal_force=fz,
            speed_age=age[:, :4],
            ground_speed_age=age[:, 4],
            torque_age=age[:, 5:9],
            ground_speed_measured=~np.isnan(inputs.ground_speed),
            ground_speed_latency=latency.copy(),
            interval=intervals.interval,
            interval_gross=intervals.gross,
            interval_gross_var=intervals.gross_var,
            interval_rim_start=intervals.rim_start,
            interval_rim_end=intervals.rim_end,
            interval_ground_start=intervals.ground_start,
            interval_ground_end=intervals.ground_end,
            interval_rim_sigma=intervals.rim_sigma,
            interval_learning=intervals.active,
        )
