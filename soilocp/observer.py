"""Kalman observer of per-wheel traction (paper eqs. 11-15 and 26-35), on filterpy.

State and observability (method-notes §7)
-----------------------------------------
The paper's state (eq. 26) is [mu_1..4, mu_xR_1..4, mu_yR_1..4, psi_dot, omega_1..4] with
measurements [V_x_dot, psi_dot, omega_1..4] (eq. 28).  It is not observable: each wheel equation
(eq. 13) sees only mu_i + mu_xR_i, the accelerometer (eq. 29) sees sum(mu_i Fz_i), and the yaw
equation (eq. 11) one more mix, so 17 states face 6 independent measurement directions and the
observability matrix has rank 10 (see :func:`observability_rank`).

The default ``structure="shared"`` makes the estimate determined: one longitudinal resistance
coefficient mu_xR shared by the four wheels (the wheels run on the same soil at similar slip), and
one lateral coefficient mu_yR.  Then the wheel equations give mu_i + mu_xR, the accelerometer gives
sum(mu_i Fz_i), hence mu_xR and every mu_i: full rank.  We also add the CoM speed V as a state,
driven by the same net traction (V_dot = sum(mu_i Fz_i)/m + g sin(pitch)) and measured by
ground_speed: that smooths the slip of eq. 1 with the physics instead of a low-pass filter; and a
slowly varying bias of that speed equation (accelerometer bias, g x pitch bias), which the ground
speed makes observable and which would otherwise turn into a slip bias.

``structure="none"`` drops motion-resistance compensation (mu_i absorbs mu_xR: the paper's
Figs. 11 and 13), ``structure="per_wheel"`` keeps the paper's full state (made well-posed only by
its prior; reported rank-deficient).

Corrections to the print
------------------------
* Eq. 29's V_x_dot is the accelerometer's specific force f_x (method-notes §3): sum(mu_i Fz_i)/m
  is a specific force, which is why it has no slope term.
* Eq. 35 mixes indices (P_k with M_k+1); we use the standard predict/update of filterpy with the
  Joseph-form covariance update, re-symmetrised and with variances clamped (as robot_localization
  does), and per-row innovation (Mahalanobis) gating.
* Eqs. 33-34: A(t) and B(t) are rebuilt each step from the current normal forces and torques and
  discretised by zero-order hold.  A is nilpotent (A @ A = 0: traction coefficients drive speeds,
  speeds drive nothing), so the ZOH of the augmented system is exactly F = I + A dt, G = b dt
  and the process noise Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3; ``discretization=
  "expm"`` computes the same by the matrix exponential (Van Loan) for checking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg
from filterpy.kalman import KalmanFilter
from pydantic import BaseModel, ConfigDict, Field

from .normal_force import STANDARD_GRAVITY
from .vehicle import VehicleParams

Structure = Literal["slip", "shared", "per_wheel", "none"]


class ObserverConfig(BaseModel):
    """Noise, prior and structure of the traction observer (documented defaults)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    structure: Structure = Field(
        "slip", description="slip (eq. 4's form, default) | shared | per_wheel (paper eq. 26) | none (no MR compensation)"
    )
    discretization: Literal["series", "expm"] = Field("series", description="exact ZOH by series (A nilpotent) or expm")
    # process noise: random-walk intensities (per sqrt(s)) of the coefficient states
    q_mu: float = Field(1.0, gt=0, description="Random-walk intensity of mu_i, 1/sqrt(s): slip sweeps move mu by ~1/s")
    q_resistance: float = Field(0.1, gt=0, description="Random-walk intensity of mu_xR (or its constant part), 1/sqrt(s)")
    q_resistance_slope: float = Field(0.1, gt=0, description="Random-walk intensity of d mu_xR/dS ('slip' structure), 1/sqrt(s)")
    p0_resistance_slope: float = Field(0.5, gt=0, description="Initial 1-sigma of d mu_xR/dS ('slip' structure)")
    q_lateral: float = Field(0.3, gt=0, description="Random-walk intensity of mu_yR, 1/sqrt(s)")
    q_wheel_speed: float = Field(0.3, gt=0, description="Unmodelled wheel acceleration, rad/s^2/sqrt(Hz) (torque ripple)")
    q_ground_speed: float = Field(0.1, gt=0, description="Unmodelled CoM acceleration, m/s^2/sqrt(Hz)")
    q_speed_bias: float = Field(0.005, gt=0, description="Random walk of the speed-equation bias, m/s^2/sqrt(s)")
    p0_speed_bias: float = Field(0.05, gt=0, description="Initial 1-sigma of the speed-equation bias, m/s^2")
    q_yaw_rate: float = Field(0.2, gt=0, description="Unmodelled yaw acceleration, rad/s^2/sqrt(Hz)")
    # measurement noise (1-sigma)
    r_specific_force: float = Field(0.08, gt=0, description="Accelerometer f_x noise incl. vibration, m/s^2")
    r_yaw_rate: float = Field(0.01, gt=0, description="Gyro noise, rad/s")
    r_wheel_speed: float = Field(0.03, gt=0, description="Encoder speed noise incl. quantisation, rad/s")
    r_ground_speed: float = Field(0.02, gt=0, description="GNSS / visual-odometry speed noise, m/s")
    # initial covariance (1-sigma)
    p0_mu: float = Field(0.5, gt=0)
    p0_resistance: float = Field(0.2, gt=0)
    p0_lateral: float = Field(0.5, gt=0)
    p0_speed: float = Field(0.1, gt=0)
    # robustness
    gate_sigma: float = Field(5.0, gt=0, description="Reject a measurement row whose innovation exceeds this many sigma")
    gate_patience: int = Field(
        10, ge=1, description="After this many consecutive rejections a row is accepted again (the model, not the sensor, is off)"
    )
    max_gap: float = Field(0.5, gt=0, description="A time step longer than this (s) re-initialises the filter")
    variance_floor: float = Field(1e-10, gt=0)
    variance_ceiling: float = Field(1e4, gt=0)
    gravity: float = Field(STANDARD_GRAVITY, gt=0)


