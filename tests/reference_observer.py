"""Plain numpy references of the observer, for the tests: the core (soilocp._core.ObserverCore, behind
soilocp.estimation.observer_bank.ObserverBank, soilocp/_core/src/observer/) is checked against them, step by
step, on drawn and real drives.  Nothing in the product imports this module.

* the model of eq. 33 (A, b, H) and its ZOH discretisation (eq. 34, by series and by the matrix exponential);
* the readings clock (which readings are new, docs/method.md §13; the core's readings.rs);
* the ground-speed latency fit (§13; latency.rs);
* the refresh pairs of slow wheel-speed and torque streams (§13; intervals.rs);
* the skid-steer torque split and the encoder lead (§14; wheel_inputs.rs);
* the resistance's random walk slowed while the slips spread (§12; walk.rs);
* the filter on filterpy's ``KalmanFilter`` (:class:`TractionObserver`), with the same gating rule, low-speed
  re-anchoring and conditioning written in numpy, so that the core's predict / update is checked against a
  well-kept implementation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Optional

import numpy as np
from filterpy.kalman import KalmanFilter

from soilocp.estimation.observer import N_MEAS, ObserverConfig, StateLayout
from soilocp.estimation.observer_bank import LIFT_OFF_FORCE
from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.model.vehicle import VehicleParams


# --- the model of eq. 33 and its discretisation (eq. 34) -------------------------------------------------------

def travel_direction(v_wheel: np.ndarray, travel_speed: float) -> np.ndarray:
    """Smoothed sign of each wheel's travel, in [-1, 1]: motion resistance opposes travel (§11)."""
    # minimum / maximum rather than np.clip: the same values, a third of the call overhead
    return np.minimum(np.maximum(v_wheel / travel_speed, -1.0), 1.0)


def resistance_map(layout: StateLayout, slip: Optional[np.ndarray], travel: Optional[np.ndarray],
                   bridge: float) -> np.ndarray:
    """(..., 4, n_res) map from the resistance states to each wheel's mu_xR.

    ``slip`` structure (docs/method.md §11, eq. 4 even in S): mu_xR_i = d_i (r0 b_i + r1 |S_i|), with
    b_i = min(|S_i| / bridge, 1) the zero-slip bridge of eq. 4's constant part (as in
    :mod:`soilocp.model.traction`) and d_i the travel direction; r0 ~ C4 + C5/K and r1 ~ C6/sqrt(K) are
    shared by the wheels (same soil).  ``slip`` and ``travel`` have shape (..., 4); None means zero
    slip and forward travel.  The old form r0 sgn(S) + r1 S flipped the resistance of a braking
    wheel and biased K 20-30 % low on traction tests.
    """
    s = np.zeros(4) if slip is None else np.asarray(slip, dtype=float)
    if layout.n_res == 2:
        d = np.ones_like(s) if travel is None else np.asarray(travel, dtype=float)
        out = np.empty(s.shape + (2,))
        a = np.abs(s, out=out[..., 1])
        if bridge > 0:
            np.multiply(d, np.minimum(a / bridge, 1.0), out=out[..., 0])
        else:
            out[..., 0] = d
        a *= d
        return out
    if layout.n_res == 1:
        return np.ones(s.shape + (1,))
    if layout.n_res == 4:
        return np.broadcast_to(np.eye(4), s.shape[:-1] + (4, 4)).copy()
    return np.zeros(s.shape + (0,))


def path_acceleration(specific_force_x, pitch, gravity: float = STANDARD_GRAVITY):
    """The CoM's acceleration along its path, V_dot of the speed equation below, with the
    accelerometer's specific force (eq. 29, docs/method.md §3) for sum(mu_i Fz_i) / m:
    f_x + g sin(pitch) (REP-103: pitch > 0 nose down).  The ground-speed latency fit
    (the ground-speed latency fit below) integrates it."""
    return specific_force_x + gravity_along_path(pitch, gravity)


def gravity_along_path(pitch, gravity: float = STANDARD_GRAVITY):
    """g sin(pitch): the gravity term of the speed equation (eq. 20's reaction, REP-103 pitch)."""
    return gravity * np.sin(pitch)


