"""Per-wheel torque loops: wheel-speed tracking and slip limiting, with saturation and anti-windup.

Each wheel has two PI channels that both produce a motor torque:

* **speed**: tracks the rim speed ``omega R_w`` to the commanded vehicle speed (the simulator's
  cruise mode, here at the sensor rate with the torque held over each interval);
* **slip**: tracks the slip set-point ``S*`` with eq. 1's slip measured from the same sample
  (:func:`soilocp.model.slip.slip_ratio_unchecked`, ground speed at the wheel V - psi_dot y_i).

The applied torque is ``min(speed, slip)`` (a limiter: the slip loop only takes over when the
speed loop would drive the wheel past ``S*``), saturated at +-``torque_limit``.  Both
integrators use back-calculation anti-windup (Astrom & Hagglund): each integrator is also driven
by ``(T_applied - T_own) / tracking_time``, so the channel that is not in control, or a
saturated one, follows the applied torque instead of winding up, and the switch between them is
bumpless.  Without ``S*`` (the ``speed`` baseline) the speed channel alone drives the wheel.

Gains (:class:`LoopGains`) are in units of the static wheel-load torque ``T0 = R_w m g / 4``
(22 N m for the default rover), so they carry over to another vehicle.  Why these values: with
the torque held over one 10 ms interval the wheel settles within it (slip time constant
~3 ms), so the plant is static, ``dS/dT = 1 / (R_w Fz dg/dS)``.  A one-step loop is stable while
``kp dS/dT`` < 1: ``dg/dS`` (eq. 3) falls to ~0.25 at high slip on firm soil, hence slip_kp = 0.1 T0
per unit slip (loop gain <= 0.4).  slip_ki = 2 T0/s gives a slip time constant of 0.1-0.3 s over
sand..firm.  speed_kp = 0.2 T0 per m/s of rim-speed error gives a vehicle-speed time constant of
~0.5 s (the 4 wheels' force on the 60 kg body); speed_ki = 1 T0/m removes the steady error
against motion resistance and draft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.model.slip import DEFAULT_FLOOR, slip_ratio_unchecked
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams


@dataclass(frozen=True)
class LoopGains:
    """PI gains of the per-wheel loops, in units of T0 = R_w m g / 4 (see the module docstring)."""

    speed_kp: float = 0.2  #: T0 per m/s of rim-speed error
    speed_ki: float = 1.0  #: T0 per m of integrated rim-speed error
    slip_kp: float = 0.1  #: T0 per unit slip error
    slip_ki: float = 2.0  #: T0 per unit slip error per second
    tracking_time: float = 0.1  #: s, back-calculation time constant of both integrators
    torque_limit: float = 40.0  #: N m, |T| max per wheel (the simulator's motor limit)

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"loop gain {name} must be a finite number >= 0, got {v!r}")
        if self.tracking_time <= 0 or self.torque_limit <= 0:
            raise ValueError(f"tracking_time and torque_limit must be > 0, got {self.tracking_time!r}, "
                             f"{self.torque_limit!r}")


DEFAULT_GAINS = LoopGains()


@dataclass(frozen=True)
class LoopOutput:
    torque: tuple[float, float, float, float]  #: applied (saturated) torque per wheel, N m
    slip: tuple[float, float, float, float]  #: measured slip per wheel (eq. 1)
    limiting: tuple[bool, bool, bool, bool]  #: True where the slip channel sets the torque
    saturated: tuple[bool, bool, bool, bool]  #: True where |T| hit the torque limit


class WheelTorqueLoop:
    """The four wheels' speed and slip PI channels; :meth:`step` once per sensor sample."""

    def __init__(self, vehicle: VehicleParams = DEFAULT_VEHICLE, gains: LoopGains = DEFAULT_GAINS,
                 slip_floor: float = DEFAULT_FLOOR):
        self.vehicle, self.gains, self.slip_floor = vehicle, gains, slip_floor
        t0 = vehicle.wheel_radius * vehicle.mass * STANDARD_GRAVITY / 4.0
        self.t0 = t0
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        self.i_speed = np.zeros(4)  # integrator states, N m
        self.i_slip = np.zeros(4)
        self._last_stamp: Optional[float] = None

    def reset(self) -> None:
        self.i_speed[:] = 0.0
        self.i_slip[:] = 0.0
        self._last_stamp = None

    def step(self, stamp: float, wheel_speed: Sequence[float], ground_speed: float, yaw_rate: float,
             speed_command: float, slip_setpoint: Optional[float]) -> LoopOutput:
        """Torques for the next interval from one sample.  ``slip_setpoint`` None: speed only."""
        g, R = self.gains, self.vehicle.wheel_radius
        if not all(map(math.isfinite, (stamp, ground_speed, yaw_rate, speed_command, *wheel_speed))):
            raise ValueError(f"loop inputs must be finite: stamp {stamp!r}, wheel_speed {list(wheel_speed)!r}, "
                             f"ground_speed {ground_speed!r}, yaw_rate {yaw_rate!r}, speed_command {speed_command!r}")
        if slip_setpoint is not None and not (math.isfinite(slip_setpoint) and -1.0 < slip_setpoint < 1.0):
            raise ValueError(f"slip_setpoint must be in (-1, 1), got {slip_setpoint!r}")
        # a repeated or backwards stamp (source restart) integrates nothing
        dt = 0.0 if self._last_stamp is None else stamp - self._last_stamp
        dt = dt if 0.0 < dt <= 1.0 else 0.0
        self._last_stamp = stamp
        w = np.asarray(wheel_speed, dtype=float)
        v_wheel = ground_speed - yaw_rate * self._wheel_y
        s = slip_ratio_unchecked(w, v_wheel, R, 0.0, self.slip_floor).slip
        e_speed = speed_command - w * R
        u_speed = self.t0 * g.speed_kp * e_speed + self.i_speed
        if slip_setpoint is None:
            u = u_speed
            u_slip = None
        else:
            e_slip = slip_setpoint - s
            u_slip = self.t0 * g.slip_kp * e_slip + self.i_slip
            u = np.minimum(u_speed, u_slip)
        tmax = g.torque_limit
        applied = np.clip(u, -tmax, tmax)
        back = 1.0 / g.tracking_time
        self.i_speed += dt * (self.t0 * g.speed_ki * e_speed + back * (applied - u_speed))
        if u_slip is not None:
            self.i_slip += dt * (self.t0 * g.slip_ki * e_slip + back * (applied - u_slip))
            limiting = u_slip < u_speed
        else:
            self.i_slip[:] = applied  # ready to take over bumplessly when a set-point appears
            limiting = np.zeros(4, dtype=bool)
        quad = lambda a: tuple(float(q) for q in a)  # noqa: E731
        return LoopOutput(torque=quad(applied), slip=quad(s), limiting=tuple(bool(q) for q in limiting),
                          saturated=tuple(bool(abs(q) >= tmax) for q in u))
