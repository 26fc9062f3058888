"""The traction observer's configuration, state layout and observability (paper eqs. 11-15 and 26-35).

The observer itself runs in the compiled core (soilocp/_core/src/observer/, behind
:class:`soilocp.estimation.observer_bank.ObserverBank`); its numpy / filterpy reference is the tests'
(tests/reference_observer.py).

State and observability (docs/method.md §7)
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
* Eq. 29's V_x_dot is the accelerometer's specific force f_x (docs/method.md §3): sum(mu_i Fz_i)/m
  is a specific force, which is why it has no slope term.
* Eq. 35 mixes indices (P_k with M_k+1); we use the standard predict/update (filterpy's, in the
  tests' reference) with the Joseph-form covariance update, re-symmetrised and with variances clamped (as robot_localization
  does), and per-row innovation (Mahalanobis) gating.
* Eqs. 33-34: A(t) and B(t) are rebuilt each step from the current normal forces and torques and
  discretised by zero-order hold.  A is nilpotent (A @ A = 0: traction coefficients drive speeds,
  speeds drive nothing), so the ZOH of the augmented system is exactly F = I + A dt, G = b dt
  and the process noise Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3; the tests' reference computes
  the same by the matrix exponential (Van Loan) for checking.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.model.vehicle import VehicleParams

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
    anchor_speed: float = Field(
        0.3, ge=0, description="m/s: below this rim and ground speed, a wheel-speed reading the gate rejects re-anchors "
        "that wheel's speed state to it (a stall under torque: the stiff wheel equation with a wrong traction state "
        "drove a filtered speed to 7 rad/s against a true 0.48, docs/method.md §17); 0 = off"
    )
    full_rate_share: float = Field(
        0.5, gt=0, lt=1, description="A reading stream whose value changes come at consecutive samples more often than "
        "this (running share) is read at the sample rate: a repeated value is a new, quantised reading of the same "
        "value, not a held one (the core's observer/readings.rs, docs/method.md §13)"
    )
    repeat_window: float = Field(
        0.5, ge=0, description="s: the longest a full-rate stream's unchanged value still counts as a new reading "
        "(a frozen driver repeats forever)"
    )
    ground_speed_latency_max: float = Field(
        0.3, ge=0, description="s: the longest ground-speed latency the observer measures against the accelerometer "
        "and leads the reading by (the core's observer/latency.rs, docs/method.md §13); 0 = none"
    )
    latency_window: float = Field(30.0, gt=0, description="s: memory of the ground-speed latency fit")
    refresh_jerk: float = Field(
        50.0, gt=0, description="rad/s^3: the wheel's unmeasured jerk between a slow wheel-speed stream's refreshes, "
        "which sets the variance of the interval's gross traction from the readings "
        "(the core's observer/intervals.rs, docs/method.md §13)"
    )
    refresh_min_interval: float = Field(
        0.1, gt=0, description="s: a wheel-speed stream held at least this long between its readings refreshes slowly, "
        "and its intervals' gross traction is taken from the readings (a quantised encoder's few repeats are not)"
    )
    refresh_max_interval: float = Field(
        1.0, gt=0, description="s: the longest refresh interval of a slow wheel-speed stream whose gross traction is "
        "taken from the readings (a longer one says little of the speed's course between them)"
    )
    variance_floor: float = Field(1e-10, gt=0)
    variance_ceiling: float = Field(1e4, gt=0)
    gravity: float = Field(STANDARD_GRAVITY, gt=0)
    # physics bounds and what the data determine (docs/method.md §11-12)
    mu_bound: float = Field(1.5, gt=0, description="|mu_i| (net traction coefficient) is kept <= this: no soil gives more")
    resistance_bound: float = Field(1.0, gt=0, description="|r0| and |mu_xR| shared constant part kept <= this")
    resistance_slope_bound: float = Field(5.0, gt=0, description="|r1| (d mu_xR / d|S|) kept <= this")
    lateral_bound: float = Field(2.0, gt=0, description="|mu_yR| kept <= this")
    speed_bias_bound: float = Field(3.0, gt=0, description="|speed-equation bias| kept <= this, m/s^2")
    mu_std_determined: float = Field(
        0.15, gt=0, description="mu_i counts as determined by the data while its posterior 1-sigma is <= this"
    )
    travel_speed: float = Field(0.05, gt=0, description="m/s over which the travel direction of a wheel is smoothed")
    bridge_slip: float = Field(0.005, ge=0, description="Zero-slip bridge of eq. 4's constant part (ModelConstants.bridge_slip)")
    max_wheel_speed: float = Field(1000.0, gt=0, description="A filtered wheel speed above this (rad/s) is divergence: reset")
    max_ground_speed: float = Field(100.0, gt=0, description="A filtered ground speed above this (m/s) is divergence: reset")


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

    def per_state(self, mu: float, res: float, res_slope: float, lat: float, omega: float, v: float, psi: float,
                  bias: float) -> np.ndarray:
        """(n,) one value per state, by kind (``res_slope`` for the second resistance state of the
        ``slip`` structure)."""
        out = np.zeros(self.n)
        out[self.mu] = mu
        out[self.res] = res
        if self.n_res == 2:
            out[self.res.start + 1] = res_slope
        out[self.lat] = lat
        out[self.omega] = omega
        out[self.v] = v
        out[self.psi] = psi
        out[self.bias] = bias
        return out

    def bounds(self, cfg: "ObserverConfig") -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) physical box of the state (docs/method.md §12: a net traction coefficient of 3
        is not a soil); speeds are unbounded here (the divergence guard watches them)."""
        inf = np.inf
        hi = self.per_state(cfg.mu_bound, cfg.resistance_bound, cfg.resistance_slope_bound, cfg.lateral_bound,
                            inf, inf, inf, cfg.speed_bias_bound)
        return -hi, hi