def model(layout: StateLayout, vehicle: VehicleParams, fz: np.ndarray, torque: np.ndarray, pitch: np.ndarray,
          M: np.ndarray, gravity: float = STANDARD_GRAVITY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (k, n, n), b (k, n), H (k, 7, n) of eq. 33 for k vehicles, built from eqs. 11-15 and 29 at
    the current normal forces fz (k, 4) [N], wheel torques (k, 4) [N m] and pitch (k,) [rad], with
    the resistance maps M (k, 4, n_res) of :func:`resistance_map`.

    omega_i_dot = (T_i - R_w (mu_i + mu_xR_i) Fz_i) / I_w          (eqs. 13-15)
    V_dot       = sum(mu_i Fz_i) / m + g sin(pitch) - bias           (longitudinal, REP-103 pitch)
    psi_ddot    = [d(Fx3 + Fx4) - c(Fx1 + Fx2) - M_zR] / I_z          (eqs. 11-12), Fx_i = mu_i Fz_i
    M_zR        = a(mu_yR1 Fz1 + mu_yR4 Fz4) + b(mu_yR2 Fz2 + mu_yR3 Fz3)
    z = [f_x = sum(mu_i Fz_i)/m (eq. 29, docs/method.md §3), psi_dot, omega_1..4, V]

    The product's observer builds the same model in the compiled core (soilocp/_core/src/observer/model.rs,
    ``ObserverCore.model``); this numpy form serves the filterpy reference below and the discretisation check.
    """
    L, v = layout, vehicle
    k, nx = fz.shape[0], L.n
    A, b, H = np.zeros((k, nx, nx)), np.zeros((k, nx)), np.zeros((k, N_MEAS, nx))
    # an accelerometer bias or a pitch bias would otherwise integrate into V and bias every slip
    A[:, L.v, L.bias] = -1.0
    H[:, 1, L.psi] = 1.0
    H[:, 2:6, L.omega] = np.eye(4)
    H[:, 6, L.v] = 1.0
    wheel_gain = -v.wheel_radius * fz / v.wheel_inertia
    wheels = np.arange(4)
    A[:, L.omega.start + wheels, wheels] = wheel_gain
    if L.n_res:
        A[:, L.omega, L.res] = wheel_gain[:, :, None] * M
    b[:, L.omega] = torque / v.wheel_inertia
    A[:, L.v, L.mu] = fz / v.mass
    b[:, L.v] = gravity_along_path(pitch, gravity)
    A[:, L.psi, L.mu] = np.array([-v.c, -v.c, v.d, v.d]) * fz / v.yaw_inertia
    lat = np.array([v.a, v.b, v.b, v.a]) * fz
    if L.n_lat == 1:
        A[:, L.psi, L.lat.start] = -lat.sum(axis=1) / v.yaw_inertia
    else:
        A[:, L.psi, L.lat] = -lat / v.yaw_inertia
    H[:, 0, L.mu] = A[:, L.v, L.mu]
    return A, b, H


def continuous_model(layout: StateLayout, vehicle: VehicleParams, fz: np.ndarray, torque: np.ndarray,
                     pitch: float, g: float = STANDARD_GRAVITY, slip=None, travel=None):
    """A (n, n), b (n,), H (7, n) of eq. 33 for one vehicle: :func:`model` with k = 1."""
    M = resistance_map(layout, slip, travel, DEFAULT_CONSTANTS.bridge_slip)
    A, b, H = model(layout, vehicle, np.asarray(fz, float)[None], np.asarray(torque, float)[None],
                    np.array([pitch], float), M[None], g)
    return A[0], b[0], H[0]


def discretize(A: np.ndarray, b: np.ndarray, Qc: np.ndarray, dt: float, method: str = "series"):
    """Zero-order-hold discretisation of x_dot = A x + b + w (eq. 33 -> eq. 34).

    Returns (F, G, Qd) with x_k+1 = F x_k + G + w_k.  ``series`` is exact when A @ A = 0 (our A);
    ``expm`` uses the matrix exponential of the augmented system [[A, b], [0, 0]] and Van Loan's
    method for Qd, exact for any A.
    """
    n = A.shape[0]
    if method == "series":
        F = np.eye(n) + A * dt
        G = b * dt + A @ b * (dt * dt / 2.0)
        q = np.diagonal(Qc)
        if np.count_nonzero(Qc) == np.count_nonzero(q):  # diagonal Qc (ours): A Qc = A * q
            AQ = A * q
        else:
            AQ = A @ Qc
        Qd = Qc * dt + (AQ + AQ.T) * (dt * dt / 2.0) + AQ @ A.T * (dt**3 / 3.0)
        return F, G, Qd
    if method == "expm":
        import scipy.linalg  # the checking path only: not loaded in every service process (memory)

        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n] = A
        aug[:n, n] = b
        E = scipy.linalg.expm(aug * dt)
        F, G = E[:n, :n], E[:n, n]
        vl = np.zeros((2 * n, 2 * n))
        vl[:n, :n] = -A
        vl[:n, n:] = Qc
        vl[n:, n:] = A.T
        V = scipy.linalg.expm(vl * dt)
        Qd = V[n:, n:].T @ V[:n, n:]
        return F, G, (Qd + Qd.T) / 2.0
    raise ValueError(f"discretization must be 'series' or 'expm', got {method!r}")


# --- the readings clock (readings.rs) ----------------------------------------------------------------------

#: weight of one value change in the running share of consecutive changes (~10 changes of memory)
SHARE_WEIGHT = 0.1


class Readings(NamedTuple):
    """One step's verdict on readings (k, c)."""

    fresh: np.ndarray  #: a new measurement: a changed value, or a full-rate stream's repeat
    changed: np.ndarray  #: the value itself changed (or everything is new: a first sample, a restart)
    prev: np.ndarray  #: the previous sample's readings
    changed_before: np.ndarray  #: when the value last changed before this sample (the interval of a count difference)
    age: np.ndarray  #: s since the channel's last new measurement (0 when fresh)
    full_rate: np.ndarray  #: the stream is read at the sample rate (its running share of consecutive changes)


