"""Simulated 4-wheel, differentially steered rover (paper Fig. 6) with ground truth.

This is the truth the whole project is measured against.  It uses the library's physics and
nothing else: the traction model of :mod:`soilocp.model.traction` (net traction mu, eq. 6; gross
traction g, eq. 3; motion resistance r = g - mu, eq. 4, odd in slip and bridged near S = 0,
docs/method.md §8), the zero-warp normal-force solver of :mod:`soilocp.model.normal_force` (eqs. 16-25
corrected, docs/method.md §2-3), slip eq. 1 with the standstill floor of :mod:`soilocp.model.slip`
(docs/method.md §6, §10) and the OCPs of :mod:`soilocp.model.ocp`.

Model (wheels 1 LR, 2 LF, 3 RF, 4 RR; body x forward, y left, z up, REP-103):

* slip of wheel i, eq. 1: S_i = (omega_i R_w - V_i) / max(|omega_i R_w|, |V_i|, floor), with the
  ground speed at the wheel V_i = V - psi_dot * y_i (differential steering); for a wheel whose drive
  travels backwards (``ControllerParams.reverse``, or one side of a turn on the spot) eq. 1 for that
  direction, -S_i, and the drive mirrored: the same body force, the resistance opposing backward
  travel (dynamics.RoverDrive._substep); the truth reports slip, mu, gross traction and resistance
  in the frame of travel;
* wheel i, eq. 13: I_w omega_i' = T_i - R_w (mu_i + r_i) Fz_i: the wheel sees gross traction;
* body, longitudinal: m V' = sum(mu_i Fz_i) - m g sin(grade) (net traction already contains
  the motion resistance; -g sin(grade) is the x component of gravity, eq. 20 with pitch = -grade);
* yaw, eqs. 11-12: I_z psi'' = d (Fx3 + Fx4) - c (Fx1 + Fx2) - M_zR with Fx_i = mu_i Fz_i and the
  skid-steer resistance moment M_zR = mu_y (a (Fz1 + Fz4) + b (Fz2 + Fz3)) tanh(psi'/eps), which
  opposes the yaw rate smoothly (eq. 12 with a regularised sign);
* normal forces from the TRUE specific force f = (V', V psi', 0) + g_R(roll, pitch) (eq. 20's
  gravity reaction plus the acceleration, docs/method.md §3) through the zero-warp solver, solved
  together with the dynamics in each step (see ``dynamics.RoverDrive._substep`` for why not lagged).

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

import math
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from soilocp.schemas.sensor import VEHICLE_ID_PATTERN, SensorSample

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.sim.scenarios import MODES, Scenario, SweepParams, get_scenario
from soilocp.sim.controller import DEFAULT_CONTROLLER, ControllerParams
from soilocp.sim.dynamics import RoverDrive
from soilocp.sim.field import StartPose
from soilocp.sim.sensor_models import SensorNoise
from soilocp.sim.truth import TruthRecord
from soilocp.model.slip import DEFAULT_FLOOR
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams

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


DEFAULT_SIM = SimParams()


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
    start: StartPose | None = None,
    drive_command: Callable[[SensorSample], tuple[float, float | None]] | None = None,
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
    * ``drive_command(sample)`` is called with each sensor sample and returns ``(speed, slip)``: the speed
      set-point (m/s) and the leading axle's driving slip set-point (None: every wheel holds the speed),
      held over the next interval.  They replace the scenario's speed, start ramp, swing and sweep; the
      rover's own loops follow them as in a traction test (excitation mode: the trailing axle brakes to hold
      the speed while the leading one sweeps).  A robot that follows a calibration drive's set-points
      (:mod:`soilocp.control.calibration_drive`).

    ``start`` (a :class:`soilocp.sim.field.StartPose`) puts the drive in a map frame: the samples
    then carry the true position and heading (and latitude/longitude with a ``geo_origin``); the
    truth's x, y are always integrated (from (0, 0), heading 0 without a start).
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
    run = RoverDrive(
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
        start=start,
        drive_command=drive_command,
    )
    return run.samples()
