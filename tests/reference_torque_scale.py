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
carries 1 / rho = k^w, w = 1 - prior_sigma^2 / state_sigma^2, at the shadow's k before the window.
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
        self.theta = np.tile([1.0, 0.0], (n, 1))
        self.P = np.tile(np.diag([self.state_sigma**2, cfg.resistance_sigma**2]), (n, 1, 1))
        self.signs = np.zeros(n, dtype=np.int64)  # acceleration signs fitted since b's last reset: 1 accel, 2 brake
        self.shadow_theta = self.theta.copy()  # as if every accelerating or braking window informed k
        self.shadow_P = self.P.copy()
        self.jumps = np.zeros(n, dtype=int)  # windows taken as a jump of F_MR, per vehicle (for the tests)
        self.taken_back = np.zeros(n, dtype=int)  # of which the previous window was taken back (for the tests)
        self.t0 = np.full(n, np.nan)
        self.t_prev = np.full(n, np.nan)
        self.prev = np.zeros((n, 4))
        self.area = np.zeros((n, 4))
        self.w0 = np.zeros(n)
        self.slow = np.zeros(n, dtype=bool)
        # the state before the last fitted window (theta, P, signs, shadow theta, shadow P), its span and last stamp
        self.before = (self.theta.copy(), self.P.copy(), self.signs.copy(), self.shadow_theta.copy(), self.shadow_P.copy())
        self.last_span = np.full(n, np.nan)
        self.last_end = np.full(n, np.nan)

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
        return self.theta[ix, 0].copy(), np.sqrt(self.P[ix, 0, 0])

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
        cfg = self.cfg
        accel = np.abs(a) >= cfg.min_accel
        sign = np.where(accel, np.where(a > 0, 1, 2), 0)
        signs = self.signs[iv]
        th, P = self.theta[iv], self.P[iv]
        sth, sP = self.shadow_theta[iv], self.shadow_P[iv]
        before = tuple(b[iv].copy() for b in (self.theta, self.P, self.signs, self.shadow_theta, self.shadow_P))
        for M in (P, sP):
            M[:, 0, 0] += cfg.scale_walk**2 * span * accel
            M[:, 1, 1] += cfg.resistance_walk**2 * span
        H = np.stack([x, -np.ones_like(x)], axis=1)
        innov = y - np.einsum("mi,mi->m", H, th)
        PH = np.einsum("mij,mj->mi", P, H)
        S = np.einsum("mi,mi->m", H, PH) + cfg.force_sigma**2
        # a jump of F_MR (only once windows of both signs have been fitted since b's last reset): b's variance
        # back to its prior, uncorrelated with k; the window informs b alone, and the shadow restarts from it
        jump_var = cfg.resistance_jump**2
        jump = (jump_var > 0) & (signs == 3) & (innov * innov > jump_var * S)
        self.jumps[iv] += jump
        # a jump whose window adjoins the previous fitted one: from the state before that one, over both spans
        back = jump & adjoins
        self.taken_back[iv] += back
        if back.any():
            th[back], P[back] = self.before[0][iv[back]], self.before[1][iv[back]]
            P[back, 0, 0] += cfg.scale_walk**2 * (self.last_span[iv[back]] + span[back]) * accel[back]
            P[back, 1, 1] += cfg.resistance_walk**2 * (self.last_span[iv[back]] + span[back])
            innov[back] = y[back] - np.einsum("mi,mi->m", H[back], th[back])
        P[jump, 0, 1] = 0.0
        P[jump, 1, 0] = 0.0
        P[jump, 1, 1] = cfg.resistance_sigma**2
        reset_th, reset_P = th.copy(), P.copy()  # a jump's shadow restarts here, without the window's b
        signs = np.where(jump, sign, signs | sign)
        # the shadow: every accelerating or braking window informs k; the state: once both signs are fitted
        s_innov = y - np.einsum("mi,mi->m", H, sth)
        sth, sP = self._correct(sth, sP, H, s_innov, accel)
        th, P = self._correct(th, P, H, innov, np.zeros_like(accel))
        both = ~jump & (signs == 3)
        th = np.where(both[:, None], sth, th)
        P = np.where(both[:, None, None], sP, P)
        sth = np.where(jump[:, None], reset_th, sth)
        sP = np.where(jump[:, None, None], reset_P, sP)
        self.theta[iv], self.P[iv], self.signs[iv] = th, P, signs
        self.shadow_theta[iv], self.shadow_P[iv] = sth, sP
        for b, v in zip(self.before, before):
            b[iv] = v

    def _correct(self, th, P, H, innov, informs):
        """The update with these innovations; k's gain 0 where not ``informs`` (the Schmidt update)."""
        PH = np.einsum("mij,mj->mi", P, H)
        S = np.einsum("mi,mi->m", H, PH) + self.cfg.force_sigma**2
        K = PH / S[:, None]
        K[:, 0] = np.where(informs, K[:, 0], 0.0)
        th = th + K * innov[:, None]
        A = np.eye(2)[None] - K[:, :, None] * H[:, None, :]
        P = np.einsum("mij,mjk,mlk->mil", A, P, A) + self.cfg.force_sigma**2 * K[:, :, None] * K[:, None, :]
        return th, P
