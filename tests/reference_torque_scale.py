"""A plain numpy reference of the online torque scale (docs/method.md §15): the
product's numpy kernel as it was before the port to the compiled core (main at 86852cb,
soilocp/estimation/torque_scale.py, with eq. TC, eq. 4 summed and eq. 20 written out as
soilocp/model/force_balance.py and soilocp/model/normal_force.py had them).  Kept here only so that
the tests can hold the core to it, to the bit; the product never imports it.  Eq. 4's coefficient
itself is the product's (``motion_resistance``): this reference checks the torque scale, not the
traction law (tests/reference_physics.py does that).

Since the port, one change of the kernel's model is mirrored here: a window whose innovation is beyond
``resistance_jump`` of its sigmas is a jump of F_MR, which informs F_MR alone (only once windows of both
acceleration signs have been fitted since F_MR was last reset), and k moves only once windows of both signs
have been fitted since then (a shadow posterior, which they all inform, becomes the state then)
(docs/robustness.md, "The accelerate/brake rows: a jump of the resistance").  And (docs/method.md §15, "A
jump is a mixed window" and "The wheels' inertia under an unknown payload"): a jump's shadow restarts from the
reset state, without the jump window's b; a jump whose window adjoins the previous fitted window takes that
one back (the state before it, predicted over both spans, then the jump); the wheel-inertia term of eq. TC
carries 1 / rho = k^w, w = 1 - prior_sigma^2 / state_sigma^2, at the shadow's k before the window.  And
(docs/method.md §15, "Gentle swings"): the state is (k, b, c), the balance y = k x - b - c |a| with c the
resistance's growth with the window's |a| (prior ``resistance_slope_sigma``; a jump resets it with b), and a window
below ``min_accel`` informs nothing.  The filter runs per vehicle in plain floats in the core's operation order.
"""

from __future__ import annotations

import math

import numpy as np

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import motion_resistance
from soilocp.model.vehicle import VehicleParams

G = 9.80665
FLOOR = 0.05  # eq. 1's floor, soilocp.model.slip.DEFAULT_FLOOR


def gravity_from_attitude(roll, pitch, g: float = G) -> np.ndarray:
    """Eq. 20, (..., 3)."""
    al, th = np.broadcast_arrays(np.asarray(roll, dtype=float), np.asarray(pitch, dtype=float))
    return np.stack([-g * np.sin(th), g * np.sin(al) * np.cos(th), g * np.cos(al) * np.cos(th)], axis=-1)


def longitudinal_balance(f_x, omega_dot_sum, torque_sum, vehicle: VehicleParams, resistance=None, inertia_scale=1.0):
    """Eq. TC: (x, y) = (sum T_log / R, m f_x + (1 / rho) I_w sum omega_dot / R + F_MR,model)."""
    r = vehicle.wheel_radius
    x = np.asarray(torque_sum, dtype=float) / r
    y = vehicle.mass * np.asarray(f_x, dtype=float) + np.asarray(inertia_scale, dtype=float) * (
        vehicle.wheel_inertia * np.asarray(omega_dot_sum, dtype=float) / r)
    if resistance is not None:
        y = y + np.asarray(resistance, dtype=float)
    return x, y


def modelled_resistance(slip, soil_strength, normal_force, direction, constants: ModelConstants = DEFAULT_CONSTANTS):
    """d sum_i F_z,i r(S_i, K), eq. 4 with |S|."""
    s = np.asarray(slip, dtype=float)
    r = np.asarray(motion_resistance(s, np.asarray(soil_strength, dtype=float)[..., None], constants))
    return np.asarray(direction, dtype=float) * (np.asarray(normal_force, dtype=float) * r).sum(axis=-1)