@dataclass(frozen=True)
class StateLayout:
    """Index map of the observer state for a given structure."""

    structure: Structure
    n_res: int  # longitudinal resistance states: 2 (slip), 1 (shared), 4 (per wheel) or 0
    n_lat: int  # lateral resistance states: 1 or 4

    @property
    def mu(self) -> slice:
        return slice(0, 4)

    @property
    def res(self) -> slice:
        return slice(4, 4 + self.n_res)

    @property
    def lat(self) -> slice:
        return slice(4 + self.n_res, 4 + self.n_res + self.n_lat)

    @property
    def omega(self) -> slice:
        s = 4 + self.n_res + self.n_lat
        return slice(s, s + 4)

    @property
    def v(self) -> int:
        return 4 + self.n_res + self.n_lat + 4

    @property
    def psi(self) -> int:
        return self.v + 1

    @property
    def bias(self) -> int:
        """Bias of the speed equation (accelerometer bias + g x pitch bias), m/s^2."""
        return self.psi + 1

    @property
    def n(self) -> int:
        return self.bias + 1

    @staticmethod
    def of(structure: Structure) -> "StateLayout":
        if structure == "slip":
            return StateLayout(structure, 2, 1)
        if structure == "shared":
            return StateLayout(structure, 1, 1)
        if structure == "per_wheel":
            return StateLayout(structure, 4, 4)
        if structure == "none":
            return StateLayout(structure, 0, 1)
        raise ValueError(f"observer structure must be slip, shared, per_wheel or none, got {structure!r}")

    def resistance_matrix(self, slip=None, bridge: float = 0.005) -> np.ndarray:
        """(4, n_res) map from resistance states to each wheel's mu_xR.

        ``slip`` structure: mu_xR_i = r0 * sgn(S_i) + r1 * S_i, eq. 4's form C4 + C5/K + C6 |S|/sqrt(K)
        mirrored for braking (soilocp.traction's odd convention), with sgn smoothed over the
        zero-slip bridge.  r0, r1 are shared by the wheels (same soil), and the wheels' different
        slips make them identifiable over time.
        """
        if self.n_res == 2:
            s = np.zeros(4) if slip is None else np.asarray(slip, dtype=float)
            return np.stack([np.clip(s / bridge, -1.0, 1.0), s], axis=1)
        if self.n_res == 1:
            return np.ones((4, 1))
        if self.n_res == 4:
            return np.eye(4)
        return np.zeros((4, 0))


# measurement rows: f_x, yaw rate, omega_1..4, ground speed
N_MEAS = 7


