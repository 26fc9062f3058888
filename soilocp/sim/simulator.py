"""Simulated 4-wheel, differentially steered rover (paper Fig. 6) with ground truth.

This is the truth the whole project is measured against.  It uses the library's physics and
nothing else: the traction model of :mod:`soilocp.model.traction` (net traction mu, eq. 6; gross
traction g, eq. 3; motion resistance r = g - mu, eq. 4, odd in slip and bridged near S = 0,
docs/method.md §8), the zero-warp normal-force solver of :mod:`soilocp.model.normal_force` (eqs. 16-25
corrected, docs/method.md §2-3), slip eq. 1 with the standstill floor of :mod:`soilocp.model.slip`
(docs/method.md §6, §10) and the OCPs of :mod:`soilocp.model.ocp`.

Model (wheels 1 LR, 2 LF, 3 RF, 4 RR; body x forward, y left, z up, REP-103):

* slip of wheel i, eq. 1: S_i = (omega_i R_w - V_i) / max(|omega_i R_w|, |V_i|, floor), with the
  ground speed at the wheel V_i = V - psi_dot * y_i (differential steering);
* wheel i, eq. 13: I_w omega_i' = T_i - R_w (mu_i + r_i) Fz_i: the wheel sees gross traction;
* body, longitudinal: m V' = sum(mu_i Fz_i) - m g sin(grade) (net traction already contains
  the motion resistance; -g sin(grade) is the x component of gravity, eq. 20 with pitch = -grade);
* yaw, eqs. 11-12: I_z psi'' = d (Fx3 + Fx4) - c (Fx1 + Fx2) - M_zR with Fx_i = mu_i Fz_i and the
  skid-steer resistance moment M_zR = mu_y (a (Fz1 + Fz4) + b (Fz2 + Fz3)) tanh(psi'/eps), which
  opposes the yaw rate smoothly (eq. 12 with a regularised sign);
* normal forces from the TRUE specific force f = (V', V psi', 0) + g_R(roll, pitch) (eq. 20's
  gravity reaction plus the acceleration, docs/method.md §3) through the zero-warp solver, solved
  together with the dynamics in each step (see ``_Run._substep`` for why not lagged).

Lateral sliding is not modelled (the rover tracks its heading); grade and cross-slope are those
of the segment under the CoM, taken as pitch = -grade and roll = +cross_slope.

Stiffness (docs/method.md §10): at low speed the wheel-slip time constants are well below 1 ms,
so every sub-step (default <= 2.5 ms, several per sensor interval) is a backward-Euler step of
(omega_1..4, V, psi') solved by Newton's method with the analytic Jacobian (d g/dS, d mu/dS,
d S/d omega, d S/dV, d Fz/dV, d Fz/d psi'; the 6x6 system is reduced to 2x2 by eliminating the
diagonal wheel block).  For speed, eqs. 3 and 6 and their slip derivatives are sampled from
:mod:`soilocp.model.traction` on a fine slip grid (1e-4) per soil strength and interpolated; the truth
record reports the accepted iterate's own slip and coefficients, which agree with
:mod:`soilocp.model.traction` at that slip to better than 5e-7 (tested).

Energy is booked per sub-step so that a test can close the balance
motor work = kinetic + potential energy change + dissipation (+ the integrator's own, >= 0).
"""

from __future__ import annotations

import bisect
import itertools
import math
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from schemas.sensor import VEHICLE_ID_PATTERN, SensorSample

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.normal_force import STANDARD_GRAVITY, gravity_from_attitude, normal_forces
from soilocp.model.ocp import ocp_from_soil_strength
from soilocp.sim.scenarios import MODES, Scenario, SweepParams, get_scenario
from soilocp.sim.sensor_models import SensorNoise, SensorSuite
from soilocp.model.slip import DEFAULT_FLOOR
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams

TRUTH_SCHEMA_ID = "soilocp.truth_record/1"

#: m/s: the drawbar draft ramps in as tanh(V / _LOAD_EPS), so that it resists motion like friction
_LOAD_EPS = 0.05

_F4 = tuple[float, float, float, float]
_F3 = tuple[float, float, float]


