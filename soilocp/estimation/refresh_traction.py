"""Gross traction at a slow stream's refresh, from the readings themselves (docs/method.md §13, "Slow
wheel speeds or torques"): over a held wheel speed's interval, eq. 13 integrated
(:meth:`RefreshIntervals.step`); at a held torque's refresh while the speed is read at every sample,
eq. 13 at that instant (:meth:`RefreshIntervals.torque_refresh`).

Between the refreshes of a wheel-speed stream held by a slow driver (5 Hz, 4.7 Hz) the observer's
wheel speed is a prediction through the stiff wheel equation, and at the refresh its gross traction
extrapolates the interval: 1-sigma 0.095 against the truth on the robustness drive, which read K
13-29 % off.  Integrated over the interval from the previous refresh t0 to this one t1, eq. 13 needs
no prediction at all:

    I_w (omega(t1) - omega(t0)) = int T dt - R_w int g Fz dt,

so the Fz-weighted mean gross traction over the interval is

    g_bar = (int T dt - I_w (omega(t1) - omega(t0))) / (R_w int Fz dt),

exact but for the readings' own noise.  Its slip runs from eq. 1 at the previous reading to eq. 1 at
this one (the speed taken as linear in between), so the soil stage compares g_bar with the curve
averaged over that slip path, not with the curve at one slip: a braking wheel released from -0.35
to -0.06 within one 0.2 s interval reads a mean gross traction of -0.69 where the curve at the mean
slip gives -0.84.  That needs the torque read throughout the interval (its integral): a torque stream held
too (a motor current refreshed once a second, as on the Warthog) leaves the interval's torque
unknown, and then nothing is served and the soil stage keeps to the observer's own gross traction
at the refresh.  The speed is taken as linear over the interval, which it is not near a sweep's kink:
the variance states that as the inertia torque of a ``jerk`` (rad/s^3) over the interval,
(I_w jerk tau / (R_w Fz))^2, plus the scatter of T / (R_w Fz) about a straight line in time within
it, and the slip path as uncertain by R_w |d omega_dot| tau / 8 (``rim_sigma``).  Against the
simulated truth g_bar is off by 1-sigma 0.004-0.006 on the 4.7 Hz drive, and the end slips by
0.008-0.014.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

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