class ReadingClock:
    """Per (vehicle, channel): the last value, when it last changed, when the channel last gave a
    new reading, and the running share of value changes at consecutive samples.  Arrays (n, c)."""

    def __init__(self, n_vehicles: int, n_channels: int, full_rate_share: float, repeat_window: float):
        self.full_rate_share, self.repeat_window = full_rate_share, repeat_window
        self.prev = np.full((n_vehicles, n_channels), np.nan)
        self.fresh_at = np.full((n_vehicles, n_channels), np.nan)  # last new reading (changed or a full-rate repeat)
        self.value_at = np.full((n_vehicles, n_channels), np.nan)  # last change of the value itself
        self.share = np.zeros((n_vehicles, n_channels))

    def step(self, sel, stamp: np.ndarray, last_stamp: np.ndarray, raw: np.ndarray,
             restart: np.ndarray) -> Readings:
        """Readings ``raw`` (k, c) of the vehicles ``sel`` at ``stamp`` (k,), whose previous sample
        was at ``last_stamp`` (k,; NaN at a first); ``restart`` (k,): a first sample or a stamp that
        went backwards (everything is new then)."""
        # copies: ``sel`` may be a slice, and the state is overwritten below
        prev, fresh_before, value_before = self.prev[sel].copy(), self.fresh_at[sel].copy(), self.value_at[sel].copy()
        share = self.share[sel]
        changed = (raw != prev) | restart[:, None]
        # a missing reading (NaN: a dropout) and the first one after it change nothing about the
        # stream's rate: counted, a dropout would make a held 10 Hz stream look full-rate
        counted = changed & ~restart[:, None] & np.isfinite(raw) & np.isfinite(prev)
        # the previous sample brought a new value too: the stream is read at the sample rate
        consecutive = value_before == last_stamp[:, None]
        share = np.where(counted, share + SHARE_WEIGHT * (consecutive - share), share)
        with np.errstate(invalid="ignore"):
            repeat = (~changed & (share > self.full_rate_share) & (stamp - last_stamp > 0)[:, None]
                      & (stamp[:, None] - value_before <= self.repeat_window))
        fresh = changed | repeat
        fresh_at = np.where(fresh, stamp[:, None], fresh_before)
        self.prev[sel] = raw
        self.fresh_at[sel] = fresh_at
        self.value_at[sel] = np.where(changed, stamp[:, None], value_before)
        self.share[sel] = share
        return Readings(fresh, changed, prev, value_before, stamp[:, None] - fresh_at, share > self.full_rate_share)


# --- the ground-speed latency (latency.rs) ----------------------------------------------------------------

#: t-statistic of the fitted latency above which it is used
MIN_T = 3.0
#: m/s^2: the root sum of squares of the acceleration changes the fit needs (its lever)
MIN_SPREAD = 0.5
#: pairs of readings (decayed count) the fit needs
MIN_PAIRS = 10.0
#: s: low-pass of the accelerometer (its noise would otherwise enter x and the lead)
SMOOTHING = 0.05