class TruthRecord(BaseModel):
    """Ground truth of the simulated rover at one sensor sample (same vehicle_id / seq / stamp).

    Per-wheel lists are in the paper's order: 1 left-rear, 2 left-front, 3 right-front, 4 right-rear.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, title="TruthRecord", json_schema_extra={"$id": TRUTH_SCHEMA_ID})

    vehicle_id: str
    seq: int = Field(ge=0)
    stamp: float = Field(ge=0, description="s, equal to the sensor sample's stamp")
    mode: Literal["cruise", "excitation"] = Field(description="Wheel-speed controller mode")
    segment: int = Field(ge=0, description="Index of the terrain segment under the CoM")
    soil_class: str = Field(description="Soil class of the segment under the CoM")
    soil_strength: float = Field(gt=0, description="True soil strength K under the CoM")
    wheel_soil_strength: _F4 = Field(description="True K under each wheel (front wheels cross changes first)")
    grade: float = Field(description="Grade under the CoM, rad, > 0 = climb (pitch = -grade)")
    cross_slope: float = Field(description="Cross-slope under the CoM, rad, > 0 = left side up (roll = +cross_slope)")
    roll: float = Field(description="True roll, rad (REP-103, > 0 left side up)")
    pitch: float = Field(description="True pitch, rad (REP-103, > 0 nose down; < 0 on a climb)")
    distance: float = Field(description="Distance travelled by the CoM, m")
    heading: float = Field(description="Yaw angle relative to the start, rad")
    yaw_rate: float = Field(description="True yaw rate, rad/s, > 0 turning left")
    slip: _F4 = Field(description="Slip per wheel, eq. 1 with V_i = V - yaw_rate*y_i (> 0 driving)")
    mu: _F4 = Field(description="Net traction coefficient per wheel, eq. 6 (F_DP / Fz)")
    motion_resistance: _F4 = Field(description="Motion-resistance coefficient per wheel, eq. 4 (= gross - mu)")
    gross_traction: _F4 = Field(description="Gross traction coefficient per wheel, eq. 3 (what the wheel's eq. 13 sees)")
    normal_force: _F4 = Field(description="Normal force per wheel, N (zero-warp solution from specific_force)")
    ground_speed: float = Field(description="Longitudinal speed of the CoM, m/s")
    wheel_speed: _F4 = Field(description="True wheel angular speeds, rad/s")
    wheel_torque: _F4 = Field(description="True motor torques at the wheels, N m")
    specific_force: _F3 = Field(description="True specific force at the CoM, m/s^2 (body x fwd, y left, z up)")
    speed_command: float = Field(description="Vehicle speed set-point, m/s (ramps up from rest)")
    slip_command: float | None = Field(description="Front-axle slip set-point in excitation mode (None in cruise)")
    mu_T: float = Field(description="Maximum traction coefficient for the true K under the CoM (eq. 8)")
    S_T: float = Field(description="Slip of maximum traction for the true K under the CoM (eq. 7 corrected)")
    S_E: float = Field(description="Slip of best efficiency for the true K under the CoM (eq. 10)")
    motor_work: float = Field(description="Work done by the four motors since the start, J")
    kinetic_energy: float = Field(description="Body translation + yaw + wheel spin kinetic energy, J")
    potential_energy: float = Field(description="m g (height gained since the start), J")
    slip_dissipation: float = Field(description="Energy dissipated by slip, sum Fz g (omega R_w - V_i) dt, J (>= 0)")
    resistance_work: float = Field(
        description="Work of motion resistance, sum Fz r V_i dt, J (can be < 0 for K < ~125, docs/method.md §8)"
    )
    yaw_dissipation: float = Field(description="Energy dissipated by the skid-steer moment M_zR, J (>= 0)")


@dataclass(frozen=True)
class ControllerParams:
    """Wheel-speed PI controllers (one per wheel) and the outer speed / heading loops."""

    wheel_kp: float = 10.0  #: N m per rad/s
    wheel_ki: float = 200.0  #: N m per rad
    torque_limit: float = 40.0  #: |T| max per wheel, N m
    speed_kp: float = 1.0  #: rear-axle speed loop (excitation), m/s per m/s
    speed_ki: float = 3.0  #: 1/s
    speed_i_limit: float = 0.25  #: bound on the speed PI's integral, m (anti-windup)
    yaw_kp: float = 1.0  #: heading correction, rad/s per rad/s of yaw rate
    yaw_ki: float = 2.0  #: 1/s
    ramp_time: float = 2.0  #: smooth start: speed (and sweep amplitude) ramp from 0, s
    #: Sweep governor: when the braking axle cannot hold the cycle-mean speed (low-pass, time
    #: constant governor_tau), the slip set-point is scaled by 1 - gain * (overspeed - deadband).
    #: The truth records the actual set-point.
    governor_gain: float = 4.0
    governor_deadband: float = 0.05
    governor_tau: float = 1.5
    #: Excitation: the speed-holding axle never brakes harder than this slip, so that it stays on
    #: the stable side of the traction peak (past it a braking wheel locks).
    brake_slip_limit: float = 0.35
    #: Excitation: > 0 makes the rear axle mirror the front's slip set-point (brake at about
    #: -rear_mirror x S, trimmed by the speed PI) instead of holding the speed alone (docs/method.md §12).
    rear_mirror: float = 0.0
    mirror_trim: float = 0.05  #: rear_mirror: slip trim per m/s of the speed PI output (small: a close mirror)
    #: S-turns: yaw-rate set-point s_turn_rate * sin(2 pi t / s_turn_period), rad/s (0 = heading hold).
    s_turn_rate: float = 0.0
    s_turn_period: float = 6.0

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"controller {name} must be finite and >= 0, got {v!r}")
        if self.governor_tau <= 0 or self.torque_limit <= 0:
            raise ValueError(f"controller torque_limit and governor_tau must be > 0, got {self.torque_limit!r}, {self.governor_tau!r}")


@dataclass(frozen=True)
class SimParams:
    """Integrator and resistance-moment settings."""

    max_substep: float = 0.0025  #: s; sub-steps per sensor interval = ceil(interval / max_substep)
    lateral_resistance: float = 0.2  #: mu_y of eq. 12
    yaw_rate_eps: float = 0.05  #: rad/s, smoothing of sign(psi') in M_zR
    slip_floor: float = DEFAULT_FLOOR  #: m/s, floor on eq. 1's denominator (standstill)
    newton_tol: float = 1e-8  #: accept a Newton iterate once its update is below this (rad/s, m/s)
    newton_loose_tol: float = 1e-4  #: intermediate sub-steps: accept the first update below this
    newton_max_iter: int = 8

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"sim parameter {name} must be finite and > 0, got {v!r}")


DEFAULT_CONTROLLER = ControllerParams()
DEFAULT_SIM = SimParams()


class _TractionTable:
    """Gross (eq. 3) and net (eq. 6) traction and their slip derivatives, sampled from
    :mod:`soilocp.model.traction` on a uniform slip grid per soil strength and linearly interpolated.

    The integrator's inner loop is scalar Python (four wheels: numpy's per-call overhead would
    dominate), so the tables are Python lists on a uniform grid, indexed in O(1) by
    ``_Run._substep``: j = int((S + SPAN) / STEP), then linear interpolation.
    """

    STEP = 1e-4
    SPAN = 2.0  # |S| <= 2 for eq. 1 with the max() denominator

    def __init__(self, constants: ModelConstants):
        self.constants = constants
        self.n = int(round(2 * self.SPAN / self.STEP)) + 1
        self.grid = np.linspace(-self.SPAN, self.SPAN, self.n)
        self._tabs: dict[float, tuple[list[float], ...]] = {}

    def tables(self, k: float) -> tuple[list[float], list[float], list[float], list[float]]:
        """(g, dg/dS, mu, dmu/dS) sampled on the grid for soil strength k (built once per k)."""
        k = float(k)
        if k not in self._tabs:
            g, dg, _ = gross_traction_with_derivatives(self.grid, k, self.constants)
            mu, dmu, _ = net_traction_with_derivatives(self.grid, k, self.constants)
            self._tabs[k] = (g.tolist(), dg.tolist(), mu.tolist(), dmu.tolist())
        return self._tabs[k]


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def _check_args(duration, rate, seed, mode, vehicle_id):
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 0 < rate <= 2000):
        raise ValueError(f"rate must be in (0, 2000] Hz, got {rate!r}")
    if duration is not None and not (isinstance(duration, (int, float)) and not math.isnan(duration) and duration > 0):
        raise ValueError(f"duration must be > 0 s (math.inf = endless, for a live vehicle), got {duration!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if mode is not None and mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    # the sensor schema validates the id pattern; check it here so that a bad id fails at once
    if not isinstance(vehicle_id, str) or not re.match(VEHICLE_ID_PATTERN, vehicle_id):
        raise ValueError(f"vehicle_id must match {VEHICLE_ID_PATTERN}, got {vehicle_id!r}")


def simulate(
    scenario: str | Scenario,
    *,
    duration: float | None = None,
    rate: float = 100.0,
    seed: int = 0,
    vehicle: VehicleParams = DEFAULT_VEHICLE,
    constants: ModelConstants = DEFAULT_CONSTANTS,
    mode: str | None = None,
    noise: SensorNoise | None = None,
    vehicle_id: str = "rover1",
    sweep: SweepParams | None = None,
    controller: ControllerParams = DEFAULT_CONTROLLER,
    params: SimParams = DEFAULT_SIM,
    wheel_torque_command: Callable[[SensorSample], Sequence[float]] | None = None,
    drawbar_load: Callable[[float, float], float] | None = None,
) -> Iterator[tuple[SensorSample, TruthRecord]]:
    """Drive ``scenario`` and yield ``(SensorSample, TruthRecord)`` pairs lazily, one per sensor
    sample at ``stamp = seq / rate`` (seq 0 = at rest at t = 0), for ``duration`` seconds
    (default: the scenario's; ``math.inf`` = endless, for a live synthetic vehicle).  Arguments are checked at once (ValueError), before the first sample.

    ``mode`` overrides the scenario's controller mode; ``sweep`` its front-axle slip sweep;
    ``noise`` the sensor noise levels (None = :class:`SensorNoise` defaults;
    ``SensorNoise.noiseless()`` = exact truth through the sensors).  The same seed gives the same logs.

    Closed-loop hooks (``soilocp.control``), both None by default (the built-in controllers):

    * ``wheel_torque_command(sample)`` is called with each sensor sample before the next interval
      is integrated and returns the four motor torques (N m, clamped to the controller's
      ``torque_limit``), held over that interval (zero-order hold, as a digital motor drive):
      it replaces the wheel-speed PIs, so an external controller closes the loop on the sensors.
    * ``drawbar_load(t, V)`` is a towed load's draft force (N >= 0) at time t and speed V, held over each
      interval; it opposes the motion like friction (F tanh(V / _LOAD_EPS)), so a stalled
      rover is not pulled backwards (``_LOAD_EPS`` = 0.05 m/s).
    """
    sc = get_scenario(scenario)
    _check_args(duration, rate, seed, mode, vehicle_id)
    if not isinstance(vehicle, VehicleParams):
        raise ValueError(f"vehicle must be a VehicleParams, got {type(vehicle).__name__}")
    if not isinstance(constants, ModelConstants):
        raise ValueError(f"constants must be a ModelConstants, got {type(constants).__name__}")
    if noise is not None and not isinstance(noise, SensorNoise):
        raise ValueError(f"noise must be a SensorNoise or None, got {type(noise).__name__}")
    if sweep is not None:
        sc = sc.with_overrides(sweep=sweep)
    run = _Run(
        sc,
        duration=float(duration if duration is not None else sc.duration),
        rate=float(rate),
        rng=np.random.default_rng(seed),
        vehicle=vehicle,
        constants=constants,
        mode=mode or sc.mode,
        noise=noise if noise is not None else SensorNoise(),
        vehicle_id=vehicle_id,
        ctl=controller,
        par=params,
        torque_command=wheel_torque_command,
        drawbar_load=drawbar_load,
    )
    return run.samples()


def _side_references(ref: list[float]) -> list[float]:
    """Skid steer (vehicle drive per_side): one motor per side turns both of its wheels (chained),
    so both follow one speed reference, the mean of what the side's two wheels would get; in
    excitation mode the front sweep and the rear's speed hold then act on the whole side.  The two
    wheels keep their own stiff speed loops: a chain is rigid, the loops nearly so."""
    left, right = 0.5 * (ref[0] + ref[1]), 0.5 * (ref[2] + ref[3])
    return [left, left, right, right]


def _side_readings(read: dict) -> dict:
    """What a per-side drive measures: one encoder and one motor current per side.  Both wheels of
    a side read the side's speed (mean of the two) and half the side's total torque."""
    w, t = read["wheel_speed"], read["wheel_torque"]
    ws = (0.5 * (w[0] + w[1]), 0.5 * (w[2] + w[3]))
    ts = (0.5 * (t[0] + t[1]), 0.5 * (t[2] + t[3]))
    return {**read, "wheel_speed": (ws[0], ws[0], ws[1], ws[1]), "wheel_torque": (ts[0], ts[0], ts[1], ts[1])}


class _Run:
    """State and stepping of one simulated drive (scalar Python inner loop over the 4 wheels)."""

    def __init__(self, sc: Scenario, *, duration, rate, rng, vehicle, constants, mode, noise, vehicle_id, ctl, par,
                 torque_command=None, drawbar_load=None):
        self.sc, self.duration, self.rate, self.mode = sc, duration, rate, mode
        self.v, self.c, self.ctl, self.par, self.vehicle_id = vehicle, constants, ctl, par, vehicle_id
        self.interval = 1.0 / rate
        self.n_sub = max(1, math.ceil(self.interval / par.max_substep - 1e-9))
        self.h = self.interval / self.n_sub
        self.sensors = SensorSuite(noise, rng, self.interval)
        self.table = _TractionTable(constants)
        self.x_w = np.array(vehicle.wheel_x)
        self.y_w = np.array(vehicle.wheel_y)
        self.ys = [float(q) for q in vehicle.wheel_y]
        self.xs = [float(q) for q in vehicle.wheel_x]
        self._starts = [float(q) for q in sc.starts]
        self.front = [xq > 0 for xq in vehicle.wheel_x]
        self.absx = [abs(float(q)) for q in vehicle.wheel_x]
        # normal_forces is linear in the specific force (B of eq. 24 is): Fz = f @ N exactly.
        self.fz_matrix = normal_forces(vehicle, np.eye(3))
        self._nz = self.fz_matrix.T.tolist()  # per wheel: (dFz/dfx, dFz/dfy, dFz/dfz)
        self._ocp_cache: dict[float, object] = {}
        # state
        self.t = 0.0
        self.w = [0.0] * 4  # wheel speeds, rad/s
        self.V = 0.0  # CoM longitudinal speed, m/s
        self.r = 0.0  # yaw rate, rad/s
        self.prev = [0.0] * 6  # previous (w, V, r), for the Newton predictor
        self.dist = 0.0
        self.heading = 0.0
        self.z = 0.0
        self.wheel_angle = [0.0] * 4
        self.acc = 0.0  # V' of the last sub-step
        self.i_wheel = [0.0] * 4
        self.i_speed = 0.0
        self.i_yaw = 0.0
        self.v_mean = 0.0  # low-passed speed for the sweep governor
        self.torque = [0.0] * 4
        self.slips, self.gross, self.mus = [0.0] * 4, [0.0] * 4, [0.0] * 4
        self.slip_cmd: float | None = None
        self.speed_cmd = 0.0
        self.energy = dict(motor_work=0.0, slip_dissipation=0.0, resistance_work=0.0, yaw_dissipation=0.0)
        self.newton_iters = 0
        self.newton_failures = 0
        self.substeps = 0
        self.torque_command, self.drawbar_load = torque_command, drawbar_load
        self.held_torque: list[float] | None = None  # external torque command over this interval
        self.load = 0.0  # drawbar draft force over this interval, N
        self.drawbar_work = 0.0  # work done against the draft, J (not in the truth record's balance)
        self._terrain()
        self.f_used = self._specific_force()
        self.fz = self._fz(self.f_used)

    # --- terrain -------------------------------------------------------------------------
    def _terrain(self) -> None:
        segs = self.sc.segments
        if len(segs) == 1 and hasattr(self, "seg"):
            return
        starts, d = self._starts, self.dist
        seg_wheels = [max(bisect.bisect_right(starts, d + xi) - 1, 0) for xi in self.xs]
        seg_com = max(bisect.bisect_right(starts, d) - 1, 0)
        if hasattr(self, "seg") and seg_com == self.seg and seg_wheels == self.seg_wheels:
            return
        self.seg_wheels, self.seg = seg_wheels, seg_com
        seg = segs[self.seg]
        self.k_wheels = np.array([segs[j].soil_strength for j in seg_wheels])
        self.k_tabs = [self.table.tables(k) for k in self.k_wheels]
        self.roll, self.pitch = seg.cross_slope, 0.0 - seg.grade  # (0.0 - x: no "-0.0" in the logs)
        self.f_grav = [float(q) for q in gravity_from_attitude(self.roll, self.pitch, STANDARD_GRAVITY)]

    def _specific_force(self) -> tuple[float, float, float]:
        """True specific force: acceleration (V', V psi', 0) + gravity reaction (eq. 20), body frame."""
        fg = self.f_grav
        return (fg[0] + self.acc, fg[1] + self.V * self.r, fg[2])

    def _fz(self, f) -> list[float]:
        """Zero-warp normal forces (eqs. 16-25 corrected), via the exact linear map of normal_forces."""
        return [n[0] * f[0] + n[1] * f[1] + n[2] * f[2] for n in self._nz]

    # --- controller ----------------------------------------------------------------------
    def _references(self, t: float) -> list[float]:
        """Wheel-speed references for the sub-step ending at t (explicit in the step)."""
        ctl, R, h, sc = self.ctl, self.v.wheel_radius, self.h, self.sc
        ramp = _smoothstep(t / ctl.ramp_time) if ctl.ramp_time > 0 else 1.0
        v_ref = sc.speed * ramp
        self.speed_cmd = v_ref
        # heading hold: a yaw-rate PI commands a small differential (V_i = V - r_c y_i)
        if ctl.s_turn_rate > 0:  # S-turns: the same PI around a sinusoidal yaw-rate set-point
            r_ref = ctl.s_turn_rate * ramp * math.sin(2.0 * math.pi * t / ctl.s_turn_period)
            self.i_yaw += h * (self.r - r_ref)
            r_c = r_ref - (ctl.yaw_kp * (self.r - r_ref) + ctl.yaw_ki * self.i_yaw)
        else:
            self.i_yaw += h * self.r
            r_c = -(ctl.yaw_kp * self.r + ctl.yaw_ki * self.i_yaw)
        if self.mode == "cruise":
            self.slip_cmd = None
            return [max(v_ref - r_c * yi, 0.0) / R for yi in self.ys]
        # excitation: the front axle sweeps driving slip, the rear holds the speed by braking
        # (scenarios.SweepParams explains why not the other way round)
        s_cmd = sc.sweep.slip_at(t) * ramp
        # the governor acts on the cycle-mean speed, not on the excursions within one sweep
        self.v_mean += h / ctl.governor_tau * (self.V - self.v_mean)
        over = (self.v_mean - sc.speed) / sc.speed - ctl.governor_deadband
        if over > 0:
            s_cmd *= max(0.0, 1.0 - ctl.governor_gain * over)
        self.slip_cmd = s_cmd
        err = v_ref - self.V
        # rear: speed PI.  Its integrator keeps integrating while the braking slip is clamped, so
        # that the dwell makes up for the overspeed near the sweep's peak (mean speed = V_ref).
        self.i_speed = min(max(self.i_speed + h * err, -ctl.speed_i_limit), ctl.speed_i_limit)
        if ctl.rear_mirror > 0:  # braking slip -m S means omega R = V (1 - m S); the PI trims the slip
            trim = ctl.mirror_trim * (ctl.speed_kp * err + ctl.speed_ki * self.i_speed)
            v_hold = max(self.V, v_ref) * (1.0 - ctl.rear_mirror * s_cmd + trim)  # v_ref: start from rest
        else:
            v_hold = v_ref + ctl.speed_kp * err + ctl.speed_ki * self.i_speed
        # the braking axle stays on the stable side of the traction peak: slip >= -brake_slip_limit
        v_hold = max(v_hold, self.V * (1.0 - ctl.brake_slip_limit))
        out = []
        for front, yi in zip(self.front, self.ys):
            if front:
                out.append(max(self.V - r_c * yi, 0.0) / (R * (1.0 - s_cmd)))
            else:
                out.append(max(v_hold - r_c * yi, 0.0) / R)
        return _side_references(out) if self.v.drive == "per_side" else out

    # --- one backward-Euler sub-step -----------------------------------------------------
    def _substep(self, final: bool) -> None:
        """Backward Euler for (omega_1..4, V, psi') by Newton's method (analytic Jacobian, the
        diagonal wheel block eliminated).  Eq. 13 per wheel with gross traction, the longitudinal
        and yaw equations (eqs. 11-12) with net traction, and the normal forces (zero-warp solution
        of eqs. 16-25) from the specific force of the SAME step, f = ((V - V0)/h, V psi', 0) + g_R.

        The load transfer is implicit on purpose: with h/L = 0.6 and |mu| ~ 1 the loop
        acceleration -> Fz -> traction -> acceleration has a gain above 1 (one axle driving, the
        other braking), and a one-step lag turns it into a numerical oscillation of the whole
        rover.

        The last sub-step before a sample (``final``) iterates until the update is below
        ``newton_tol`` and keeps the iterate whose forces were evaluated, so that the reported state
        and forces are exactly consistent; intermediate sub-steps accept the first update once it is
        below ``newton_loose_tol`` (then they are linearly implicit Euler steps, also L-stable)."""
        v, ctl, par, h = self.v, self.ctl, self.par, self.h
        t_new = self.t + h
        self._terrain()
        w_ref = self._references(t_new)
        R, m, Iw, Iz, ys, ax = v.wheel_radius, v.mass, v.wheel_inertia, v.yaw_inertia, self.ys, self.absx
        kp, tmax = ctl.wheel_kp, ctl.torque_limit
        held, load = self.held_torque, self.load
        if held is not None:
            kp = 0.0  # torque held over the interval: no d T / d omega in the Jacobian
        t_int = [ctl.wheel_ki * q for q in self.i_wheel]
        muy, eps, floor, tol = par.lateral_resistance, par.yaw_rate_eps, par.slip_floor, par.newton_tol
        loose = par.newton_loose_tol
        gx, gy, gz = self.f_grav  # m V' = sum(mu Fz) - m gx  (gx = g sin(grade))
        nz = self._nz
        w0, V0, r0 = self.w, self.V, self.r
        x0 = [*w0, V0, r0]
        x = [2.0 * a - b for a, b in zip(x0, self.prev)]  # linear predictor
        tabs = self.k_tabs
        span, inv_step, last = self.table.SPAN, 1.0 / self.table.STEP, self.table.n - 1
        Fw, BV, Br, inv, gs, mus, tq, traw, ss, fz, cv = ([0.0] * 4 for _ in range(11))
        # skid steer: the two wheels of a side are chained to one motor (one speed per side)
        units = ((0, 1), (2, 3)) if v.drive == "per_side" else ((0,), (1,), (2,), (3,))
        hkp, hR, inv_h = h * kp, h * R, 1.0 / h
        for it in range(par.newton_max_iter):
            V, r = x[4], x[5]
            f = (gx + (V - V0) * inv_h, gy + V * r, gz)
            lz = lzV = lzr = 0.0
            sum_fx = sum_yfx = 0.0
            eVV = eVr = eRV = eRr = 0.0  # sums for the V and yaw rows' own partials
            a11c = a12c = a21c = a22c = b1c = b2c = 0.0
            for i in range(4):
                wi, yi = x[i], ys[i]
                nx_, ny_, nz_ = nz[i]
                fzi = nx_ * f[0] + ny_ * f[1] + nz_ * f[2]
                zV = nx_ * inv_h + ny_ * r  # dFz/dV
                zr = ny_ * V  # dFz/d psi'
                lz += ax[i] * fzi
                lzV += ax[i] * zV
                lzr += ax[i] * zr
                vi = V - r * yi
                # eq. 1 exactly as soilocp.model.slip.slip_ratio (floored denominator; the truth test
                # checks the reported slip against slip_ratio) and its partials for the Jacobian
                rho = wi * R
                arho, av = abs(rho), abs(vi)
                d = max(arho, av, floor)
                s = (rho - vi) / d
                if arho >= av and arho >= floor:
                    sw = (vi if rho > 0 else -vi) / (d * d) * R
                    sv = -1.0 / d
                elif av >= floor:
                    sw = R / d
                    sv = (-rho if vi > 0 else rho) / (d * d)
                else:
                    sw = R / d
                    sv = -1.0 / d
                # _TractionTable lookup, inline (this loop is the hot path)
                u = (s + span) * inv_step
                if u <= 0.0:
                    j, fr = 0, 0.0
                elif u >= last:
                    j, fr = last - 1, 1.0
                else:
                    j = int(u)
                    fr = u - j
                tg, tdg, tmu, tdmu = tabs[i]
                g = tg[j] + fr * (tg[j + 1] - tg[j])
                dg = tdg[j] + fr * (tdg[j + 1] - tdg[j])
                mu = tmu[j] + fr * (tmu[j + 1] - tmu[j])
                dmu = tdmu[j] + fr * (tdmu[j + 1] - tdmu[j])
                tr = kp * (w_ref[i] - wi) + t_int[i] if held is None else held[i]
                if tr > tmax:
                    T, kpe = tmax, 0.0
                elif tr < -tmax:
                    T, kpe = -tmax, 0.0
                else:
                    T, kpe = tr, hkp
                # wheel row (eq. 13) and its partials
                fwi = Iw * (wi - w0[i]) - h * T + hR * g * fzi
                k1 = hR * fzi * dg
                invi = 1.0 / (Iw + kpe + k1 * sw)
                bvi = k1 * sv + hR * g * zV
                bri = -k1 * sv * yi + hR * g * zr
                # body rows: d(mu Fz)/dV and d(mu Fz)/d psi'
                ai = fzi * dmu
                dFV = ai * sv + mu * zV
                dFr = -ai * sv * yi + mu * zr
                eVV += dFV
                eVr += dFr
                eRV += yi * dFV
                eRr += yi * dFr
                cv[i] = -h * ai * sw  # CV_i: the body row's d/d omega_i (and Cr_i = -CV_i y_i)
                fx = mu * fzi
                sum_fx += fx
                sum_yfx += yi * fx
                Fw[i], BV[i], Br[i], inv[i] = fwi, bvi, bri, invi
                gs[i], mus[i], tq[i], traw[i], ss[i], fz[i] = g, mu, T, tr, s, fzi
            # eliminate the wheel rows: each wheel (or, skid steer, each side's chained pair: one speed,
            # the pair's rows summed) couples to the body rows through CV / D
            for u in units:
                d_u = sum(1.0 / inv[i] for i in u)
                f_u, bv_u, br_u = sum(Fw[i] for i in u), sum(BV[i] for i in u), sum(Br[i] for i in u)
                q = sum(cv[i] for i in u) / d_u
                yu = ys[u[0]]
                a11c += q * bv_u
                a12c += q * br_u
                a21c -= q * yu * bv_u
                a22c -= q * yu * br_u
                b1c += q * f_u
                b2c -= q * yu * f_u
                for i in u:
                    Fw[i], BV[i], Br[i], inv[i] = f_u, bv_u, br_u, 1.0 / d_u
            th = math.tanh(r / eps)
            FV = m * (V - V0) - h * (sum_fx - m * gx)
            if load:  # draft opposing the motion, implicit like the rest of the body row
                thl = math.tanh(V / _LOAD_EPS)
                FV += h * load * thl
            Fr = Iz * (r - r0) + h * (sum_yfx + muy * lz * th)
            A11 = m - h * eVV - a11c
            if load:
                A11 += h * load * (1.0 - thl * thl) / _LOAD_EPS
            A12 = -h * eVr - a12c
            A21 = h * (eRV + muy * lzV * th) - a21c
            A22 = Iz + h * (eRr + muy * (lzr * th + lz * (1.0 - th * th) / eps)) - a22c
            b1 = FV - b1c
            b2 = Fr - b2c
            det = A11 * A22 - A12 * A21
            dV = (b1 * A22 - A12 * b2) / det
            dr = (A11 * b2 - A21 * b1) / det
            dw = [(Fw[i] - BV[i] * dV - Br[i] * dr) * inv[i] for i in range(4)]
            big = max(abs(dV), abs(dr), abs(dw[0]), abs(dw[1]), abs(dw[2]), abs(dw[3]))
            if big < tol:
                break  # accept x itself: the stored forces are exactly those of the accepted state
            x = [x[0] - dw[0], x[1] - dw[1], x[2] - dw[2], x[3] - dw[3], V - dV, r - dr]
            if not final and big < loose:
                break  # intermediate sub-step: one small Newton update (linearly implicit Euler) suffices
        else:
            self.newton_failures += 1
        self.newton_iters += it + 1
        self.substeps += 1
        w, V, r = x[:4], x[4], x[5]
        # wheel PI integrators, with anti-windup (hold while saturated and pushing further)
        for i in range(4):
            err = w_ref[i] - w[i]
            if abs(traw[i]) < tmax or (err > 0) != (traw[i] > 0):
                self.i_wheel[i] += h * err
        # energy book (backward Euler: powers at the new state, torques held over the step)
        e = self.energy
        vis = [V - r * yi for yi in ys]
        pm = ps = pr = 0.0
        for i in range(4):
            pm += tq[i] * w[i]
            ps += fz[i] * gs[i] * (R * w[i] - vis[i])
            pr += fz[i] * (gs[i] - mus[i]) * vis[i]
        e["motor_work"] += h * pm
        e["slip_dissipation"] += h * ps
        e["resistance_work"] += h * pr
        e["yaw_dissipation"] += h * muy * lz * th * r
        if load:
            self.drawbar_work += h * load * math.tanh(V / _LOAD_EPS) * V
        self.z += h * V * gx / STANDARD_GRAVITY
        # advance
        self.prev = x0
        self.acc = (V - V0) / h
        self.w, self.V, self.r = w, V, r
        self.torque = tq[:]
        self.slips, self.gross, self.mus = ss[:], gs[:], mus[:]
        self.f_used, self.fz = f, fz[:]
        self.wheel_angle = [a + h * wi for a, wi in zip(self.wheel_angle, w)]
        self.dist += h * V
        self.heading += h * r
        self.t = t_new

    # --- records -------------------------------------------------------------------------
    def _ocp(self, k: float):
        if k not in self._ocp_cache:
            self._ocp_cache[k] = ocp_from_soil_strength(k, self.c)
        return self._ocp_cache[k]

    def _records(self, seq: int) -> tuple[SensorSample, TruthRecord]:
        v = self.v
        stamp = seq / self.rate
        w = np.array(self.w)
        # the accepted Newton iterate's own slip and forces: exactly what the dynamics used
        # (eq. 1 as slip_ratio; eqs. 3/6 from the sampled table, within 2e-7 of soilocp.model.traction)
        s, g, mu = np.array(self.slips), np.array(self.gross), np.array(self.mus)
        seg = self.sc.segments[self.seg]
        ocp = self._ocp(seg.soil_strength)
        ke = 0.5 * (v.mass * self.V**2 + v.yaw_inertia * self.r**2 + v.wheel_inertia * float(w @ w))
        tup = lambda a: tuple(float(q) for q in a)  # noqa: E731
        truth = TruthRecord(
            vehicle_id=self.vehicle_id,
            seq=seq,
            stamp=stamp,
            mode=self.mode,
            segment=self.seg,
            soil_class=seg.soil_class,
            soil_strength=seg.soil_strength,
            wheel_soil_strength=tup(self.k_wheels),
            grade=seg.grade,
            cross_slope=seg.cross_slope,
            roll=self.roll,
            pitch=self.pitch,
            distance=self.dist,
            heading=self.heading,
            yaw_rate=self.r,
            slip=tup(s),
            mu=tup(mu),
            motion_resistance=tup(g - mu),
            gross_traction=tup(g),
            normal_force=tup(self.fz),
            ground_speed=self.V,
            wheel_speed=tup(self.w),
            wheel_torque=tup(self.torque),
            specific_force=tup(self.f_used),
            speed_command=self.speed_cmd,
            slip_command=self.slip_cmd,
            mu_T=ocp.mu_T,
            S_T=ocp.S_T,
            S_E=ocp.S_E,
            kinetic_energy=ke,
            potential_energy=v.mass * STANDARD_GRAVITY * self.z,
            **self.energy,
        )
        read = self.sensors.read(
            specific_force=self.f_used,
            roll=self.roll,
            pitch=self.pitch,
            yaw_rate=self.r,
            wheel_angle=self.wheel_angle,
            wheel_speed=self.w,
            wheel_torque=self.torque,
            ground_speed=self.V,
        )
        if v.drive == "per_side":
            read = _side_readings(read)
        sample = SensorSample(vehicle_id=self.vehicle_id, seq=seq, stamp=stamp, **read)
        return sample, truth

    def samples(self) -> Iterator[tuple[SensorSample, TruthRecord]]:
        n = itertools.count() if math.isinf(self.duration) else range(max(1, int(round(self.duration * self.rate))))
        for seq in n:
            if seq:
                for k in range(self.n_sub):
                    self._substep(final=k == self.n_sub - 1)
                if not (all(map(math.isfinite, (*self.w, self.V, self.r))) and max(map(abs, self.f_used)) < 100.0):
                    raise RuntimeError(
                        f"simulation diverged at t={self.t:.4f} s: wheel speeds {self.w}, V {self.V}, yaw rate "
                        f"{self.r}, specific force {self.f_used} (controller gains or vehicle out of range?)"
                    )
            records = self._records(seq)
            yield records
            if self.torque_command is not None:
                cmd = [float(q) for q in self.torque_command(records[0])]
                if len(cmd) != 4 or not all(map(math.isfinite, cmd)):
                    raise ValueError(f"wheel_torque_command must return 4 finite torques (N m), got {cmd!r}")
                tmax = self.ctl.torque_limit
                self.held_torque = [min(max(q, -tmax), tmax) for q in cmd]
            if self.drawbar_load is not None:
                f = float(self.drawbar_load(self.t, self.V))
                if not (math.isfinite(f) and f >= 0):
                    raise ValueError(f"drawbar_load must return a finite draft force >= 0 N, got {f!r}")
                self.load = f
