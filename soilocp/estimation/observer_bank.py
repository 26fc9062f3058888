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
from functools import lru_cache

import numpy as np

from soilocp.estimation.observer import (N_MEAS, ObserverConfig, StateLayout, continuous_process_noise, initial_covariance, model,
                       resistance_map, travel_direction)
from soilocp.model.checks import check_count, check_index
from soilocp.model.vehicle import VehicleParams
from soilocp.estimation.wheel_inputs import encoder_lead, split_side_torque, wheel_acceleration  # noqa: F401 (re-exported)

#: Normal force (N) below which a wheel is treated as lifted off: no traction information.
LIFT_OFF_FORCE = 1.0

RESET_REASONS = ("start", "time_gap", "stamp_backwards", "non_finite_state", "state_out_of_physics")


@lru_cache(maxsize=None)
def _eye(n: int) -> np.ndarray:
    """I (n, n), built once per size (read-only): the hot path allocates no constant."""
    e = np.eye(n)
    e.flags.writeable = False
    return e


@lru_cache(maxsize=None)
def _arange(n: int) -> np.ndarray:
    a = np.arange(n)
    a.flags.writeable = False
    return a


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
        k = np.shape(self.stamp)[0] if np.ndim(self.stamp) == 1 else -1
        # happy path: float arrays of the right shapes, all finite but the ground speed's NaN, in
        # one test; anything else takes the field-by-field check below, which names the field
        arrs = [getattr(self, n) for n in _FIELDS_K + _FIELDS_K4]
        if k >= 0 and all(type(a) is np.ndarray and a.dtype == np.float64 for a in arrs) \
                and all(a.shape == (k,) for a in arrs[:5]) and all(a.shape == (k, 4) for a in arrs[5:]):
            gs = arrs[4]
            if np.isfinite(np.concatenate([*arrs[:4], *arrs[5:]], axis=None)).all() \
                    and not np.isinf(gs).any():
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
    speed_age: np.ndarray  # s since the wheel's speed reading last changed
    ground_speed_age: np.ndarray  # (k,) s since the ground speed reading last changed
    torque_age: np.ndarray  # s since the wheel's torque reading last changed
    ground_speed_measured: np.ndarray  # (k,) bool: an independent ground speed came with the sample