# measurement rows: f_x, yaw rate, omega_1..4, ground speed
N_MEAS = 7


def continuous_process_noise(layout: StateLayout, cfg: ObserverConfig) -> np.ndarray:
    """Q (n, n): diagonal random-walk intensities of the states, squared."""
    c = cfg
    return np.diag(layout.per_state(c.q_mu, c.q_resistance, c.q_resistance_slope, c.q_lateral, c.q_wheel_speed,
                                    c.q_ground_speed, c.q_yaw_rate, c.q_speed_bias) ** 2)


def observability_rank(structure: Structure, vehicle: VehicleParams, fz=None, slips=None, tol: float = 1e-9) -> int:
    """Rank of the observability matrix [H_0; H_1 F_0; H_2 F_1 F_0; ...] of the discretised model, with the
    core's own A and H (``ObserverCore.model``, soilocp/_core/src/observer/model.rs) and F = I + A dt (eq. 34,
    exact: A is nilpotent).

    ``slips`` is a sequence of per-wheel slip vectors, one per step (cycled), for the ``slip``
    structure whose model varies with slip; by default a traction test's pattern.  With the
    paper's full state (``per_wheel``) the rank is below the state dimension (docs/method.md §7);
    ``slip``, ``shared`` and ``none`` are fully observable (``slip`` only while the wheels' slips
    vary, as in a traction test: at one constant slip pattern its two resistance coefficients
    merge into one).
    """
    from soilocp.estimation.observer_bank import ObserverBank  # the core's bank (a module that imports this one)

    layout = StateLayout.of(structure)
    core = ObserverBank(vehicle, ObserverConfig(structure=structure), 1)._core
    fz = np.full(4, vehicle.mass * STANDARD_GRAVITY / 4) if fz is None else np.asarray(fz, float)
    if slips is None:
        # a traction test: rear wheels (1, 4) sweep driving slip, front wheels (2, 3) brake
        slips = [(0.3, -0.1, -0.1, 0.3), (0.1, -0.05, -0.05, 0.1), (0.5, -0.2, -0.2, 0.5)]
    blocks, Phi = [], np.eye(layout.n)
    for k in range(layout.n):
        # the state whose wheels run at these slips (eq. 1) at 1 m/s straight ahead: the resistance map's prior
        s = np.asarray(slips[k % len(slips)], float)
        x = np.zeros(layout.n)
        x[layout.v] = 1.0
        x[layout.omega] = np.where(s >= 0, 1.0 / (1.0 - np.minimum(s, 0.99)), 1.0 + s) / vehicle.wheel_radius
        A, _, H = core.model(x.tolist(), fz.tolist(), [0.0] * 4, 0.0)
        blocks.append(H @ Phi)
        Phi = (np.eye(layout.n) + A * 0.01) @ Phi
    O = np.vstack(blocks)
    # scale rows so that the tolerance is relative
    O = O / np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    return int(np.linalg.matrix_rank(O, tol=tol))


def initial_covariance(layout: StateLayout, cfg: ObserverConfig) -> np.ndarray:
    """P_0 (n, n): diagonal, from the config's initial 1-sigmas (speeds from their sensors' noise)."""
    c = cfg
    return np.diag(layout.per_state(c.p0_mu, c.p0_resistance, c.p0_resistance_slope, c.p0_lateral, c.r_wheel_speed,
                                    c.p0_speed, c.r_yaw_rate, c.p0_speed_bias) ** 2)
