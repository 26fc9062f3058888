"""What ``soilocp run`` watches of its vehicle, from a client session of its own: OCPs,
rejections, status and liveliness, summarised in :meth:`Monitor.snapshot`."""

from __future__ import annotations

import threading
import time
from collections import Counter as Tally
from collections import deque
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.services.runtime.process import undeclare_all
from soilocp.schemas.messages import Rejection, ServiceHealth, SlipSetpoint
from soilocp.schemas.pipeline import OcpEstimate


class Monitor:
    """What the run shows, fed by Zenoh callbacks (cheap: store and count only)."""

    def __init__(self, vehicle_id: str, stale_timeout: float):
        self.vid = vehicle_id
        self.stale_timeout = stale_timeout
        self.lock = threading.Lock()
        self.latest: Optional[OcpEstimate] = None
        self.latest_wall: Optional[float] = None
        self.ocp_count = 0
        self.arrivals: deque[float] = deque(maxlen=5000)
        self.rejections = 0
        self.rejection_codes: Tally = Tally()
        self.health: dict[str, ServiceHealth] = {}
        self.alive: set[str] = set()
        self.stale_reports = 0
        self.setpoint: Optional[SlipSetpoint] = None
        #: OCP records received per (status, reason code)
        self.reasons: dict[tuple[str, str], int] = {}
        self._decls: list[Any] = []

    def attach(self, session) -> None:
        import zenoh

        vid = self.vid

        def parsed(model, apply):
            """A callback that parses the payload with ``model`` and applies it under the lock
            (an unparsable payload is the gateway's and the services' business, not the view's)."""

            def on_sample(sample) -> None:
                try:
                    msg = model.model_validate_json(sample.payload.to_bytes())
                except ValueError:
                    return
                with self.lock:
                    apply(msg)

            return on_sample

        def ocp(est: OcpEstimate) -> None:
            now = time.time()
            self.latest, self.latest_wall = est, now
            self.ocp_count += 1
            self.arrivals.append(now)
            why = (est.status, est.reason_code)
            self.reasons[why] = self.reasons.get(why, 0) + 1

        def on_rejected(sample) -> None:
            try:
                rej = Rejection.model_validate_json(sample.payload.to_bytes())
                code, unpublished = rej.code, rej.suppressed
            except ValueError:
                code, unpublished = "?", 0
            with self.lock:
                self.rejections += 1 + unpublished
                self.rejection_codes[code] += 1
                if unpublished:  # their codes are in the gateway's health (rejected_<code>)
                    self.rejection_codes["unpublished"] += unpublished

        def status(h: ServiceHealth) -> None:
            self.health[h.service] = h
            if h.service == "ocp" and h.stale:
                self.stale_reports += 1

        def setpoint(sp: SlipSetpoint) -> None:
            self.setpoint = sp

        def on_alive(sample) -> None:
            try:
                _vid, service = keys.service_of_alive_key(str(sample.key_expr))
            except ValueError:
                return
            with self.lock:
                if sample.kind == zenoh.SampleKind.PUT:
                    self.alive.add(service)
                else:
                    self.alive.discard(service)

        self._decls = [
            session.declare_subscriber(keys.ocp(vid), parsed(OcpEstimate, ocp)),
            session.declare_subscriber(keys.rejected(vid), on_rejected),
            session.declare_subscriber(keys.vehicle_status_all(vid), parsed(ServiceHealth, status)),
            session.declare_subscriber(keys.control_slip(vid), parsed(SlipSetpoint, setpoint)),
            session.liveliness().declare_subscriber(keys.vehicle_alive_all(vid), on_alive, history=True),
        ]

    def _rejection_codes(self) -> dict[str, int]:
        """Rejections by code: the gateway health's counters, which hold every one, where they are at least
        as new as the published rejections (a flood's are sampled, see ``Rejection.suppressed``)."""
        gw = self.health.get("gateway")
        exact = {k[len("rejected_"):]: n for k, n in (gw.detail if gw else {}).items()
                 if k.startswith("rejected_") and n}
        if exact and sum(exact.values()) >= self.rejections:
            return exact
        return dict(self.rejection_codes)

    def detach(self) -> None:
        undeclare_all(self._decls)

    def snapshot(self) -> dict[str, Any]:
        now = time.time()
        with self.lock:
            recent = [t for t in self.arrivals if now - t <= 2.0]
            rate = len(recent) / 2.0 if recent else 0.0
            est = self.latest
            age = None if self.latest_wall is None else now - self.latest_wall
            ocp_h = self.health.get("ocp")
            return dict(
                est=est,
                age=age,
                stale=age is None or age > self.stale_timeout,
                rate=rate,
                count=self.ocp_count,
                rejections=self.rejections,
                codes=self._rejection_codes(),
                alive=set(self.alive),
                health=dict(self.health),
                ocp_stale_reported=bool(ocp_h and ocp_h.stale),
                setpoint=self.setpoint,
                reasons=dict(self.reasons),
            )