class GroundSpeedLatency:
    """Per vehicle: the accelerometer's integral since the last new ground-speed reading, that
    reading, the low-passed acceleration then, and the decaying fit sums.  Arrays (n,)."""

    def __init__(self, n_vehicles: int, window: float, max_latency: float):
        self.window, self.max_latency = window, max_latency
        self.integral = np.full(n_vehicles, np.nan)  # of a since the last new reading (NaN: no pair open)
        self.read = np.full(n_vehicles, np.nan)  # that reading
        self.a_then = np.zeros(n_vehicles)  # the low-passed acceleration at that reading
        self.a_lp = np.full(n_vehicles, np.nan)
        self.a_prev = np.full(n_vehicles, np.nan)  # the previous sample's acceleration (trapezoid)
        self.sums = np.zeros((n_vehicles, 4))  # decaying sums of x y, x x, y y and the pair count
        self.latency = np.zeros(n_vehicles)  # s; 0 while not determined
        self.clock = np.zeros(n_vehicles)  # s since the last restart
        # the recent (clock, acceleration) samples the lead integrates, at least max_latency of them
        self.recent: list[list[tuple[float, float]]] = [[] for _ in range(n_vehicles)]

    def step(self, sel, dt: np.ndarray, acc: np.ndarray, reading: np.ndarray, new: np.ndarray) -> np.ndarray:
        """One sample of the vehicles ``sel``: ``dt`` (k,) s since their previous sample (NaN or
        negative: a restart, which closes the open pair; 0: a repeated stamp), ``acc`` (k,) m/s^2,
        the ground-speed ``reading`` (k,; NaN: none, which neither closes a pair nor enters the
        fit) and whether it is a new one (k,).  Returns the reading led by the latency (k,): V_read
        plus the acceleration's integral over the last tau seconds (trapezoids, the first cut at
        now - tau by interpolation, the oldest acceleration held before it)."""
        with np.errstate(invalid="ignore"):
            restart = ~(dt >= 0)  # NaN or negative
        a_lp, a_prev, integral = self.a_lp[sel], self.a_prev[sel], self.integral[sel]
        if restart.any():  # the usual case: no mask copies
            a_lp, a_prev, integral = (np.where(restart, np.nan, v) for v in (a_lp, a_prev, integral))
            step = np.where(restart, 0.0, dt)
        else:
            step = dt
        fresh_lp = np.isnan(a_lp)
        if fresh_lp.any():
            a_lp = np.where(fresh_lp, acc, a_lp + -np.expm1(-step / SMOOTHING) * (acc - a_lp))
            a_prev = np.where(np.isnan(a_prev), acc, a_prev)
        else:
            a_lp = a_lp + -np.expm1(-step / SMOOTHING) * (acc - a_lp)
        integral = integral + 0.5 * (a_prev + acc) * step
        sums = self.sums[sel] * np.exp(-step / self.window)[:, None]
        latency = self.latency[sel]
        new = new & np.isfinite(reading)
        if new.any():
            pair = new & np.isfinite(integral)  # a new reading with one before it (and no restart since)
            x = a_lp - self.a_then[sel]
            y = integral - (reading - self.read[sel])
            sums[:, 0] += np.where(pair, x * y, 0.0)
            sums[:, 1] += np.where(pair, x * x, 0.0)
            sums[:, 2] += np.where(pair, y * y, 0.0)
            sums[:, 3] += pair
            sxy, sxx, syy, n = sums.T
            with np.errstate(invalid="ignore", divide="ignore"):
                tau = sxy / sxx
                t_stat = tau * np.sqrt(sxx * np.maximum(n - 1.0, 1.0) / np.maximum(syy - tau * sxy, 1e-30))
            determined = (sxx > MIN_SPREAD**2) & (n > MIN_PAIRS) & (t_stat > MIN_T)
            latency = np.where(pair, np.where(determined, np.clip(tau, 0.0, self.max_latency), 0.0), latency)
            self.read[sel] = np.where(new, reading, self.read[sel])
            self.a_then[sel] = np.where(new, a_lp, self.a_then[sel])
            integral = np.where(new, 0.0, integral)
        self.latency[sel], self.sums[sel], self.integral[sel] = latency, sums, integral
        self.a_lp[sel], self.a_prev[sel] = a_lp, acc
        lead = np.zeros(len(latency))
        for j, g in enumerate(np.arange(len(self.latency))[sel]):
            if restart[j]:
                self.recent[g], self.clock[g] = [], 0.0
            self.clock[g] += step[j]
            recent = self.recent[g]
            recent.append((float(self.clock[g]), float(acc[j])))
            while len(recent) > 2 and recent[1][0] <= self.clock[g] - self.max_latency:
                recent.pop(0)
            lead[j] = _trailing_integral(recent, float(self.clock[g]), float(latency[j]))
        return np.where(latency > 0.0, reading + lead, reading)


def _trailing_integral(recent: list[tuple[float, float]], now: float, tau: float) -> float:
    """The integral of the acceleration over [now - tau, now] from the samples ``recent``."""
    start = now - tau
    t1, a1 = recent[-1]
    total = 0.0
    for t0, a0 in reversed(recent[:-1]):
        if t1 <= start:
            break
        if t0 >= start:
            total += 0.5 * (a0 + a1) * (t1 - t0)
            t1, a1 = t0, a0
        else:
            a_start = a0 + (a1 - a0) * (start - t0) / (t1 - t0)
            total += 0.5 * (a_start + a1) * (t1 - start)
            t1 = start
            break
    if t1 > start:
        total += a1 * (t1 - start)
    return total


# --- the refresh pairs (intervals.rs) --------------------------------------------------------------------

#: s: intervals are sums or differences of stamps, so a 10 Hz stream's 0.1 s reads 0.1 - 1e-15 as
#: often as not; the interval bounds are taken this much wider
STAMP_TOLERANCE = 1e-6


class IntervalTraction(NamedTuple):
    """One step's refresh intervals (k, 4); ``interval`` 0 where the sample closes none."""

    interval: np.ndarray  #: s from the previous refresh to this one (0: none closed here)
    gross: np.ndarray  #: the interval's Fz-weighted mean gross traction coefficient (eq. 13 integrated)
    gross_var: np.ndarray  #: its variance
    rim_start: np.ndarray  #: the rim speed R_w omega at the interval's start (the previous reading), m/s
    rim_end: np.ndarray  #: and at its end (this reading), m/s
    ground_start: np.ndarray  #: the ground speed at the wheel (V - psi_dot y_i) at the interval's start, m/s
    ground_end: np.ndarray  #: and at its end, m/s
    rim_sigma: np.ndarray  #: 1-sigma of the rim speed's course between the readings against their chord, m/s
    active: np.ndarray  #: bool: one stream refreshes slowly and the other is read at the sample rate


