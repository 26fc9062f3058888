"""The traction observer's kernel: N vehicles' Kalman filters as stacked numpy arrays.

One implementation serves every caller: the single-vehicle stage (:mod:`soilocp.estimation.pipeline`, N = 1),
the batched service (:mod:`soilocp.estimation.batch`, N = many) and, through :func:`model`, the filterpy
reference :class:`soilocp.estimation.observer.TractionObserver` that the tests check this kernel against.
Shapes follow filterpy's procedural style: x (k, n), P (k, n, n), z (k, 7), with k the number of
vehicles stepped now.

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

from soilocp.estimation.kalman_kernel import _arange, _bmv, condition, gated_update, outlier_variance, predict
from soilocp.estimation.observer import (N_MEAS, ModelBuffers, ObserverConfig, StateLayout, continuous_process_noise,
                                         initial_covariance, model, path_acceleration, resistance_map,
                                         travel_direction)
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


class _Workspace:
    """Per-step scratch arrays for up to k vehicles stepped together, allocated once (a step of
    k' <= k vehicles uses their first k' rows): the model's A, b, H
    (:class:`soilocp.estimation.observer.ModelBuffers`), the raw readings, z, R and the
    gross-traction Jacobian J = [I | M] of :meth:`ObserverBank._output`."""

    def __init__(self, layout: StateLayout, k: int, r: np.ndarray):
        self.model = ModelBuffers(layout, k)
        self.raw = np.empty((k, 9))
        self.z = np.empty((k, N_MEAS))
        self.r = np.broadcast_to(r, (k, N_MEAS))
        self.J = np.zeros((k, 4, layout.n))
        self.J[:, :, layout.mu] = np.eye(4)


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


class ObserverBank:
    """N traction observers stepped together (see the module doc).  ``step(idx, inputs)`` steps
    the vehicles ``idx`` (any subset, each at most once; None: all, in order); vehicles need not
    be in step."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None, n_vehicles: int):
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        if cfg.discretization != "series":
            raise ValueError(f"discretization {cfg.discretization!r}: the observer kernel implements 'series' only")
        self.n_vehicles = n = check_count(n_vehicles)
        self.layout = L = StateLayout.of(cfg.structure)
        self._Qc = continuous_process_noise(L, cfg)
        self._q = np.diagonal(self._Qc).copy()  # Qc is diagonal: A Qc is a column scaling
        r_speed = cfg.r_wheel_speed**2 * (2.0 if vehicle.drive == "per_side" else 1.0)
        self._r = np.array([cfg.r_specific_force**2, cfg.r_yaw_rate**2, *([r_speed] * 4), cfg.r_ground_speed**2])
        self.x = np.zeros((n, L.n))
        self.P = np.zeros((n, L.n, L.n))
        self.last_stamp = np.full(n, np.nan)
        self.rejections = np.zeros((n, N_MEAS), dtype=int)
        self.resets_by_reason: dict[str, int] = {r: 0 for r in RESET_REASONS}
        #: wheel-speed states re-anchored to their reading at low speed (:func:`anchor_wheel_speeds`)
        self.anchored = 0
        # the raw readings (wheel speeds, ground speed, torques): which are new measurements, and when
        self._readings = ReadingClock(n, 9, cfg.full_rate_share, cfg.repeat_window)
        self._latency = (GroundSpeedLatency(n, cfg.latency_window, cfg.ground_speed_latency_max)
                         if cfg.ground_speed_latency_max > 0 else None)
        self._intervals = RefreshIntervals(n, vehicle.wheel_inertia, vehicle.wheel_radius, cfg.refresh_jerk,
                                           cfg.refresh_min_interval, cfg.refresh_max_interval, cfg.variance_floor,
                                           cfg.r_wheel_speed)
        self._P0 = initial_covariance(L, cfg)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._lower, self._upper = L.bounds(cfg)
        # |omega_1..4| and |V| (contiguous in the state) above these are divergence
        self._speed_limits = np.array([cfg.max_wheel_speed] * 4 + [cfg.max_ground_speed])
        self._all = _arange(n)
        self._ws = _Workspace(L, n, self._r)

    def state_slip(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-wheel slip (eq. 1, floor 0.05 m/s) and travel direction of states x (k, n): the
        regressors of the ``slip`` structure, taken from the prior so the model stays linear."""
        L = self.layout
        rim = x[:, L.omega] * self.vehicle.wheel_radius
        ground = x[:, L.v:L.v + 1] - x[:, L.psi:L.psi + 1] * self._wheel_y
        slip = (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)
        return slip, travel_direction(ground, self.cfg.travel_speed)

    def maps(self, x: np.ndarray) -> np.ndarray:
        """The resistance map (k, 4, n_res) at states x (k, n): mu_MR,i = d_i (r0 b(|S_i|) + r1 |S_i|)
        (eq. 4 with |S|, even in slip, docs/method.md §11), d_i the direction of travel."""
        if self.layout.n_res != 2:
            return resistance_map(self.layout, np.zeros((x.shape[0], 4)), None, self.cfg.bridge_slip)
        slip, travel = self.state_slip(x)
        return resistance_map(self.layout, slip, travel, self.cfg.bridge_slip)

    def _reset(self, ix: np.ndarray, rows: np.ndarray, x: np.ndarray, P: np.ndarray, inputs: ObserverInputs,
               reasons: list[str], why: str) -> None:
        L = self.layout
        for j in np.flatnonzero(rows):
            x0 = np.zeros(L.n)
            x0[L.omega] = inputs.wheel_speed[j]
            gs = inputs.ground_speed[j]
            x0[L.v] = gs if not np.isnan(gs) else float(np.mean(inputs.wheel_speed[j])) * self.vehicle.wheel_radius
            x0[L.psi] = inputs.yaw_rate[j]
            x[j] = np.clip(x0, self._lower, self._upper)
            P[j] = self._P0
            self.rejections[ix[j]] = 0
            reasons[j] = why
            self.resets_by_reason[why] += 1

    def step(self, idx, inputs: ObserverInputs) -> ObserverBankOutput:
        """One predict / gated update (eq. 35, standard form) for the vehicles ``idx`` (None: all)."""
        ix = self._all if idx is None else check_index(idx, self.n_vehicles)
        k = inputs.check()
        if k != ix.size:
            raise ValueError(f"inputs hold {k} samples for {ix.size} vehicle indices")
        cfg, L = self.cfg, self.layout
        ws = self._ws
        fz = np.maximum(inputs.normal_force, LIFT_OFF_FORCE)
        # every vehicle in order (idx None, e.g. N = 1): basic slices instead of fancy indexing
        sel = slice(None) if idx is None else ix
        x, P = self.x[sel].copy(), self.P[sel].copy()
        last = self.last_stamp[sel].copy()
        dt = inputs.stamp - last  # NaN at a vehicle's first sample (quiet NaN: no FP warning)
        reasons = [""] * k
        first = np.isnan(last)
        raw = ws.raw[:k]
        raw[:, :4] = inputs.wheel_speed
        raw[:, 4] = inputs.ground_speed
        raw[:, 5:] = inputs.wheel_torque
        rd = self._readings.step(sel, inputs.stamp, last, raw, first | (dt < 0))
        fresh, changed, prev = rd.fresh, rd.changed, rd.prev
        per_side = self.vehicle.drive == "per_side"
        interval_mean = self.vehicle.wheel_speed_reading == "interval_mean"
        lead = None
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
                lead = encoder_lead(interval, omega_rate)
        age = rd.age
        # dt == 0 (a repeated stamp) is no reset: only the update runs
        restart = first | (dt < 0) | (dt > cfg.max_gap)
        any_restart = bool(restart.any())
        if any_restart:
            for rows, why in ((first, "start"), (~first & (dt < 0), "stamp_backwards"),
                              (~first & (dt > cfg.max_gap), "time_gap")):
                if rows.any():
                    self._reset(ix, rows, x, P, inputs, reasons, why)
        gs = inputs.ground_speed
        if self._latency is not None:  # a late ground speed, led by its measured latency (ground_speed_latency)
            gs = self._latency.step(sel, np.where(restart, np.nan, dt) if any_restart else dt,
                                    path_acceleration(inputs.specific_force_x, inputs.pitch, cfg.gravity), gs,
                                    fresh[:, 4])
        A, b, H = model(L, self.vehicle, fz, torque, inputs.pitch, self.maps(x), cfg.gravity, out=ws.model)
        rejected = np.zeros(k, dtype=int)
        every = not any(reasons)  # the usual case: no mask copies, same arithmetic
        run = slice(None) if every else np.array([not r for r in reasons])
        if every or run.any():
            xr, Pr = (x, P) if every else (x[run], P[run])
            dtr = dt if every else dt[run]
            moving = dtr > 0
            if moving.all():
                xr, Pr = predict(xr, Pr, A if every else A[run], b if every else b[run], self._Qc, dtr, self._q)
            elif moving.any():
                xr[moving], Pr[moving] = predict(xr[moving], Pr[moving], A[run][moving], b[run][moving], self._Qc,
                                                 dtr[moving], self._q)
            no_gs = np.isnan(gs)
            z = ws.z[:k]
            z[:, 0] = inputs.specific_force_x
            z[:, 1] = inputs.yaw_rate
            if lead is None:
                z[:, 2:6] = inputs.wheel_speed
            else:
                np.add(inputs.wheel_speed, lead, out=z[:, 2:6])
            z[:, 6] = np.where(no_gs, 0.0, gs)
            available = np.empty(z.shape, dtype=bool)
            available[:, :2] = True
            available[:, 2:7] = fresh[:, :5]  # held wheel / ground speeds are no new measurement
            available[:, 6] &= ~no_gs
            if not every:
                z, available = z[run], available[run]
            rows = sel if every else ix[run]
            r = ws.r[:k] if every else ws.r[:k][run]
            xr, Pr, counts, _, keep = gated_update(xr, Pr, z, r, H if every else H[run],
                                                   cfg.gate_sigma, self.rejections[rows], cfg.gate_patience, available)
            self.rejections[rows] = counts
            rejected[run] = (available & ~keep).sum(axis=1)
            if cfg.anchor_speed > 0:
                self.anchored += anchor_wheel_speeds(xr, Pr, z, available & ~keep, available, L,
                                                     self.vehicle.wheel_radius, cfg.anchor_speed, self._r[2])
            xr, Pr = condition(xr, Pr, self._lower, self._upper, cfg.variance_floor, cfg.variance_ceiling)
            if every:
                x, P = xr, Pr
            else:
                x[run], P[run] = xr, Pr
        # divergence guard: a non-finite or out-of-physics state restarts that vehicle's filter
        speeds = np.abs(x[:, L.omega.start:L.v + 1])
        if not ((speeds <= self._speed_limits).all() and np.isfinite(P).all() and np.isfinite(x).all()):
            finite = np.isfinite(x).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
            sane = (speeds <= self._speed_limits).all(axis=1)
            for bad, why in ((~finite, "non_finite_state"), (finite & ~sane, "state_out_of_physics")):
                if bad.any():
                    self._reset(ix, bad, x, P, inputs, reasons, why)
        self.x[sel], self.P[sel] = x, P
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
        return self._output(x, P, fz, rejected, reasons, age, ~np.isnan(inputs.ground_speed), latency, intervals, ws)

    def _output(self, x, P, fz, rejected, reasons, age, measured, latency, intervals: IntervalTraction,
                ws: _Workspace) -> ObserverBankOutput:
        L, k = self.layout, x.shape[0]
        M = self.maps(x)
        res = _bmv(M, x[:, L.res]) if L.n_res else np.zeros((k, 4))
        # gross_i = mu_i + (M x_res)_i: its variance from the joint covariance (determined by the
        # wheel torque balance even when the net / resistance split is not: docs/method.md §12)
        J = ws.J[:k]
        if L.n_res:
            J[:, :, L.res] = M
        # x and P are this step's own arrays (self.x / self.P hold copies): the outputs are views of them
        mu_var = np.diagonal(P, axis1=1, axis2=2)[:, L.mu]
        mu = x[:, L.mu]
        return ObserverBankOutput(
            mu=mu,
            mu_var=mu_var,
            mu_determined=mu_var <= self.cfg.mu_std_determined**2,
            resistance=res,
            gross=mu + res,
            # a quadratic form of the conditioned P: floored, since clamping correlations keeps P only
            # nearly positive semi-definite
            gross_var=np.maximum(((J @ P) * J).sum(axis=2), self.cfg.variance_floor),
            wheel_speed=x[:, L.omega],
            ground_speed=x[:, L.v],
            yaw_rate=x[:, L.psi],
            rejected=rejected,
            reset=np.array([bool(r) for r in reasons]),
            reset_reason=reasons,
            normal_force=fz,
            speed_age=age[:, :4],
            ground_speed_age=age[:, 4],
            torque_age=age[:, 5:9],
            ground_speed_measured=measured,
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