def fresh_readings(prev: np.ndarray, now: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Which readings (k, c) are new: a value exactly equal to the previous sample's is a reading
    held by a slow driver or logger (docs/method.md §13: wheel speeds and currents refresh at
    0.5-5 Hz and are held in between), not a new measurement.  Everything is new at a start."""
    return (now != prev) | first[:, None]


def predict(x: np.ndarray, P: np.ndarray, A: np.ndarray, b: np.ndarray, Qc: np.ndarray, dt: np.ndarray):
    """ZOH prediction (eq. 34, exact series: A nilpotent) over dt (k,) > 0: returns x (k, n), P (k, n, n)."""
    eye = _eye(x.shape[1])
    d3 = dt[:, None, None]
    F = eye + A * d3
    G = b * dt[:, None] + np.einsum("kij,kj->ki", A, b) * (dt * dt / 2.0)[:, None]
    AQ = A @ Qc
    Qd = Qc * d3 + (AQ + AQ.transpose(0, 2, 1)) * (d3 * d3 / 2.0) + AQ @ A.transpose(0, 2, 1) * (d3**3 / 3.0)
    return np.einsum("kij,kj->ki", F, x) + G, F @ P @ F.transpose(0, 2, 1) + Qd


def outlier_variance(innov: np.ndarray, hph: np.ndarray, r: np.ndarray, gate_sigma: float, keep: np.ndarray):
    """Measurement variance of each row for the update: R where the row passes its gate (``keep``);
    for a row beyond it, the variance that puts its innovation exactly on the gate
    (nu^2 / gate^2 - H P H^T, Huber's weighting): a sensor spike moves the state by at most a
    gate's worth, and a model that is off (a traction change faster than the random walk) is
    still followed, instead of coasting on a prediction that runs away."""
    return np.where(keep, r, np.maximum(r, innov**2 / gate_sigma**2 - hph))


def gated_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, r: np.ndarray, H: np.ndarray,
                 gate_sigma: float, counts: np.ndarray, patience: int, available: np.ndarray | None = None):
    """Kalman update (Joseph form) of x (k, n), P (k, n, n) by z (k, m) with diagonal R (k, m) and
    H (k, m, n).  Each row is gated on its innovation (|nu| <= gate_sigma sqrt(S_ii)); a row beyond
    it is down-weighted (:func:`outlier_variance`) unless it was beyond it ``patience`` times in a
    row (then the model, not the sensor, is off: full weight again).  Rows not ``available`` (k, m)
    (a held, not a new, reading) take no part and count nothing.  Returns x, P, the new counts
    (k, m), the normalised innovation squares nu_i^2 / S_ii (k, m) of the prior and the rows taken
    at full weight (k, m)."""
    innov = z - np.einsum("kij,kj->ki", H, x)
    hph = np.einsum("kij,kij->ki", H @ P, H)
    nis = innov**2 / (hph + r)
    keep = (nis <= gate_sigma**2) | (counts >= patience)
    avail = np.ones_like(keep) if available is None else available
    counts = np.where(avail, np.where(keep, 0, counts + 1), counts)
    keep &= avail
    upd = avail.any(axis=1)
    if upd.any():
        av = avail[upd]
        Hm = H[upd] * av[:, :, None]  # a row not available: zero H row and innovation, harmless R
        y = innov[upd] * av
        rm = np.where(av, outlier_variance(innov[upd], hph[upd], r[upd], gate_sigma, keep[upd]), 1.0)
        Pu = P[upd]
        PHT = Pu @ Hm.transpose(0, 2, 1)
        S = Hm @ PHT
        dg = _arange(S.shape[1])
        S[:, dg, dg] += rm
        K = PHT @ np.linalg.inv(S)
        x = x.copy()
        P = P.copy()
        x[upd] = x[upd] + np.einsum("kij,kj->ki", K, y)
        IKH = _eye(x.shape[1]) - K @ Hm
        P[upd] = IKH @ Pu @ IKH.transpose(0, 2, 1) + (K * rm[:, None, :]) @ K.transpose(0, 2, 1)
    return x, P, counts, nis, keep & avail


def condition(x: np.ndarray, P: np.ndarray, lower: np.ndarray, upper: np.ndarray, floor: float, ceiling: float):
    """Keep P symmetric positive semi-definite (symmetrise, clamp variances to [floor, ceiling] and
    correlations to +-0.9999) and project x into the physical box [lower, upper] (each (n,)).
    Returns x, P (new arrays)."""
    P = (P + P.transpose(0, 2, 1)) / 2.0
    dg = _arange(P.shape[1])
    var = np.clip(P[:, dg, dg], floor, ceiling)
    sd = np.sqrt(var)
    lim = 0.9999 * sd[:, :, None] * sd[:, None, :]
    P = np.clip(P, -lim, lim)
    P[:, dg, dg] = var
    return np.clip(x, lower, upper), P


class ObserverBank:
    """N traction observers stepped together (see the module doc).  ``step(idx, inputs)`` steps
    the vehicles ``idx`` (any subset, each at most once); vehicles need not be in step."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None, n_vehicles: int):
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        if cfg.discretization != "series":
            raise ValueError(f"discretization {cfg.discretization!r}: the observer kernel implements 'series' only")
        self.n_vehicles = n = check_count(n_vehicles)
        self.layout = L = StateLayout.of(cfg.structure)
        self._Qc = continuous_process_noise(L, cfg)
        r_speed = cfg.r_wheel_speed**2 * (2.0 if vehicle.drive == "per_side" else 1.0)
        self._r = np.array([cfg.r_specific_force**2, cfg.r_yaw_rate**2, *([r_speed] * 4), cfg.r_ground_speed**2])
        self.x = np.zeros((n, L.n))
        self.P = np.zeros((n, L.n, L.n))
        self.last_stamp = np.full(n, np.nan)
        self.rejections = np.zeros((n, N_MEAS), dtype=int)
        self.resets_by_reason: dict[str, int] = {r: 0 for r in RESET_REASONS}
        # the last raw readings (wheel speeds, ground speed, torques) and when each last changed
        self._prev = np.full((n, 9), np.nan)
        self._changed_at = np.full((n, 9), np.nan)
        self._P0 = initial_covariance(L, cfg)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._lower, self._upper = L.bounds(cfg)

    def state_slip(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-wheel slip (eq. 1, floor 0.05 m/s) and travel direction of states x (k, n): the
        regressors of the ``slip`` structure, taken from the prior so the model stays linear."""
        L = self.layout
        rim = x[:, L.omega] * self.vehicle.wheel_radius
        ground = x[:, L.v][:, None] - x[:, L.psi][:, None] * self._wheel_y
        slip = (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)
        return slip, travel_direction(ground, self.cfg.travel_speed)

    def maps(self, x: np.ndarray) -> np.ndarray:
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
        """One predict / gated update (eq. 35, standard form) for the vehicles ``idx``."""
        ix = check_index(idx, self.n_vehicles)
        k = inputs.check()
        if k != ix.size:
            raise ValueError(f"inputs hold {k} samples for {ix.size} vehicle indices")
        cfg, L = self.cfg, self.layout
        fz = np.maximum(inputs.normal_force, LIFT_OFF_FORCE)
        x, P = self.x[ix], self.P[ix]
        last = self.last_stamp[ix]
        with np.errstate(invalid="ignore"):
            dt = inputs.stamp - last
        reasons = [""] * k
        first = np.isnan(last)
        raw = np.column_stack([inputs.wheel_speed, inputs.ground_speed, inputs.wheel_torque])
        fresh = fresh_readings(self._prev[ix], raw, first | (dt < 0))
        # a fresh encoder speed is a count difference: the mean over the interval since the last one
        interval = np.where(fresh[:, :4], inputs.stamp[:, None] - self._changed_at[ix][:, :4], 0.0)
        interval = np.where(interval <= cfg.max_gap, interval, 0.0)
        omega_rate = wheel_acceleration(self._prev[ix][:, :4], inputs.wheel_speed, interval, fresh[:, :4], cfg.max_gap)
        torque = (split_side_torque(inputs.wheel_torque, fz, self.vehicle.wheel_inertia * omega_rate)
                  if self.vehicle.drive == "per_side" else inputs.wheel_torque)
        if self.vehicle.wheel_speed_reading == "instant":
            interval = np.zeros_like(interval)  # no lead
        changed_at = np.where(fresh, inputs.stamp[:, None], self._changed_at[ix])
        self._prev[ix], self._changed_at[ix] = raw, changed_at
        age = inputs.stamp[:, None] - changed_at
        # dt == 0 (a repeated stamp) is no reset: only the update runs
        for rows, why in ((first, "start"), (~first & (dt < 0), "stamp_backwards"),
                          (~first & (dt > cfg.max_gap), "time_gap")):
            if rows.any():
                self._reset(ix, rows, x, P, inputs, reasons, why)
        A, b, H = model(L, self.vehicle, fz, torque, inputs.pitch, self.maps(x), cfg.gravity)
        lead = encoder_lead(interval, omega_rate)
        rejected = np.zeros(k, dtype=int)
        every = not any(reasons)  # the usual case: no mask copies, same arithmetic
        run = slice(None) if every else np.array([not r for r in reasons])
        if every or run.any():
            xr, Pr = (x, P) if every else (x[run], P[run])
            dtr = dt if every else dt[run]
            moving = dtr > 0
            if moving.all():
                xr, Pr = predict(xr, Pr, A if every else A[run], b if every else b[run], self._Qc, dtr)
            elif moving.any():
                xr[moving], Pr[moving] = predict(xr[moving], Pr[moving], A[run][moving], b[run][moving], self._Qc,
                                                 dtr[moving])
            gs = inputs.ground_speed[run]
            no_gs = np.isnan(gs)
            z = np.column_stack([inputs.specific_force_x[run], inputs.yaw_rate[run], inputs.wheel_speed[run] + lead[run],
                                 np.where(no_gs, 0.0, gs)])
            available = np.ones(z.shape, dtype=bool)
            available[:, 2:7] = fresh[run][:, :5]  # held wheel / ground speeds are no new measurement
            available[:, 6] &= ~no_gs
            rows = ix[run]
            xr, Pr, counts, _, keep = gated_update(xr, Pr, z, np.broadcast_to(self._r, z.shape), H[run], cfg.gate_sigma,
                                                   self.rejections[rows], cfg.gate_patience, available)
            self.rejections[rows] = counts
            rejected[run] = np.count_nonzero(available & ~keep, axis=1)
            xr, Pr = condition(xr, Pr, self._lower, self._upper, cfg.variance_floor, cfg.variance_ceiling)
            if every:
                x, P = xr, Pr
            else:
                x[run], P[run] = xr, Pr
        # divergence guard: a non-finite or out-of-physics state restarts that vehicle's filter
        finite = np.isfinite(x).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
        sane = (np.abs(x[:, L.omega]).max(axis=1) <= cfg.max_wheel_speed) & (np.abs(x[:, L.v]) <= cfg.max_ground_speed)
        for rows, why in ((~finite, "non_finite_state"), (finite & ~sane, "state_out_of_physics")):
            if rows.any():
                self._reset(ix, rows, x, P, inputs, reasons, why)
        self.x[ix], self.P[ix] = x, P
        self.last_stamp[ix] = inputs.stamp
        return self._output(x, P, fz, rejected, reasons, age, ~np.isnan(inputs.ground_speed))

    def _output(self, x, P, fz, rejected, reasons, age, measured) -> ObserverBankOutput:
        L, k = self.layout, x.shape[0]
        M = self.maps(x)
        res = np.einsum("kir,kr->ki", M, x[:, L.res]) if L.n_res else np.zeros((k, 4))
        # gross_i = mu_i + (M x_res)_i: its variance from the joint covariance (determined by the
        # wheel torque balance even when the net / resistance split is not: docs/method.md §12)
        J = np.zeros((k, 4, L.n))
        J[:, :, L.mu] = _eye(4)
        if L.n_res:
            J[:, :, L.res] = M
        dg = _arange(L.n)
        mu_var = P[:, dg, dg][:, L.mu]
        mu = x[:, L.mu]
        return ObserverBankOutput(
            mu=mu.copy(),
            mu_var=mu_var,
            mu_determined=mu_var <= self.cfg.mu_std_determined**2,
            resistance=res,
            gross=mu + res,
            # a quadratic form of the conditioned P: floored, since clamping correlations keeps P only
            # nearly positive semi-definite
            gross_var=np.maximum(np.einsum("kil,kil->ki", J @ P, J), self.cfg.variance_floor),
            wheel_speed=x[:, L.omega].copy(),
            ground_speed=x[:, L.v].copy(),
            yaw_rate=x[:, L.psi].copy(),
            rejected=rejected,
            reset=np.array([bool(r) for r in reasons]),
            reset_reason=reasons,
            normal_force=fz,
            speed_age=age[:, :4],
            ground_speed_age=age[:, 4],
            torque_age=age[:, 5:9],
            ground_speed_measured=measured,
        )