class ReferenceTorqueScale:
    """N vehicles' torque scales, the numpy kernel: ``step`` takes one sample per vehicle in ``ix``;
    ``apply_arrays`` is the product's ``apply`` on the observer inputs' arrays."""

    def __init__(self, vehicle: VehicleParams, cfg, prior_sigma: float, n_vehicles: int,
                 constants: ModelConstants = DEFAULT_CONSTANTS, *, slip_floor: float = FLOOR, gravity: float = G):
        self.vehicle, self.cfg, self.prior_sigma, self.constants = vehicle, cfg, float(prior_sigma), constants
        self.slip_floor, self.gravity = float(slip_floor), float(gravity)
        wider = cfg.enabled and cfg.prior_sigma is not None and prior_sigma > 0
        self.state_sigma = float(cfg.prior_sigma) if wider else self.prior_sigma
        n = n_vehicles
        self.k_default = float(np.median(list(constants.soils.values())))
        self.soil_k = np.full(n, self.k_default)
        self.soil_slip = np.full((n, 4), np.nan)
        # (k, b, c): c the resistance's growth with the window's |a| (F_MR = b + c |a| in the balance)
        self.theta3 = np.tile([1.0, 0.0, 0.0], (n, 1))
        self.P3 = np.tile(np.diag([self.state_sigma**2, cfg.resistance_sigma**2, cfg.resistance_slope_sigma**2]),
                          (n, 1, 1))
        self.signs = np.zeros(n, dtype=np.int64)  # acceleration signs fitted since b's last reset: 1 accel, 2 brake
        self.shadow_theta = self.theta3.copy()  # as if every accelerating or braking window informed k
        self.shadow_P = self.P3.copy()
        self.jumps = np.zeros(n, dtype=int)  # windows taken as a jump of F_MR, per vehicle (for the tests)
        self.taken_back = np.zeros(n, dtype=int)  # of which the previous window was taken back (for the tests)
        self.t0 = np.full(n, np.nan)
        self.t_prev = np.full(n, np.nan)
        self.prev = np.zeros((n, 4))
        self.area = np.zeros((n, 4))
        self.w0 = np.zeros(n)
        self.slow = np.zeros(n, dtype=bool)
        # the state before the last fitted window (theta, P, signs, shadow theta, shadow P), its span and last stamp
        self.before = (self.theta3.copy(), self.P3.copy(), self.signs.copy(), self.shadow_theta.copy(),
                       self.shadow_P.copy())
        self.last_span = np.full(n, np.nan)
        self.last_end = np.full(n, np.nan)

    @property
    def theta(self) -> np.ndarray:
        """(k, b) of every vehicle, (N, 2): what the core shows."""
        return self.theta3[:, :2].copy()

    @property
    def P(self) -> np.ndarray:  # noqa: N802
        """Their covariances, (N, 2, 2)."""
        return self.P3[:, :2, :2].copy()

    def apply_arrays(self, ix, stamp, f_x, pitch, yaw_rate, wheel_speed, wheel_torque, ground_speed, normal_force):
        """(torques x k's mean, k's relative 1-sigma for K's band), or (the torques, None) while never learnt."""
        if not self.cfg.enabled or self.prior_sigma <= 0:
            return wheel_torque, None
        m, sd = self.step(ix, stamp, f_x, pitch, yaw_rate, wheel_speed, wheel_torque, ground_speed, normal_force)
        if np.all(m == 1.0) and np.all(sd == self.state_sigma):
            return wheel_torque, None
        return wheel_torque * m[:, None], self.band_sigma(sd) / m

    def band_sigma(self, sd: np.ndarray) -> np.ndarray:
        if self.state_sigma == self.prior_sigma:
            return sd
        info = np.maximum(1.0 / np.maximum(sd, 1e-12) ** 2 - 1.0 / self.state_sigma**2, 0.0)
        return 1.0 / np.sqrt(1.0 / self.prior_sigma**2 + info)

    def feed_soil(self, ix: np.ndarray, soil_strength, slip=None) -> None:
        k = np.array([np.nan if v is None else v for v in np.atleast_1d(soil_strength)], dtype=float)
        self.soil_k[ix] = np.where(np.isfinite(k) & (k > 0), k, self.soil_k[ix])
        if slip is not None:
            self.soil_slip[ix] = np.asarray(slip, dtype=float).reshape(-1, 4)

    def scale(self, ix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.theta3[ix, 0].copy(), np.sqrt(self.P3[ix, 0, 0])

    def step(self, ix, stamp, f_x, pitch, yaw_rate, wheel_speed, torque, speed, normal_force=None):
        cfg, v = self.cfg, self.vehicle
        if not cfg.enabled or self.prior_sigma <= 0:
            return self.scale(ix)
        stamp = np.asarray(stamp, dtype=float)
        w_sum = np.asarray(wheel_speed, dtype=float).sum(axis=1)
        t_sum = np.asarray(torque, dtype=float).sum(axis=1)
        g_x = gravity_from_attitude(0.0, np.asarray(pitch, dtype=float), self.gravity)[..., 0]
        spd = np.asarray(speed, dtype=float)
        spd = np.where(np.isnan(spd), w_sum / 4.0 * v.wheel_radius, spd)
        rim = np.asarray(wheel_speed, dtype=float) * v.wheel_radius
        gs = spd[:, None]
        slip = (rim - gs) / np.maximum(np.maximum(np.abs(rim), np.abs(gs)), self.slip_floor)
        if normal_force is None or not cfg.model_resistance:
            f_mr = np.zeros(stamp.shape)
        else:
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
        area = self.area[ix] + np.where(cont[:, None], 0.5 * (self.prev[ix] + cur) * np.where(cont, dt, 0.0)[:, None], 0.0)
        slow = self.slow[ix] | bad
        span = stamp - self.t0[ix]
        full = cont & (span >= cfg.window - 1e-9)
        if full.any():
            j = np.flatnonzero(full)
            means = area[j] / span[j, None]
            omega_dot = (w_sum[j] - self.w0[ix[j]]) / span[j]
            sk = self.shadow_theta[ix[j], 0]
            w = 1.0 - self.prior_sigma**2 / self.state_sigma**2 if self.state_sigma**2 > self.prior_sigma**2 else 0.0
            ok = np.isfinite(sk) & (sk > 0) & (w != 0.0)
            # libm's pow, as the core's powf: numpy's vector pow differs in the last bit on ~5 % of arguments
            alpha = np.array([math.pow(k, w) if good else 1.0 for k, good in zip(sk.tolist(), ok.tolist())])
            x, y = longitudinal_balance(means[:, 0], omega_dot, means[:, 2], v, means[:, 3], alpha)
            valid = ~slow[j]
            if valid.any():
                jj = j[valid]
                a = means[valid, 0] - means[valid, 1]
                adjoins = self.t0[ix[jj]] == self.last_end[ix[jj]]
                self._update(ix[jj], span[jj], x[valid], y[valid], a, adjoins)
                self.last_span[ix[jj]] = span[jj]
                self.last_end[ix[jj]] = stamp[jj]
            self.last_end[ix[j[~valid]]] = np.nan
        restart = ~cont | full
        self.t0[ix] = np.where(restart, stamp, self.t0[ix])
        self.w0[ix] = np.where(restart, w_sum, self.w0[ix])
        self.area[ix] = np.where(restart[:, None], 0.0, area)
        self.slow[ix] = np.where(restart, bad, slow)
        self.prev[ix] = cur
        self.t_prev[ix] = stamp
        return self.scale(ix)

    def _update(self, iv, span, x, y, a, adjoins) -> None:
        """Each vehicle's window in turn, in plain floats in the core's operation order (kalman.rs)."""
        for m, i in enumerate(iv.tolist()):
            st = self._get(i)
            before = self._copy(st)
            jumped = self._step(st, float(span[m]), float(x[m]), float(y[m]), float(a[m]))
            self.jumps[i] += jumped
            if jumped and adjoins[m]:
                # a jump whose window adjoins the previous one: from the state before that one, over both spans
                self.taken_back[i] += 1
                st = self._get_before(i)
                sg = self._sign(float(a[m]))
                self._predict(st["P"], float(self.last_span[i]) + float(span[m]), sg != 0)
                self._predict(st["sP"], float(self.last_span[i]) + float(span[m]), sg != 0)
                self._jump(st, self._design(float(x[m]), float(a[m])), float(y[m]), sg)
            self._put(i, st)
            self._put_before(i, before)

    # ---- one vehicle's (k, b, c) filter: lists of floats ------------------------------------------------------

    def _get(self, i):
        return dict(th=self.theta3[i].tolist(), P=self.P3[i].tolist(), signs=int(self.signs[i]),
                    sth=self.shadow_theta[i].tolist(), sP=self.shadow_P[i].tolist())

    def _get_before(self, i):
        b = self.before
        return dict(th=b[0][i].tolist(), P=b[1][i].tolist(), signs=int(b[2][i]), sth=b[3][i].tolist(),
                    sP=b[4][i].tolist())

    @staticmethod
    def _copy(st):
        return dict(th=list(st["th"]), P=[list(r) for r in st["P"]], signs=st["signs"], sth=list(st["sth"]),
                    sP=[list(r) for r in st["sP"]])

    def _put(self, i, st) -> None:
        self.theta3[i], self.P3[i], self.signs[i] = st["th"], st["P"], st["signs"]
        self.shadow_theta[i], self.shadow_P[i] = st["sth"], st["sP"]

    def _put_before(self, i, st) -> None:
        for b, v in zip(self.before, (st["th"], st["P"], st["signs"], st["sth"], st["sP"])):
            b[i] = v

    def _sign(self, a: float) -> int:
        return (1 if a > 0 else 2) if abs(a) >= self.cfg.min_accel else 0

    @staticmethod
    def _design(x: float, a: float) -> list:
        return [x, -1.0, -abs(a)]

    @staticmethod
    def _dot(h, v) -> float:
        return (h[0] * v[0] + h[1] * v[1]) + h[2] * v[2]

    def _predict(self, P, span: float, acc: bool) -> None:
        P[0][0] += self.cfg.scale_walk**2 * span * (1.0 if acc else 0.0)
        P[1][1] += self.cfg.resistance_walk**2 * span

    def _step(self, st, span: float, x: float, y: float, a: float) -> bool:
        """One window: predict; a window below min_accel informs nothing; a jump of F_MR (once both signs
        were fitted since b's last reset) informs b and c alone; else the shadow takes it, and is the state
        once both signs were fitted (the state alone: k's gain 0)."""
        sg = self._sign(a)
        acc = sg != 0
        self._predict(st["P"], span, acc)
        self._predict(st["sP"], span, acc)
        if not acc:
            return False
        h = self._design(x, a)
        innov = y - self._dot(h, st["th"])
        s = self._gain_terms(st["P"], h)[1]
        jump_var = self.cfg.resistance_jump**2
        if jump_var > 0 and st["signs"] == 3 and innov * innov > jump_var * s:
            self._jump(st, h, y, sg)
            return True
        st["signs"] |= sg
        st["sth"], st["sP"] = self._correct(st["sth"], st["sP"], h, y - self._dot(h, st["sth"]), True)
        if st["signs"] == 3:
            st["th"], st["P"] = list(st["sth"]), [list(r) for r in st["sP"]]
        else:
            st["th"], st["P"] = self._correct(st["th"], st["P"], h, innov, False)
        return False

    def _jump(self, st, h, y: float, sg: int) -> None:
        """b's and c's variances back to their priors, uncorrelated with k and each other; the shadow restarts
        here (without the window's b); the window informs b and c alone."""
        P = st["P"]
        for j in (1, 2):
            for m in range(3):
                if m != j:
                    P[j][m] = 0.0
                    P[m][j] = 0.0
        P[1][1] = self.cfg.resistance_sigma**2
        P[2][2] = self.cfg.resistance_slope_sigma**2
        st["signs"], st["sth"], st["sP"] = sg, list(st["th"]), [list(r) for r in P]
        st["th"], st["P"] = self._correct(st["th"], P, h, y - self._dot(h, st["th"]), False)

    def _gain_terms(self, P, h):
        ph = [self._dot(P[i], h) for i in range(3)]
        return ph, self._dot(h, ph) + self.cfg.force_sigma**2

    def _correct(self, th, P, h, innov: float, informs: bool):
        """The update with this innovation; k's gain 0 unless ``informs`` (the Schmidt update); Joseph form."""
        ph, s = self._gain_terms(P, h)
        K = [v / s for v in ph]
        if not informs:
            K[0] = 0.0
        th = [th[i] + K[i] * innov for i in range(3)]
        A = [[(1.0 if i == j else 0.0) - K[i] * h[j] for j in range(3)] for i in range(3)]
        r = self.cfg.force_sigma**2

        def apa(i, l):
            def row(j):
                return ((A[i][j] * P[j][0]) * A[l][0] + (A[i][j] * P[j][1]) * A[l][1]) + (A[i][j] * P[j][2]) * A[l][2]
            return (row(0) + row(1)) + row(2)

        return th, [[apa(i, l) + r * K[i] * K[l] for l in range(3)] for i in range(3)]
