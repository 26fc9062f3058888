"""The latency of the ground-speed sensor, measured against the accelerometer, and the reading led
by it (docs/method.md §13).

GNSS, visual and lidar odometry report the speed of a moment ago: a reading tau late is
V(t - tau) = V(t) - tau a, a slip error of tau a / V exactly while the robot accelerates, which is
when K is visible (§9).  50 ms at 1 m/s^2 is 0.05 m/s: in the robustness variant ground-speed-lag
a braking wheel's slip read 0.03-0.07 too negative and firm soil (K 300) read 146 and 876 within
0.2 s.  Nothing in a log states tau, but the accelerometer measures it.  Between two new
ground-speed readings at t1 and t2 the speed changes by the integral of the acceleration
a = f_x + g sin(pitch) (the specific force of eq. 29 plus the gravity term of the observer's
speed equation); the readings change by the same integral taken tau earlier, so to first order

    y = integral of a over [t1, t2] - (V_read(t2) - V_read(t1))  =  tau (a(t2) - a(t1)) = tau x.

A least-squares line through the origin over the recent pairs (forgetting ``window`` s) gives
tau.  An accelerometer bias adds b (t2 - t1) to y, which does not follow x; the integral is a
trapezoid (the rectangle at each sample's end reads dt / 2 of latency: 25 ms at 20 Hz).  tau is
used only while the fit determines it (t-statistic above ``MIN_T``, the acceleration changed by
``MIN_SPREAD`` in root-sum-square, more than ``MIN_PAIRS`` pairs), clipped to
[0, ``max_latency``]; the observer then fuses V_read + tau a.

Measured (seed 0): ground-speed-lag reads tau 0.054 s (truth 0.05); 0 on every other robustness
variant, the product's scenarios and the skid-steer rover; 0.02-0.08 s at times on the Warthog
logs, whose ground speed comes from differentiated lidar poses.
"""

from __future__ import annotations

import numpy as np

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

    def step(self, sel, dt: np.ndarray, acc: np.ndarray, reading: np.ndarray, new: np.ndarray) -> np.ndarray:
        """One sample of the vehicles ``sel``: ``dt`` (k,) s since their previous sample (NaN or
        negative: a restart, which closes the open pair; 0: a repeated stamp), ``acc`` (k,) m/s^2,
        the ground-speed ``reading`` (k,; NaN: none, which neither closes a pair nor enters the
        fit) and whether it is a new one (k,).  Returns the reading led by the latency,
        V_read + tau a (k,)."""
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
        return reading + latency * a_lp
