"""Settings of the traction observer (its noise, prior, structure and bounds): pydantic only, no
numpy, so that a process that only reads the pipeline's configuration (the OCP publisher) does not
load the physics (:mod:`soilocp.estimation.observer` has the state layout and observability)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from soilocp.model.constants import STANDARD_GRAVITY

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
    p0_mu: float = Field(0.5, gt=0, description="Initial 1-sigma of mu_i (net traction coefficient)")
    p0_resistance: float = Field(0.2, gt=0, description="Initial 1-sigma of mu_xR (or its constant part)")
    p0_lateral: float = Field(0.5, gt=0, description="Initial 1-sigma of mu_yR")
    p0_speed: float = Field(0.1, gt=0, description="Initial 1-sigma of the ground-speed state, m/s (the wheel speeds and the "
                            "yaw rate start from their sensors' noise)")
    # robustness
    gate_sigma: float = Field(5.0, gt=0, description="Reject a measurement row whose innovation exceeds this many sigma")
    gate_patience: int = Field(
        10, ge=1, description="After this many consecutive rejections a row is accepted again (the model, not the sensor, is off)"
    )
    max_gap: float = Field(0.5, gt=0, description="A time step longer than this (s) re-initialises the filter")
    anchor_speed: float = Field(
        0.3, ge=0, description="m/s: below this rim and ground speed, a wheel-speed reading the gate rejects re-anchors "
        "that wheel's speed state to it (at a stall under torque the wheel equation is stiff, and with a wrong traction "
        "state it drives the filtered speed away from the encoder's, docs/method.md §17); 0 = off"
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
    variance_floor: float = Field(1e-10, gt=0, description="Smallest variance a state keeps after each step "
                                  "(its unit squared): the covariance stays positive definite")
    variance_ceiling: float = Field(1e4, gt=0, description="Largest variance a state keeps after each step "
                                    "(its unit squared)")
    gravity: float = Field(STANDARD_GRAVITY, gt=0, description="g, m/s^2: the speed equation's slope term "
                           "g sin(pitch) and the static wheel load m g / 4")
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
    max_wheel_speed: float = Field(1000.0, gt=0, description="A filtered wheel speed above this (rad/s) is divergence: reset")
    max_ground_speed: float = Field(100.0, gt=0, description="A filtered ground speed above this (m/s) is divergence: reset")
