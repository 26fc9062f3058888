"""Controller service: OCPs in, wheel slip set-points out (``soilocp service controller --control NAME``).

Input ``soilocp/<vid>/ocp`` (OcpEstimate); output ``soilocp/<vid>/control/slip``
(:class:`soilocp.schemas.messages.SlipSetpoint`).  The set-point policy is the library's
(:func:`soilocp.control.make_policy`): ``ocp_traction`` -> S_T, ``ocp_efficiency`` -> S_E of the
estimate, with the safe fallback of :mod:`soilocp.control.setpoints` while K is unknown.

Stale or missing OCPs: a watchdog thread looks every ``WATCH_PERIOD_S`` (10 ms); once the
last estimate is so old that it would pass ``stale_timeout_s`` before the next look (or there is
none yet), it publishes the fallback set-point and repeats it every half stale timeout while the
silence lasts.  So the fallback is out no later than ``stale_timeout_s`` after the last OCP
(the runner's 50 ms tick would be too coarse for that promise).

The vehicle's torque loops track the set-points; this service never sends torques (a set-point
over the network, the fast loop on the vehicle).
"""

from __future__ import annotations

import threading
import time
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import SlipSetpoint
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.control import OcpSetPoint, SetPoint, make_policy

from soilocp.services.runtime.service import Service

WATCH_PERIOD_S = 0.01


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
        self._watchdog: Optional[threading.Thread] = None

    def declare(self, session, vehicle_id: str) -> None:
        self.pubs[vehicle_id] = self.publisher(session, keys.control_slip(vehicle_id))
        self.subscribe(session, keys.ocp(vehicle_id), vehicle_id, "ocp")
        if self._watchdog is None:  # the runner sets stop_event before declaring
            self._watchdog = threading.Thread(target=self._watch, name="controller-watchdog", daemon=True)
            self._watchdog.start()

    def _watch(self) -> None:
        while not self.stop_event.wait(WATCH_PERIOD_S):
            try:
                self.check_stale(time.time())
            except Exception as exc:  # never let the watchdog die silently
                self.log.error("watchdog_error", error=f"{type(exc).__name__}: {exc}"[:300])

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
            self._next_fallback[vid] = 0.0  # the next silence gets its fallback at once
            self.log.info("ocp_fresh", vehicle_id=vid)
        sp = self.policy(est.stamp, est)
        self._publish(vid, sp, est, wall)
        c.last_seq, c.last_stamp = est.seq, est.stamp

    def check_stale(self, now: float) -> None:
        """Publish the fallback for every vehicle whose OCPs are (about to be) stale."""
        timeout = self.cfg.stale_timeout_s
        for vid in list(self.pubs):
            last = self._last_ocp_wall[vid]
            if last is not None and now - last + WATCH_PERIOD_S <= timeout:
                continue
            if now < self._next_fallback[vid]:
                continue
            self._next_fallback[vid] = now + timeout / 2.0
            if self.fallback is not None:
                reason = ("no OCP yet" if last is None else
                          f"OCPs stale: none for {now - last:.3f} s (stale_timeout_s {timeout} s)")
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
