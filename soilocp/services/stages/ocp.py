"""OCP publisher: soil estimate -> mu_T, S_T, S_E (``OcpStage``), published and queryable.

Input ``soilocp/<vid>/soil``; output: every OcpEstimate on ``soilocp/<vid>/ocp`` (the same record
``soilocp estimate`` writes), and a queryable on that key answering an :class:`OcpReply`: the
latest estimate, its age and freshness, plus ``?last=N`` or ``?since=STAMP`` from a bounded
history.  When no input arrives for longer than ``stale_timeout_s`` the output is stale: every
reply says so (``stale: true``, latest status ``stale``) and a ``stale`` ServiceHealth is
published on ``soilocp/<vid>/status/ocp`` until fresh data arrives.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any, Callable, Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import OcpReply
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.services.stages.graph import BY_NAME
from soilocp.model.parse import parse_finite
from soilocp.services.stages.stage_service import StageService


class OcpStore:
    """Latest estimate, bounded history and freshness of one vehicle (thread-safe)."""

    def __init__(self, vehicle_id: str, *, capacity: int, stale_timeout_s: float,
                 clock: Callable[[], float] = time.time):
        self.vehicle_id = vehicle_id
        self.capacity = int(capacity)
        self.stale_timeout_s = float(stale_timeout_s)
        self.clock = clock
        self._hist: deque[OcpEstimate] = deque(maxlen=self.capacity)
        self._last_wall: Optional[float] = None
        self._lock = threading.Lock()

    def add(self, est: OcpEstimate, wall: Optional[float] = None) -> None:
        with self._lock:
            self._hist.append(est)
            self._last_wall = self.clock() if wall is None else wall

    def age(self, now: Optional[float] = None) -> Optional[float]:
        if self._last_wall is None:
            return None
        return max(0.0, (self.clock() if now is None else now) - self._last_wall)

    def is_stale(self, now: Optional[float] = None) -> bool:
        age = self.age(now)
        return age is None or age > self.stale_timeout_s

    def reply(self, parameters: dict[str, str], now: Optional[float] = None) -> OcpReply:
        """The queryable's answer.  ValueError for a bad parameter (named, with its value)."""
        last_n: Optional[int] = None
        since: Optional[float] = None
        for name, value in parameters.items():
            if name == "last":
                try:
                    last_n = int(value)
                except ValueError:
                    raise ValueError(f"last={value!r}: must be an integer >= 1") from None
                if last_n < 1:
                    raise ValueError(f"last={value!r}: must be an integer >= 1")
            elif name == "since":
                since = parse_finite(value, "since (a sample stamp in seconds)")
            else:
                raise ValueError(f"unknown parameter {name!r}: use last=N or since=STAMP")
        now = self.clock() if now is None else now
        with self._lock:
            hist = list(self._hist)
            age = self.age(now)
        stale = age is None or age > self.stale_timeout_s
        latest = hist[-1] if hist else None
        if latest is not None and stale:
            latest = latest.model_copy(update={
                "status": "stale", "reason_code": "stale", "confirmed": False,
                "reason": f"no input for {age:.3f} s (> stale_timeout_s {self.stale_timeout_s} s); last status "
                          f"{hist[-1].status}",
            })
        history = None
        if since is not None:
            history = [e for e in hist if e.stamp >= since]
        if last_n is not None:
            history = (history if history is not None else hist)[-last_n:]
        return OcpReply(vehicle_id=self.vehicle_id, stale=stale, age_s=age, stale_timeout_s=self.stale_timeout_s,
                        latest=latest, history=history, history_capacity=self.capacity)


def parse_parameters(text: str) -> dict[str, str]:
    """``"last=5;since=2.5"`` (Zenoh selector parameters, ``;``- or ``&``-separated) -> dict."""
    out: dict[str, str] = {}
    for part in text.replace("&", ";").split(";"):
        if not part:
            continue
        name, _, value = part.partition("=")
        out[name.strip()] = value.strip()
    return out


class OcpService(StageService):
    """The OCP row: every estimate also goes to a bounded store that a queryable answers from."""

    spec = BY_NAME["ocp"]

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        self.stores = {vid: OcpStore(vid, capacity=cfg.history_size, stale_timeout_s=cfg.stale_timeout_s)
                       for vid in cfg.vehicle_ids}
        self.status_pubs: dict[str, Any] = {}
        self._stale: dict[str, bool] = {vid: True for vid in cfg.vehicle_ids}
        self._next_stale_report: dict[str, float] = {vid: 0.0 for vid in cfg.vehicle_ids}

    def declare(self, session, vehicle_id: str) -> None:
        import zenoh

        super().declare(session, vehicle_id)
        key = self.spec.output(vehicle_id)
        self.status_pubs[vehicle_id] = self.keep(
            session.declare_publisher(keys.status(vehicle_id, self.name), congestion_control=zenoh.CongestionControl.DROP))
        store = self.stores[vehicle_id]
        log = self.log

        def _query(query) -> None:
            try:
                params = parse_parameters(str(query.parameters))
                try:
                    rep = store.reply(params)
                except ValueError as exc:
                    query.reply_err(str(exc))
                    return
                query.reply(key, rep.model_dump_json())
            except Exception as exc:  # never let a query disturb the session
                log.warning("query_failed", vehicle_id=vehicle_id, error=str(exc)[:300])

        self.keep(session.declare_queryable(key, _query))

    def emit(self, vehicle_id: str, out: OcpEstimate) -> None:
        self.stores[vehicle_id].add(out)
        super().emit(vehicle_id, out)

    def tick(self, now: float) -> None:
        for vid, store in self.stores.items():
            stale = store.is_stale(now)
            was = self._stale[vid]
            self._stale[vid] = stale
            if stale != was:
                age = store.age(now)
                if stale:
                    self.log.warning("stale", vehicle_id=vid, age_s=age, stale_timeout_s=store.stale_timeout_s)
                else:
                    self.log.info("fresh", vehicle_id=vid)
                self.counters[vid].bump("stale_transitions" if stale else "fresh_transitions")
            # while stale, say so at least every stale timeout (and at once on each transition)
            if stale != was or (stale and now >= self._next_stale_report[vid]):
                self._next_stale_report[vid] = now + max(store.stale_timeout_s, 0.25)
                if store.age(now) is not None or stale != was:
                    self.status_pubs[vid].put(self.health(vid).model_dump_json())

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        store = self.stores[vehicle_id]
        stale = store.is_stale()
        return {"stale": stale, "state": "stale" if stale else "running",
                "detail": {**self.counters[vehicle_id].detail, "age_s": store.age()}}
