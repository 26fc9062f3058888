"""The simulated rover's controllers: wheel-speed references from the outer speed, heading and
slip-sweep loops (the excitation that makes K identifiable: the front axle sweeps driving slip,
the rear holds the speed by braking; scenarios.SweepParams says why not the other way round).
The wheel-speed PI loops themselves are stepped with the dynamics (dynamics.RoverDrive._substep)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from soilocp.model.vehicle import VehicleParams
from soilocp.sim.scenarios import Scenario


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
    #: Travel backwards at the scenario's speed (speed set-point -speed).  In a traction test the
    #: LEADING axle (the rear) sweeps driving slip and the trailing one (the front) brakes to hold
    #: the speed: accelerating backwards moves load onto the front, off the sweeping axle, which
    #: keeps the load-transfer loop a negative feedback as in forward travel (SweepParams).
    reverse: bool = False
    #: Constant yaw-rate set-point (rad/s, > 0 turning left), ramped in with the speed: arcs, or a
    #: turn on the spot with ``turn_in_place``.  Adds to the S-turn set-point.
    turn_rate: float = 0.0
    #: Speed set-point 0: the robot turns on the spot at ``turn_rate`` (a skid turn; cruise mode).
    turn_in_place: bool = False
    #: Accelerate and brake: speed set-point speed x (1 + speed_swing sin(2 pi t / speed_swing_period)),
    #: so that the longitudinal force balance (docs/method.md §15) sees the mass and torque scale.  In a
    #: traction test the swing alternates with the sweep: one swing period of driving (every wheel holds
    #: the speed, no sweep), then ``swing_sweep_time`` s of the traction test at the constant speed.
    speed_swing: float = 0.0
    speed_swing_period: float = 4.0
    swing_sweep_time: float = 4.0

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"controller {name} must be finite and >= 0, got {v!r}")
        if self.governor_tau <= 0 or self.torque_limit <= 0 or self.speed_swing_period <= 0:
            raise ValueError(f"controller torque_limit, governor_tau and speed_swing_period must be > 0, got "
                             f"{self.torque_limit!r}, {self.governor_tau!r}, {self.speed_swing_period!r}")
        if self.speed_swing >= 1:
            raise ValueError(f"controller speed_swing must be < 1 (the set-point keeps its sign), got {self.speed_swing!r}")

    @property
    def direction(self) -> float:
        """+1 forward, -1 backwards: the sign of the speed set-point."""
        return -1.0 if self.reverse else 1.0


def smoothstep(x: float) -> float:
    """0 -> 1 smoothly over x in [0, 1] (zero slope at both ends): the start ramp of speed and sweep."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def side_references(ref: list[float]) -> list[float]:
    """Skid steer (vehicle drive per_side): one motor per side turns both of its wheels (chained),
    so both follow one speed reference, the mean of what the side's two wheels would get; in
    excitation mode the front sweep and the rear's speed hold then act on the whole side.  The two
    wheels keep their own stiff speed loops: a chain is rigid, the loops nearly so."""
    left, right = 0.5 * (ref[0] + ref[1]), 0.5 * (ref[2] + ref[3])
    return [left, left, right, right]


DEFAULT_CONTROLLER = ControllerParams()


