"""Closing the loop: wheel-slip controllers that act on the OCPs (pure library, no Zenoh).

:mod:`.loop` holds the per-wheel torque loops, :mod:`.setpoints` the fixed and OCP set-points
with their safe fallback, :mod:`.controllers` the five named controllers, :mod:`.rig` the
closed-loop test scenarios on the simulator and :mod:`.compare` the comparison.
"""

from soilocp.control.controllers import CONTROLLER_NAMES, ControlStep, SlipController, make_controller, make_policy
from soilocp.control.loop import DEFAULT_GAINS, LoopGains, LoopOutput, WheelTorqueLoop
from soilocp.control.setpoints import USABLE_STATUSES, FixedSetPoint, OcpSetPoint, SetPoint, fallback_slip

__all__ = [
    "CONTROLLER_NAMES", "ControlStep", "SlipController", "make_controller", "make_policy",
    "DEFAULT_GAINS", "LoopGains", "LoopOutput", "WheelTorqueLoop",
    "USABLE_STATUSES", "FixedSetPoint", "OcpSetPoint", "SetPoint", "fallback_slip",
]