class RefreshIntervals:
    """Per (vehicle, wheel), arrays (n, 4): the integrals of torque and normal force since the wheel
    speed's last change, the ground speed at the wheel then, whether every sample since brought a new
    torque reading, and whether the wheel learns at refreshes only (a slow speed or a slow torque)."""

    def __init__(self, n_vehicles: int, wheel_inertia: float, wheel_radius: float, jerk: float,
                 min_interval: float, max_interval: float, variance_floor: float, speed_sigma: float):
        self.inertia, self.radius, self.jerk, self.speed_sigma = wheel_inertia, wheel_radius, jerk, speed_sigma
        self.min_interval, self.max_interval, self.variance_floor = min_interval, max_interval, variance_floor
        shape = (n_vehicles, 4)
        self.span = np.zeros(shape)  # s integrated since the speed's last change
        self.torque_dt = np.zeros(shape)
        self.fz_dt = np.zeros(shape)
        self.ground_start = np.zeros(shape)  # the ground speed at the wheel when the interval began
        # the sums of a straight line's least squares through y = T / (R_w Fz) against the time in the interval:
        # n, t, t^2, y, t y, y^2
        self.line = np.zeros((n_vehicles, 4, 6))
        # the integrals began at a change of the speed (not at a restart) and the torque was read at
        # every sample since
        self.valid = np.zeros(shape, dtype=bool)
        # the previous closed interval's mean acceleration (rad/s^2; NaN: none since a restart), whose change
        # to this interval's measures how far the speed strays from the chord between the readings
        self.last_rate = np.full(shape, np.nan)
        self.active = np.zeros(shape, dtype=bool)  # the last interval ended as a slow refresh (IntervalTraction.active)
        self.torque_active = np.zeros(shape, dtype=bool)  # the same for a slow torque stream (torque_refresh)

    def step(self, sel, dt: np.ndarray, restart: np.ndarray, changed: np.ndarray, full_rate: np.ndarray,
             prev_speed: np.ndarray, speed: np.ndarray, torque: np.ndarray, torque_fresh: np.ndarray,
             fz: np.ndarray, ground: np.ndarray) -> IntervalTraction:
        """Integrate one sample (its values stand for the ``dt`` (k,) s before it) and close the
        intervals whose speed reading changed now: eq. 13 integrated over each, g_bar = (int T dt -
        I_w (omega(t1) - omega(t0))) / (R_w int Fz dt) (docs/method.md §13; the print's eq. 13 holds
        per instant, and a held speed leaves no instant between the readings to apply it at).

        ``restart`` (k,): a first sample, a gap or a stamp that went backwards (every interval
        restarts invalid); per wheel (k, 4): ``changed`` the speed reading changed, ``full_rate`` its
        stream is read at the sample rate (no held interval to close), ``prev_speed`` / ``speed`` the
        previous and the new reading (rad/s), ``torque`` (N m) and ``torque_fresh`` (a new torque
        reading), ``fz`` (N, > 0) and ``ground`` the ground speed at the wheel now (m/s)."""
        if full_rate.all():  # the usual case: every speed is read at the sample rate, no interval to keep
            self.valid[sel], self.active[sel], self.last_rate[sel] = False, False, np.nan
            return _none(changed.shape)
        span, torque_dt, fz_dt, ground_start = (a[sel].copy() for a in (self.span, self.torque_dt, self.fz_dt,
                                                                        self.ground_start))
        valid = self.valid[sel] & ~restart[:, None]
        step = np.where(restart | ~(dt > 0), 0.0, dt)[:, None]
        span += step
        torque_dt += torque * step
        fz_dt += fz * step
        valid &= torque_fresh
        line = self.line[sel].copy()
        y = torque / (self.radius * fz)
        t = span
        line += (step > 0)[..., None] * np.stack([np.ones_like(y), t, t * t, y, t * y, y * y], axis=-1)
        # a slow stream's refresh: the interval is longer than the sample interval and min_interval (a
        # quantised encoder's change after a few repeats is a full-rate stream's, and the observer follows
        # it), and not so long that the speed's linear course between the readings says nothing
        ended = (changed & valid & ~full_rate & (span > 1.5 * step) & (span >= self.min_interval - STAMP_TOLERANCE)
                 & (span <= self.max_interval + STAMP_TOLERANCE) & np.isfinite(prev_speed) & (fz_dt > 0))
        last_rate = self.last_rate[sel]
        active = np.where(ended, True, self.active[sel] & ~restart[:, None] & ~(changed & ~ended) & torque_fresh)
        if ended.any():
            out, rate = self._close(ended, span, torque_dt, fz_dt, line, prev_speed, speed, ground_start, ground,
                                    last_rate, active)
        else:  # most samples close nothing
            out, rate = _none(changed.shape)._replace(active=active), last_rate
        self.last_rate[sel] = np.where(ended, rate, np.where(restart[:, None] | (changed & ~ended), np.nan, last_rate))
        # a change starts the next interval; a restart starts an invalid one (its start is unknown)
        start = changed | restart[:, None]
        for a in (span, torque_dt, fz_dt):
            a[start] = 0.0
        line[start] = 0.0
        ground_start = np.where(start, ground, ground_start)
        valid = np.where(start, ~restart[:, None] & changed, valid)
        self.span[sel], self.torque_dt[sel], self.fz_dt[sel], self.ground_start[sel] = span, torque_dt, fz_dt, ground_start
        self.valid[sel] = valid
        self.line[sel] = line
        self.active[sel] = out.active
        return out

    def _close(self, ended, span, torque_dt, fz_dt, line, prev_speed, speed, ground_start, ground, last_rate,
               active) -> tuple[IntervalTraction, np.ndarray]:
        """The pairs of the intervals that ``ended`` now (k, 4), and every wheel's mean acceleration over
        its interval (rad/s^2; meaningful where ended)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            tau = np.where(ended, span, 1.0)
            rate = (speed - prev_speed) / tau
            # the first interval after a restart has no neighbour to tell its curvature: it only starts the chain
            close = ended & np.isfinite(last_rate)
            fz_mean = np.where(close, fz_dt / tau, 1.0)
            gross = (torque_dt - self.inertia * (speed - prev_speed)) / (self.radius * np.where(close, fz_dt, 1.0))
            var = (self.inertia * self.jerk * tau / (self.radius * fz_mean)) ** 2 + self.variance_floor
            # the gross traction's course within the interval off a straight line in time: the slip path's
            # average (Simpson's rule on a straight path) does not see it, so it is that much less certain
            # (a braking wheel released and braked again within one interval)
            n_, st, stt, sy, sty, syy = np.moveaxis(line, -1, 0)
            n1 = np.maximum(n_, 1.0)
            sxx, sxy, syy_c = stt - st * st / n1, sty - st * sy / n1, syy - sy * sy / n1
            resid = np.maximum(syy_c - np.where(sxx > 0, sxy * sxy / np.where(sxx > 0, sxx, 1.0), 0.0), 0.0) / n1
            var = var + resid
            # the mean speed over the interval against the readings' mean: a course bent by an acceleration
            # change d_a within the interval strays from the chord by up to d_a tau / 8 (a kink at its middle)
            rim_sigma = self.radius * np.abs(rate - last_rate) * tau / 8.0
        out = IntervalTraction(np.where(close, span, 0.0), np.where(close, gross, 0.0), np.where(close, var, 0.0),
                               np.where(close, self.radius * prev_speed, 0.0), np.where(close, self.radius * speed, 0.0),
                               np.where(close, ground_start, 0.0), np.where(close, ground, 0.0),
                               np.where(close, rim_sigma, 0.0), active)
        return out, rate

    def torque_refresh(self, sel, dt: np.ndarray, restart: np.ndarray, changed: np.ndarray, full_rate: np.ndarray,
                       since: np.ndarray, speed_full_rate: np.ndarray, speed_since: np.ndarray,
                       prev_speed: np.ndarray, speed: np.ndarray, torque: np.ndarray, fz: np.ndarray,
                       ground: np.ndarray) -> IntervalTraction:
        """A slow torque stream's refresh (a motor current held 0.1-1 s between readings) while the wheel
        speed is read at every sample: eq. 13 at this instant from the readings,
        g = (T - I_w omega_dot) / (R_w Fz), with omega_dot the last two speed readings' difference (1-sigma
        I_w sqrt(2) speed_sigma / dt / (R_w Fz): 0.008 at 100 Hz), at the slip of this speed reading
        (the observer's own speed, run on a held torque, strays: slip off by 1-sigma 0.10-0.15 at 2 Hz
        torques, its speed innovations gated as outliers).  Between the refreshes the gross traction
        would rest on a held torque, and K learns nothing there.  The pair stands for the torque's
        interval ``since`` (k, 4) s, which sets its exponent in the soil stage.

        Per wheel (k, 4): ``changed`` / ``full_rate`` the torque reading's; the speed is not held when
        its stream is read at the sample rate (``speed_full_rate``, a quantised encoder's repeats for
        up to 0.3 s included) or its value last changed less than ``min_interval`` before
        (``speed_since``, s); ``prev_speed`` / ``speed`` the last two speed
        readings (rad/s), ``torque`` N m, ``fz`` N and ``ground`` the ground speed at the wheel (m/s).
        ``speed_sigma`` (rad/s, the encoder's noise) is the constructor's."""
        if full_rate.all():  # the usual case: every torque is read at the sample rate
            self.torque_active[sel] = False
            return _none(changed.shape)
        ok_dt = ~restart & (dt > 0)
        slow = ~full_rate & (speed_full_rate | (speed_since < self.min_interval - STAMP_TOLERANCE)) & ok_dt[:, None]
        close = (changed & slow & (since >= self.min_interval - STAMP_TOLERANCE)
                 & (since <= self.max_interval + STAMP_TOLERANCE)
                 & np.isfinite(prev_speed) & (fz > 0))
        step = np.where(ok_dt, dt, 1.0)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            gross = (torque - self.inertia * (speed - prev_speed) / step) / (self.radius * fz)
            scale = self.inertia / (self.radius * fz)
            var = (scale * np.sqrt(2.0) * self.speed_sigma / step) ** 2 + (scale * self.jerk * step) ** 2 \
                + self.variance_floor
        # the stream stays slow until it is read at the sample rate (or the speeds are not), or a restart
        rim = self.radius * speed  # the pair's slip is this reading's
        active = np.where(close, True, self.torque_active[sel] & slow)
        self.torque_active[sel] = active
        zero = np.zeros(close.shape)
        return IntervalTraction(np.where(close, since, 0.0), np.where(close, gross, 0.0), np.where(close, var, 0.0),
                                np.where(close, rim, 0.0), np.where(close, rim, 0.0), np.where(close, ground, 0.0),
                                np.where(close, ground, 0.0), zero, active)


def _none(shape) -> IntervalTraction:
    """No interval closed and none kept: zeros (k, 4), inactive."""
    zero = np.zeros(shape)
    return IntervalTraction(zero, zero, zero, zero, zero, zero, zero, zero, np.zeros(shape, dtype=bool))


def merge(a: IntervalTraction, b: IntervalTraction) -> IntervalTraction:
    """Two sources' pairs (k, 4) in one: b's where it closes an interval, a's elsewhere; active in either."""
    if not b.active.any():  # (a pair closed is active)
        return a
    if not a.active.any():
        return b
    take = b.interval > 0
    return IntervalTraction(*(np.where(take, y, x) for x, y in zip(a[:-1], b[:-1])), a.active | b.active)


# --- the skid-steer split and the encoder lead (wheel_inputs.rs) ----------------------------------------

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
    readings (the readings clock above) with no acceleration and so no lead; the change
    that follows takes the whole interval, so the lead is right on average and off by at most
    half a count between (0.019 rad/s at 16384 counts and 100 Hz, under the wheel-speed noise).  At 0.01 s and the ~50 rad/s^2 of a hard skid-steer
    acceleration that is 0.23 rad/s, a slip error of ~0.02 at 1.5 m/s: enough to read firm soil
    (K 300) as K > 1000 (docs/method.md §14).  ``omega_rate`` from :func:`wheel_acceleration` (the
    readings, not the model: the model's omega_dot carries the lag of its traction states)."""
    return 0.5 * interval * omega_rate


# --- the filter on filterpy ------------------------------------------------------------------------------

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
    ran away (a stalled wheel read as spinning) and fed K a wrong slip.  The encoder is the one measurement
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
    # the readings around the filter (the observer's rows of the same names, ObserverBlocks), set by step
    normal_force: np.ndarray | None = None
    age: np.ndarray | None = None  # (9,): wheel speeds, ground speed, torques
    ground_speed_latency: float = 0.0
    pairs: IntervalTraction | None = None  # each field (4,)


def continuous_process_noise(layout: StateLayout, cfg: ObserverConfig) -> np.ndarray:
    """Q (n, n): diagonal random-walk intensities of the states, squared (the core's
    ObserverSettings::filter)."""
    c = cfg
    return np.diag(layout.per_state(c.q_mu, c.q_resistance, c.q_resistance_slope, c.q_lateral, c.q_wheel_speed,
                                    c.q_ground_speed, c.q_yaw_rate, c.q_speed_bias) ** 2)


class SlipSpread:
    """The spread of the wheels' load-weighted mean |slip| u over a window (the core's walk.rs): exponentially
    weighted mean and mean square, the first u after a restart taken whole."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.mean, self.mean_sq, self.started = 0.0, 0.0, False

    def update(self, u: float, dt: float, window: float) -> None:
        if not (np.isfinite(u) and np.isfinite(dt)):
            return
        a = min(max(dt / window, 0.0), 1.0) if self.started else 1.0
        self.mean += a * (u - self.mean)
        self.mean_sq += a * (u * u - self.mean_sq)
        self.started = True

    def std(self) -> float:
        return float(np.sqrt(max(self.mean_sq - self.mean * self.mean, 0.0)))


def walk_variance_scale(sigma: float, spread: float) -> float:
    """The factor on the resistance walks' variances: min(1, (spread / sigma)^4), 1 when off (spread 0)."""
    return 1.0 if spread <= 0.0 or not sigma > spread else (spread / sigma) ** 4


def initial_covariance(layout: StateLayout, cfg: ObserverConfig) -> np.ndarray:
    """P_0 (n, n): diagonal, from the config's initial 1-sigmas (speeds from their sensors' noise)."""
    c = cfg
    return np.diag(layout.per_state(c.p0_mu, c.p0_resistance, c.p0_resistance_slope, c.p0_lateral, c.r_wheel_speed,
                                    c.p0_speed, c.r_yaw_rate, c.p0_speed_bias) ** 2)


def state_bounds(layout: StateLayout, cfg: ObserverConfig) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) physical box of the state (docs/method.md §12); speeds unbounded (the divergence guard
    watches them)."""
    inf = np.inf
    hi = layout.per_state(cfg.mu_bound, cfg.resistance_bound, cfg.resistance_slope_bound, cfg.lateral_bound,
                          inf, inf, inf, cfg.speed_bias_bound)
    return -hi, hi


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
        # wheel speeds, ground speed, torques
        self._readings = ReadingClock(1, 9, cfg.full_rate_share, cfg.repeat_window)
        self._intervals = RefreshIntervals(1, vehicle.wheel_inertia, vehicle.wheel_radius, cfg.refresh_jerk,
                                           cfg.refresh_min_interval, cfg.refresh_max_interval, cfg.variance_floor,
                                           cfg.r_wheel_speed)
        self._latency = (GroundSpeedLatency(1, cfg.latency_window, cfg.ground_speed_latency_max)
                         if cfg.ground_speed_latency_max > 0 else None)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._lower, self._upper = state_bounds(L, cfg)
        self._spread = SlipSpread()
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
        self._spread.reset()

    def _map(self) -> np.ndarray:
        L, x, v = self.layout, self.kf.x, self.vehicle
        rim = x[L.omega] * v.wheel_radius
        ground = x[L.v] - x[L.psi] * self._wheel_y
        slip = (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)
        return resistance_map(L, slip, travel_direction(ground, self.cfg.travel_speed), DEFAULT_CONSTANTS.bridge_slip)

    def step(self, stamp: float, specific_force_x: float, yaw_rate: float, pitch: float,
             wheel_speed, wheel_torque, ground_speed: float, normal_force) -> ObserverEstimate:
        """One predict/update cycle (eq. 35, standard form) for a sample at ``stamp``."""
        fz = np.maximum(np.asarray(normal_force, dtype=float), LIFT_OFF_FORCE)
        torque = np.asarray(wheel_torque, dtype=float)
        omega = np.asarray(wheel_speed, dtype=float)
        ground_speed = float("nan") if ground_speed is None else float(ground_speed)
        dt = None if self._last_stamp is None else stamp - self._last_stamp
        reset = dt is None or dt < 0 or dt > self.cfg.max_gap
        speeds = np.array([*omega, ground_speed, *torque])
        last = np.nan if self._last_stamp is None else self._last_stamp
        fresh, changed, prev, changed_before, age, full_rate = (
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
        M = self._map()
        A, b, H = (m[0] for m in model(self.layout, self.vehicle, fz[None], torque[None], np.array([pitch]),
                                       M[None], self.cfg.gravity))
        if not reset and dt > 0:  # a repeated stamp (dt == 0) is a second measurement of the same instant
            Qc = self._Qc
            if self.layout.n_res == 2:  # the resistance's walk slows while the slips spread
                self._spread.update(float(np.sum(fz * np.abs(M[:, 1])) / np.sum(fz)), dt,
                                    self.cfg.resistance_walk_window)
                Qc = Qc.copy()
                Qc[self.layout.res, self.layout.res] *= walk_variance_scale(self._spread.std(),
                                                                            self.cfg.resistance_walk_spread)
            F, G, Qd = discretize(A, b, Qc, dt, self.cfg.discretization)
            self.kf.predict(u=np.ones(1), B=G[:, None], F=F, Q=Qd)
        self._last_stamp = stamp
        omega_now = omega + lead
        z = np.array([specific_force_x, yaw_rate, *omega_now, np.nan_to_num(read_speed)])
        rejected = 0
        if not reset:
            innov = z - H @ self.kf.x
            hph = np.einsum("ij,jk,ik->i", H, self.kf.P, H)
            # the gate on the normalised innovation nu^2 / S_ii, as the core: where the clamped correlations leave
            # P indefinite, S_ii = H P H^T + R can be negative, and nu^2 <= gate^2 S_ii (which rejects) is not the
            # same test (the core keeps the row; a drawn 20 Hz drive with speeds and torques held 1 s found it)
            with np.errstate(divide="ignore", invalid="ignore"):
                nis = innov**2 / (hph + self._R_diag)
            keep = (nis <= self.cfg.gate_sigma**2) | (self._rejections >= self.cfg.gate_patience)
            available = np.ones(N_MEAS, dtype=bool)
            available[2:7] = fresh[:5]  # held wheel / ground speeds are no new measurement
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
        out = self.estimate(rejected, reset)
        # the refresh pairs of slow streams, at the filtered ground speed under each wheel
        L, x = self.layout, self.kf.x.ravel()
        ground = (x[L.v] - x[L.psi] * self._wheel_y)[None]
        one = lambda a: np.asarray(a)[None]  # noqa: E731
        restart, dt_ = np.array([reset]), np.array([np.nan if dt is None else dt])
        pairs = self._intervals.step(slice(None), dt_, restart, one(changed[:4]), one(full_rate[:4]), one(prev[:4]),
                                     omega[None], torque[None], one(fresh[5:9]), fz[None], ground)
        torque_pairs = self._intervals.torque_refresh(
            slice(None), dt_, restart, one(changed[5:9]), one(full_rate[5:9]), one(stamp - changed_before[5:9]),
            one(full_rate[:4]), one(stamp - changed_before[:4]), one(prev[:4]), omega[None], torque[None], fz[None],
            ground)
        out.pairs = IntervalTraction(*(a[0] for a in merge(pairs, torque_pairs)))
        out.normal_force, out.age = fz, age
        out.ground_speed_latency = float(self._latency.latency[0]) if self._latency is not None else 0.0
        return out

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