def continuous_model(layout: StateLayout, vehicle: VehicleParams, fz: np.ndarray, torque: np.ndarray,
                     pitch: float, g: float = STANDARD_GRAVITY, slip=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A(t), b(t), H(t) of eq. 33, built from eqs. 11-15 and 29 at the current Fz and torques.

    omega_i_dot = (T_i - R_w (mu_i + mu_xR_i) Fz_i) / I_w          (eqs. 13-15)
    V_dot       = sum(mu_i Fz_i) / m + g sin(pitch)                  (longitudinal, REP-103 pitch)
    psi_ddot    = [d(Fx3 + Fx4) - c(Fx1 + Fx2) - M_zR] / I_z          (eqs. 11-12), Fx_i = mu_i Fz_i
    M_zR        = a(mu_yR1 Fz1 + mu_yR4 Fz4) + b(mu_yR2 Fz2 + mu_yR3 Fz3)
    z = [f_x = sum(mu_i Fz_i)/m (eq. 29), psi_dot, omega_1..4, V]
    """
    n = layout.n
    A = np.zeros((n, n))
    b = np.zeros(n)
    H = np.zeros((N_MEAS, n))
    R, Iw, m, Iz = vehicle.wheel_radius, vehicle.wheel_inertia, vehicle.mass, vehicle.yaw_inertia
    om = layout.omega
    wheel_gain = -R * fz / Iw
    A[om, layout.mu] = np.diag(wheel_gain)
    if layout.n_res:
        A[om, layout.res] = wheel_gain[:, None] * layout.resistance_matrix(slip)
    b[om] = torque / Iw
    A[layout.v, layout.mu] = fz / m
    # an accelerometer bias or a pitch bias would otherwise integrate into V and bias every slip
    A[layout.v, layout.bias] = -1.0
    b[layout.v] = g * np.sin(pitch)
    yaw_arm = np.array([-vehicle.c, -vehicle.c, vehicle.d, vehicle.d])
    A[layout.psi, layout.mu] = yaw_arm * fz / Iz
    lat_arm = np.array([vehicle.a, vehicle.b, vehicle.b, vehicle.a]) * fz
    if layout.n_lat == 1:
        A[layout.psi, layout.lat] = -lat_arm.sum() / Iz
    else:
        A[layout.psi, layout.lat] = -lat_arm / Iz
    H[0, layout.mu] = fz / m
    H[1, layout.psi] = 1.0
    H[2:6, om] = np.eye(4)
    H[6, layout.v] = 1.0
    return A, b, H


def continuous_process_noise(layout: StateLayout, cfg: ObserverConfig) -> np.ndarray:
    q = np.zeros(layout.n)
    q[layout.mu] = cfg.q_mu**2
    q[layout.res] = cfg.q_resistance**2
    if layout.n_res == 2:
        q[layout.res.start + 1] = cfg.q_resistance_slope**2
    q[layout.lat] = cfg.q_lateral**2
    q[layout.omega] = cfg.q_wheel_speed**2
    q[layout.v] = cfg.q_ground_speed**2
    q[layout.psi] = cfg.q_yaw_rate**2
    q[layout.bias] = cfg.q_speed_bias**2
    return np.diag(q)


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


def observability_rank(structure: Structure, vehicle: VehicleParams, fz=None, slips=None, tol: float = 1e-9) -> int:
    """Rank of the observability matrix [H_0; H_1 F_0; H_2 F_1 F_0; ...] of the discretised model.

    ``slips`` is a sequence of per-wheel slip vectors, one per step (cycled), for the ``slip``
    structure whose model varies with slip; by default a traction test's pattern.  With the
    paper's full state (``per_wheel``) the rank is below the state dimension (method-notes §7);
    ``slip``, ``shared`` and ``none`` are fully observable (``slip`` only while the wheels' slips
    vary, as in a traction test: at one constant slip pattern its two resistance coefficients
    merge into one).
    """
    layout = StateLayout.of(structure)
    fz = np.full(4, vehicle.mass * STANDARD_GRAVITY / 4) if fz is None else np.asarray(fz, float)
    if slips is None:
        # a traction test: rear wheels (1, 4) sweep driving slip, front wheels (2, 3) brake
        slips = [(0.3, -0.1, -0.1, 0.3), (0.1, -0.05, -0.05, 0.1), (0.5, -0.2, -0.2, 0.5)]
    blocks, Phi = [], np.eye(layout.n)
    for k in range(layout.n):
        A, b, H = continuous_model(layout, vehicle, fz, np.zeros(4), 0.0, slip=slips[k % len(slips)])
        F, _, _ = discretize(A, b, np.zeros_like(A), 0.01)
        blocks.append(H @ Phi)
        Phi = F @ Phi
    O = np.vstack(blocks)
    # scale rows so that the tolerance is relative
    O = O / np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    return int(np.linalg.matrix_rank(O, tol=tol))


@dataclass
class ObserverEstimate:
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
    extra: dict = field(default_factory=dict)


def _speed_bias_template(layout: StateLayout) -> np.ndarray:
    A = np.zeros((layout.n, layout.n))
    A[layout.v, layout.bias] = -1.0
    return A


class TractionObserver:
    """One vehicle's traction observer: filterpy KalmanFilter with matrices rebuilt every step."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None = None):
        self.vehicle = vehicle
        self.cfg = config or ObserverConfig()
        self.layout = StateLayout.of(self.cfg.structure)
        self._Qc = continuous_process_noise(self.layout, self.cfg)
        self._R = np.diag(
            [
                self.cfg.r_specific_force**2,
                self.cfg.r_yaw_rate**2,
                *([self.cfg.r_wheel_speed**2] * 4),
                self.cfg.r_ground_speed**2,
            ]
        )
        self.kf = KalmanFilter(dim_x=self.layout.n, dim_z=N_MEAS)
        self._last_stamp: float | None = None
        self._one = np.ones(1)
        self._rejections = np.zeros(N_MEAS, dtype=int)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self._J = np.zeros((4, self.layout.n))  # d gross / d x, filled per step
        self._J[:, self.layout.mu] = np.eye(4)
        self._R_diag = np.diag(self._R).copy()
        L, v = self.layout, vehicle
        H0 = np.zeros((N_MEAS, L.n))
        H0[1, L.psi] = 1.0
        H0[2:6, L.omega] = np.eye(4)
        H0[6, L.v] = 1.0
        self._tpl = {
            "A": _speed_bias_template(L), "b": np.zeros(L.n), "H": H0,
            "om_idx": np.arange(L.omega.start, L.omega.stop), "mu_idx": np.arange(4),
            "wheel_gain": -v.wheel_radius / v.wheel_inertia, "inv_iw": 1.0 / v.wheel_inertia, "inv_m": 1.0 / v.mass,
            "yaw_arm": np.array([-v.c, -v.c, v.d, v.d]) / v.yaw_inertia,
            "lat_arm": np.array([v.a, v.b, v.b, v.a]) / v.yaw_inertia,
        }
        self.steps = 0

    def _initialise(self, wheel_speed, ground_speed, yaw_rate) -> None:
        L, c = self.layout, self.cfg
        x = np.zeros(L.n)
        x[L.omega] = wheel_speed
        x[L.v] = ground_speed
        x[L.psi] = yaw_rate
        p = np.zeros(L.n)
        p[L.mu] = c.p0_mu**2
        p[L.res] = c.p0_resistance**2
        if L.n_res == 2:
            p[L.res.start + 1] = c.p0_resistance_slope**2
        p[L.lat] = c.p0_lateral**2
        p[L.omega] = c.r_wheel_speed**2
        p[L.v] = c.p0_speed**2
        p[L.psi] = c.r_yaw_rate**2
        p[L.bias] = c.p0_speed_bias**2
        self.kf.x = x
        self.kf.P = np.diag(p)
        self._rejections[:] = 0

    def step(self, stamp: float, specific_force_x: float, yaw_rate: float, pitch: float,
             wheel_speed, wheel_torque, ground_speed: float, normal_force) -> ObserverEstimate:
        """One predict/update cycle (eq. 35, standard form) for a sample at ``stamp``."""
        fz = np.asarray(normal_force, dtype=float)
        torque = np.asarray(wheel_torque, dtype=float)
        omega = np.asarray(wheel_speed, dtype=float)
        reset = False
        dt = None if self._last_stamp is None else stamp - self._last_stamp
        # ZOH over [k-1, k] with the inputs (Fz, T, pitch) of sample k held: the same matrices
        # serve the prediction to k and the measurement model at k.
        slip = self._state_slip() if self.layout.n_res == 2 and self._last_stamp is not None else None
        A, b, H = self._model(fz, torque, pitch, slip)
        if dt is None or dt < 0 or dt > self.cfg.max_gap:
            self._initialise(omega, ground_speed, yaw_rate)
            reset = True
        elif dt > 0:  # a repeated stamp (dt == 0) is a second measurement of the same instant
            F, G, Qd = discretize(A, b, self._Qc, dt, self.cfg.discretization)
            # filterpy: x = F x + B u with B = G (column) and u = 1
            self.kf.predict(u=self._one, B=G[:, None], F=F, Q=Qd)
        self._last_stamp = stamp
        z = np.array([specific_force_x, yaw_rate, *omega, ground_speed])
        rejected = 0
        if not reset:
            innov = z - H @ self.kf.x
            s = np.einsum("ij,jk,ik->i", H, self.kf.P, H) + self._R_diag
            keep = innov**2 <= (self.cfg.gate_sigma**2) * s
            # a row rejected again and again means the state has lost the sensor: re-acquire it
            # rather than coast on a diverging prediction
            keep |= self._rejections >= self.cfg.gate_patience
            self._rejections = np.where(keep, 0, self._rejections + 1)
            rejected = int(np.count_nonzero(~keep))
            if keep.all():
                self.kf.update(z, R=self._R, H=H)
            elif keep.any():
                idx = np.flatnonzero(keep)
                self.kf.update(z[idx], R=self._R[np.ix_(idx, idx)], H=H[idx])
            self._condition()
        self.steps += 1
        return self.estimate(rejected, reset)

    def _model(self, fz: np.ndarray, torque: np.ndarray, pitch: float, slip):
        """:func:`continuous_model` filled into preallocated templates (same matrices, tested)."""
        L, t = self.layout, self._tpl
        A, b, H = t["A"].copy(), t["b"].copy(), t["H"].copy()
        gain = fz * t["wheel_gain"]
        A[t["om_idx"], t["mu_idx"]] = gain
        if L.n_res:
            A[L.omega, L.res] = gain[:, None] * L.resistance_matrix(slip)
        b[L.omega] = torque * t["inv_iw"]
        fz_m = fz * t["inv_m"]
        A[L.v, L.mu] = fz_m
        b[L.v] = self.cfg.gravity * np.sin(pitch)
        A[L.psi, L.mu] = fz * t["yaw_arm"]
        lat = fz * t["lat_arm"]
        A[L.psi, L.lat] = -lat.sum() if L.n_lat == 1 else -lat
        H[0, L.mu] = fz_m
        return A, b, H

    def _gross_jacobian(self, M: np.ndarray) -> np.ndarray:
        J = self._J
        if self.layout.n_res:
            J[:, self.layout.res] = M
        return J

    def _state_slip(self) -> np.ndarray:
        """Per-wheel slip (eq. 1, floored) of the current estimate: the regressor of the 'slip'
        structure, taken from the prior so that the model stays linear within a step."""
        x, L, v = self.kf.x, self.layout, self.vehicle
        rim = x[L.omega] * v.wheel_radius
        ground = x[L.v] - x[L.psi] * self._wheel_y
        return (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)

    def _condition(self) -> None:
        """Keep P symmetric positive definite (symmetrise, clamp variances) over long runs."""
        P = (self.kf.P + self.kf.P.T) / 2.0
        d = np.clip(np.diag(P), self.cfg.variance_floor, self.cfg.variance_ceiling)
        np.fill_diagonal(P, d)
        self.kf.P = P

    def estimate(self, rejected: int = 0, reset: bool = False) -> ObserverEstimate:
        L = self.layout
        x, P = self.kf.x, self.kf.P
        mu = x[L.mu].copy()
        M = L.resistance_matrix(self._state_slip() if L.n_res == 2 else None)
        res = M @ x[L.res] if L.n_res else np.zeros(4)
        # gross_i = mu_i + (M x_res)_i : its variance from the joint covariance
        J = self._gross_jacobian(M)
        gross_var = np.einsum("ij,jk,ik->i", J, P, J)
        return ObserverEstimate(
            mu=mu,
            mu_var=np.diag(P)[L.mu].copy(),
            resistance=res,
            gross=mu + res,
            gross_var=gross_var,
            wheel_speed=x[L.omega].copy(),
            ground_speed=float(x[L.v]),
            yaw_rate=float(x[L.psi]),
            rejected=rejected,
            reset=reset,
        )