class SweepController:
    """The outer loops of one drive, with their own state (integrators, the governor's mean speed,
    the last speed and slip commands, which the truth records)."""

    def __init__(self, sc: Scenario, vehicle: VehicleParams, ctl: ControllerParams, mode: str, h: float):
        self.sc, self.v, self.ctl, self.mode, self.h = sc, vehicle, ctl, mode, h
        self.ys = [float(q) for q in vehicle.wheel_y]
        self.front = [xq > 0 for xq in vehicle.wheel_x]
        # the axle that sweeps in a traction test: the leading one (the front, or the rear in reverse)
        self.sweeping = [f != ctl.reverse for f in self.front]
        self.i_speed = 0.0
        self.i_yaw = 0.0
        self.v_mean = 0.0  # low-passed speed for the sweep governor
        self.slip_cmd: float | None = None
        self.speed_cmd = 0.0
        #: an external command (speed set-point m/s, leading axle's slip set-point or None), set by the
        #: simulator's ``drive_command`` hook: it replaces the scenario's speed, ramp, swing and sweep
        self.command: tuple[float, float | None] | None = None

    def references(self, t: float, V: float, r: float) -> list[float]:
        """Wheel-speed references (rad/s, wheels 1..4) for the sub-step ending at t, from the body
        speed V (m/s) and yaw rate r (rad/s) at its start (explicit in the step)."""
        ctl, R, h, sc = self.ctl, self.v.wheel_radius, self.h, self.sc
        ramp = smoothstep(t / ctl.ramp_time) if ctl.ramp_time > 0 else 1.0
        v_ref = sc.speed * ramp
        swinging = False
        external = self.command
        if external is not None:  # the command's own profile: no ramp, no swing, its slip or none
            v_ref, ramp, swinging = external[0], 1.0, external[1] is None
        elif ctl.speed_swing > 0:
            cycle = ctl.speed_swing_period + (ctl.swing_sweep_time if self.mode == "excitation" else 0.0)
            phase = t % cycle
            if phase < ctl.speed_swing_period:
                swinging = True
                v_ref *= 1.0 + ctl.speed_swing * math.sin(2.0 * math.pi * phase / ctl.speed_swing_period)
        if ctl.turn_in_place:
            v_ref = 0.0
        if ctl.reverse:
            v_ref = -v_ref
        self.speed_cmd = v_ref
        # heading hold: a yaw-rate PI commands a small differential (V_i = V - r_c y_i)
        if ctl.s_turn_rate > 0 or ctl.turn_rate > 0:  # around a yaw-rate set-point (S-turns, arcs, on the spot)
            r_ref = ctl.turn_rate * ramp
            if ctl.s_turn_rate > 0:
                r_ref += ctl.s_turn_rate * ramp * math.sin(2.0 * math.pi * t / ctl.s_turn_period)
            self.i_yaw += h * (r - r_ref)
            r_c = r_ref - (ctl.yaw_kp * (r - r_ref) + ctl.yaw_ki * self.i_yaw)
        else:
            self.i_yaw += h * r
            r_c = -(ctl.yaw_kp * r + ctl.yaw_ki * self.i_yaw)
        # the wheels' rim speeds keep the set-point's sign (no reversal within a drive), except on the spot
        if ctl.turn_in_place:
            clamp = lambda q: q  # noqa: E731
        elif ctl.reverse:
            clamp = lambda q: min(q, 0.0)  # noqa: E731
        else:
            clamp = lambda q: max(q, 0.0)  # noqa: E731
        if self.mode == "cruise":
            self.slip_cmd = None
            return [clamp(v_ref - r_c * yi) / R for yi in self.ys]
        # excitation: the leading axle sweeps driving slip, the trailing one holds the speed by braking
        if swinging:
            s_cmd = 0.0
        else:
            s_cmd = external[1] if external is not None else sc.sweep.slip_at(t) * ramp
        # the governor acts on the cycle-mean speed, not on the excursions within one sweep
        self.v_mean += h / ctl.governor_tau * (V - self.v_mean)
        v_gov = max(abs(v_ref), 0.1) if external is not None else sc.speed
        over = (ctl.direction * self.v_mean - v_gov) / v_gov - ctl.governor_deadband
        if over > 0:
            s_cmd *= max(0.0, 1.0 - ctl.governor_gain * over)
        self.slip_cmd = s_cmd
        err = v_ref - V
        # trailing axle: speed PI.  Its integrator keeps integrating while the braking slip is clamped, so
        # that the dwell makes up for the overspeed near the sweep's peak (mean speed = V_ref).
        self.i_speed = min(max(self.i_speed + h * err, -ctl.speed_i_limit), ctl.speed_i_limit)
        if ctl.rear_mirror > 0:  # braking slip -m S means omega R = V (1 - m S); the PI trims the slip
            trim = ctl.mirror_trim * (ctl.speed_kp * err + ctl.speed_ki * self.i_speed)
            v_hold = max(V, v_ref) * (1.0 - ctl.rear_mirror * s_cmd + trim)  # v_ref: start from rest
        else:
            v_hold = v_ref + ctl.speed_kp * err + ctl.speed_ki * self.i_speed
        # the braking axle stays on the stable side of the traction peak: driving slip >= -brake_slip_limit
        # (eq. 1 for the direction of travel: |omega R| >= |V| (1 - limit))
        if ctl.reverse:
            v_hold = min(v_hold, V * (1.0 - ctl.brake_slip_limit))
        else:
            v_hold = max(v_hold, V * (1.0 - ctl.brake_slip_limit))
        out = []
        for sweeping, yi in zip(self.sweeping, self.ys):
            if sweeping and not swinging:
                out.append(clamp(V - r_c * yi) / (R * (1.0 - s_cmd)))
            else:
                out.append(clamp(v_hold - r_c * yi) / R)
        return side_references(out) if self.v.drive == "per_side" else out
