"""Controller service: OCPs in, wheel slip set-points out (``soilocp service controller --control NAME``).

Input ``soilocp/<vid>/ocp`` (OcpEstimate); output ``soilocp/<vid>/control/slip``
(:class:`schemas.messages.SlipSetpoint`).  The set-point policy is the library's
(:func:`soilocp.control.make_policy`): ``ocp_traction`` -> S_T, ``ocp_efficiency`` -> S_E of the
estimate, with the safe fallback of :mod:`soilocp.control.setpoints` while K is unknown.

Stale or missing OCPs: when no estimate arrived for longer than ``stale_timeout_s`` (or none
yet), the tick (every 50 ms) publishes the fallback set-point, and repeats it every half stale
timeout while the silence lasts, so the vehicle is on the safe set-point at most one tick after
the stale timeout.  The vehicle's torque loops track the set-points; this service never sends
torques (a set-point over the network, the fast loop on the vehicle).
"""

from __future__ import annotations

import time
from typing import Any, Optional

from schemas import keys
from schemas.messages import SlipSetpoint
from schemas.pipeline import OcpEstimate
from soilocp.control import OcpSetPoint, SetPoint, make_policy

from .runtime import Service


class ControllerService(Service):
    name = "controller"

    def __init__(self, cfg, log, *, control: str = "ocp_traction"):
        super().__init__(cfg, log)
        self.control = control
        self.policy = make_policy(control, stale_timeout_s=cfg.stale_timeout_s)  # ValueError: bad name
        self.fallback: Optional[float] = self.policy.fallback if isinstance(self.policy, OcpSetPoint) else None
        self.pubs: dict[str, Any] = {}
        self._last_ocp_wall: dict[str, Optional[float]] = {vid: None for vid in cfg.vehicle_ids}
        self._next_fallback: dict[str, float] = {vid: 0.0 for vid in cfg.vehicle_ids}
        self._stale: dict[str, bool] = {vid: True for vid in cfg.vehicle_ids}

    def declare(self, session, vehicle_id: str) -> None:
        self.pubs[vehicle_id] = self.publisher(session, keys.control_slip(vehicle_id))
        self.subscribe(session, keys.ocp(vehicle_id), vehicle_id, "ocp")

    def _publish(self, vid: str, sp: SetPoint, est: Optional[OcpEstimate], now: float) -> None:
        last = self._last_ocp_wall[vid]
        msg = SlipSetpoint(
            vehicle_id=vid, controller=self.control, slip=None if sp.value is None else (sp.value,) * 4,
            source=sp.source, reason=sp.reason, fallback=self.fallback,
            seq=est.seq if est is not None else None, stamp=est.stamp if est is not None else None,
            soil_strength=sp.soil_strength, ocp_age_s=None if last is None else max(0.0, now - last),
            stale_timeout_s=self.cfg.stale_timeout_s, issued_at=time.time())
        self.pubs[vid].put(msg.model_dump_json())
        c = self.counters[vid]
        c.published += 1
        c.bump(f"setpoint_{sp.source}")

    def handle(self, item) -> None:
        vid, _kind, payload, wall, _key = item
        c = self.counters[vid]
        c.last_input_wall = wall
        est = OcpEstimate.model_validate_json(payload)
        self._last_ocp_wall[vid] = wall
        if self._stale[vid]:
            self._stale[vid] = False
            self.log.info("ocp_fresh", vehicle_id=vid)
        sp = self.policy(est.stamp, est)
        self._publish(vid, sp, est, wall)
        c.last_seq, c.last_stamp = est.seq, est.stamp

    def tick(self, now: float) -> None:
        timeout = self.cfg.stale_timeout_s
        for vid in self.pubs:
            last = self._last_ocp_wall[vid]
            if last is not None and now - last <= timeout:
                continue
            if now < self._next_fallback[vid]:
                continue
            self._next_fallback[vid] = now + timeout / 2.0
            if self.fallback is not None:
                reason = "no OCP yet" if last is None else f"OCPs stale: none for {now - last:.3f} s (> {timeout} s)"
                sp = SetPoint(self.fallback, "fallback", reason)
            else:  # speed / fixed: the policy does not depend on the estimate
                sp = self.policy(0.0, None)
            if last is not None and not self._stale[vid]:
                self.log.warning("ocp_stale_fallback", vehicle_id=vid, age_s=now - last, fallback=sp.value)
            self._stale[vid] = True
            self._publish(vid, sp, None, now)

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        last = self._last_ocp_wall[vehicle_id]
        stale = last is None or time.time() - last > self.cfg.stale_timeout_s
        return {"stale": stale, "state": "stale" if stale else "running",
                "detail": {**self.counters[vehicle_id].detail, "control": self.control}}
