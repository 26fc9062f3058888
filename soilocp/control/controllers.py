"""The five wheel-slip controllers compared by ``soilocp control compare``.

======================  ==========================================================================
``speed``               baseline: wheel-speed tracking only, no slip control (simulator cruise mode)
``fixed_0.15``          slip limited to 0.15 (the agricultural rule of thumb)
``fixed_0.20``          slip limited to 0.20 (an ABS-like limit)
``ocp_traction``        slip limited to S_T (eq. 7 corrected) of the live K estimate; safe fallback
``ocp_efficiency``      slip limited to S_E (eq. 10) of the live K estimate; safe fallback
======================  ==========================================================================

A controller is a set-point policy (:mod:`.setpoints`) feeding the per-wheel torque loops
(:mod:`.loop`).  :meth:`SlipController.step` takes one sensor sample and the latest OCP estimate
and returns the four torques for the next interval; it never looks at the simulator's truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from soilocp.schemas.pipeline import OcpEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams
from soilocp.control.loop import DEFAULT_GAINS, LoopGains, LoopOutput, WheelTorqueLoop
from soilocp.control.setpoints import FixedSetPoint, OcpSetPoint, SetPoint

CONTROLLER_NAMES: tuple[str, ...] = ("speed", "fixed_0.15", "fixed_0.20", "ocp_traction", "ocp_efficiency")


@dataclass(frozen=True)
class ControlStep:
    setpoint: SetPoint
    loop: LoopOutput


class _NoSetPoint:
    def __call__(self, stamp: float, estimate: Optional[OcpEstimate]) -> SetPoint:
        return SetPoint(None, "none")


class SlipController:
    """A set-point policy and the wheel torque loops, stepped once per sensor sample."""

    def __init__(self, name: str, policy: Callable[[float, Optional[OcpEstimate]], SetPoint],
                 vehicle: VehicleParams = DEFAULT_VEHICLE, gains: LoopGains = DEFAULT_GAINS):
        self.name = name
        self.policy = policy
        self.loop = WheelTorqueLoop(vehicle, gains)

    def setpoint(self, stamp: float, estimate: Optional[OcpEstimate]) -> SetPoint:
        return self.policy(stamp, estimate)

    def step(self, sample: SensorSample, estimate: Optional[OcpEstimate], speed_command: float,
             setpoint: Optional[SetPoint] = None) -> ControlStep:
        """Torques for the interval after ``sample``.  ``setpoint`` overrides the policy (the live
        vehicle, which receives its set-points from the controller service)."""
        sp = setpoint if setpoint is not None else self.policy(sample.stamp, estimate)
        out = self.loop.step(sample.stamp, sample.wheel_speed, sample.ground_speed, sample.yaw_rate,
                             speed_command, sp.value)
        return ControlStep(sp, out)


def make_policy(name: str, *, stale_timeout_s: float = 0.5, constants: ModelConstants = DEFAULT_CONSTANTS):
    """The set-point policy of controller ``name`` (ValueError lists the names)."""
    if name == "speed":
        return _NoSetPoint()
    if name.startswith("fixed_"):
        try:
            value = float(name.removeprefix("fixed_"))
        except ValueError:
            value = None
        if value is not None:
            return FixedSetPoint(value)
    if name == "ocp_traction":
        return OcpSetPoint("S_T", stale_timeout_s=stale_timeout_s, constants=constants)
    if name == "ocp_efficiency":
        return OcpSetPoint("S_E", stale_timeout_s=stale_timeout_s, constants=constants)
    raise ValueError(f"controller must be one of {', '.join(CONTROLLER_NAMES)} (or fixed_<slip>), got {name!r}")


def make_controller(name: str, *, vehicle: VehicleParams = DEFAULT_VEHICLE, gains: LoopGains = DEFAULT_GAINS,
                    constants: ModelConstants = DEFAULT_CONSTANTS, stale_timeout_s: float = 0.5) -> SlipController:
    return SlipController(name, make_policy(name, stale_timeout_s=stale_timeout_s, constants=constants),
                          vehicle, gains)
