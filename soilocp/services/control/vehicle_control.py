"""The synthetic vehicle under closed-loop control: it follows the controller service's set-points.

``soilocp service vehicle --scenario NAME --control CONTROLLER``: the simulator runs in real time
with its wheel torques from the library's torque loops (:class:`soilocp.control.WheelTorqueLoop`),
which track the latest :class:`soilocp.schemas.messages.SlipSetpoint` heard on
``soilocp/<vid>/control/slip``.  So the loop closes through the router: sample -> pipeline ->
OCP -> controller -> set-point -> vehicle.  NAME is a simulator scenario or a closed-loop rig
scenario of :mod:`soilocp.control.rig` (e.g. ``drawbar-sand``, with its towed load).

If no set-point arrives for longer than the stale timeout, the vehicle applies the controller's
safe fallback itself (a dead controller must not leave an old set-point in force).

Loop latency: the vehicle remembers when it published each sample; a set-point carrying that
sample's stamp closes the loop, and ``now - published`` is the control-loop latency
(sample -> set-point back at the vehicle), kept for the health report and the bench.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from typing import Iterator, Optional

import numpy as np

from soilocp.schemas.messages import SlipSetpoint
from soilocp.control import OcpSetPoint, SetPoint, WheelTorqueLoop, make_policy
from soilocp.services.control.setpoints import LatestSetpoint

SENT_MEMORY = 4096  # samples whose publish time is remembered for the latency


class SetpointInbox(LatestSetpoint):
    """Latest slip set-point (:class:`LatestSetpoint`) and the loop latencies."""

    message = SlipSetpoint

    def __init__(self, vehicle_id: str, control: str, stale_timeout_s: float):
        policy = make_policy(control, stale_timeout_s=stale_timeout_s)  # ValueError: bad name
        super().__init__(vehicle_id)
        self.control, self.stale_timeout_s = control, float(stale_timeout_s)
        self.fallback: Optional[float] = policy.fallback if isinstance(policy, OcpSetPoint) else None
        self._policy = policy
        self._sent: OrderedDict[float, float] = OrderedDict()  # sample stamp -> publish time
        self.latencies_ms: list[float] = []

    def sent(self, stamp: float, wall: float) -> None:
        with self._lock:
            self._sent[stamp] = wall
            while len(self._sent) > SENT_MEMORY:
                self._sent.popitem(last=False)

    def taken(self, sp: SlipSetpoint, wall: float) -> None:
        if sp.stamp is not None and sp.stamp in self._sent:
            self.latencies_ms.append((wall - self._sent.pop(sp.stamp)) * 1e3)
            if len(self.latencies_ms) > 100_000:
                del self.latencies_ms[:50_000]

    def current(self, now: Optional[float] = None) -> SetPoint:
        """The set-point in force: the latest received, or the fallback if it is too old / none."""
        now = self.clock() if now is None else now
        sp, wall = self.latest()
        if sp is None or wall is None or now - wall > self.stale_timeout_s:
            if self.fallback is not None:
                why = "no set-point yet" if sp is None else f"no set-point for {now - wall:.3f} s"
                return SetPoint(self.fallback, "fallback", why)
            return self._policy(0.0, None)  # speed / fixed: known locally
        value = None if sp.slip is None else float(np.mean(sp.slip))
        return SetPoint(value, sp.source, sp.reason, sp.soil_strength)

    def latency_summary(self) -> dict[str, float | int | None]:
        with self._lock:
            lat = sorted(self.latencies_ms)
        if not lat:
            return {"loop_latency_n": 0, "loop_latency_p50_ms": None, "loop_latency_p99_ms": None}
        q = lambda p: lat[min(len(lat) - 1, int(math.ceil(p * len(lat))) - 1)]  # noqa: E731
        return {"loop_latency_n": len(lat), "loop_latency_p50_ms": q(0.5), "loop_latency_p99_ms": q(0.99)}


def controlled_source(scenario: str, vehicle_id: str, inbox: SetpointInbox, *, duration: Optional[float],
                      rate: float, seed: int) -> Iterator[tuple[bytes, Optional[float]]]:
    """Samples of ``scenario`` driven by the torque loops under ``inbox``'s set-points.

    Not a generator itself: a bad scenario name raises ValueError here, at startup."""
    from soilocp.control.rig import RAMP_TIME, RIG_SCENARIOS
    from soilocp.sim.scenarios import get_scenario
    from soilocp.sim.controller import smoothstep
    from soilocp.sim.simulator import simulate

    rig = RIG_SCENARIOS.get(scenario)
    sc = rig.scenario if rig is not None else get_scenario(scenario)
    draft = rig.draft if rig is not None else None
    loop = WheelTorqueLoop()
    state = {"setpoint": None}

    def torque(sample):
        sp = inbox.current()
        state["setpoint"] = sp
        cmd = sc.speed * smoothstep(sample.stamp / RAMP_TIME)
        return loop.step(sample.stamp, sample.wheel_speed, sample.ground_speed, sample.yaw_rate, cmd, sp.value).torque

    samples = simulate(sc, duration=duration, rate=rate, seed=seed, vehicle_id=vehicle_id, mode="cruise",
                       wheel_torque_command=torque, drawbar_load=draft)
    return ((s.model_dump_json().encode(), s.stamp) for s, _truth in samples)
