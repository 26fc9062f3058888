"""Fleet monitor: what every vehicle behind a router is doing, from Zenoh liveliness, queries and
subscriptions.  Used by ``soilocp fleet status`` (one-shot queries) and ``soilocp dashboard``
(live subscriptions plus periodic queries).

Sources (all keys from :mod:`soilocp.schemas.keys`):

* liveliness ``soilocp/*/alive/*``: which services of which vehicle run (get, and a subscriber
  with history for the live view);
* ``soilocp/*/ocp``: the OCP queryable (latest estimate, its age and freshness; ``?last=N`` for a
  back-fill of the plots) and the per-sample publication (live view);
* ``soilocp/*/status/*``: ServiceHealth of each service (the gateway's ``rejected`` counter is
  the vehicle's rejection count);
* ``soilocp/*/rejected``: rejections as they happen (live view; counted when no gateway health
  is known);
* ``soilocp/*/supervisor``: what the supervisor of ``soilocp run`` restarted (query and publication).

:class:`FleetState` holds everything under one lock and turns it into plain JSON rows; it never
touches Zenoh.  :class:`FleetMonitor` feeds it: the Zenoh callbacks only put the raw payload in a
bounded queue (a full queue drops and counts), one worker thread parses and applies, and one
poller thread runs the periodic queries, so no slow work ever runs in a Zenoh callback.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any, Optional

from pydantic import ValidationError

from soilocp.schemas import keys
from soilocp.services.runtime.process import undeclare_all
from soilocp.schemas.messages import OcpReply, Rejection, ServiceHealth, SupervisorStatus
from soilocp.schemas.pipeline import OcpEstimate

from soilocp.services.fleet.state import FleetState


def _parse_alive(key: str) -> Optional[tuple[str, str]]:
    try:
        return keys.service_of_alive_key(key)
    except ValueError:
        return None


def query_fleet(session, state: FleetState, timeout: float, *, misses: int = 1) -> int:
    """One round of queries (liveliness, OCP queryables, status queryables) into ``state``.
    Returns how many replies arrived (0: nothing answered)."""
    n = 0
    tokens: list[tuple[str, str]] = []
    for r in session.liveliness().get(keys.any_vehicle_alive(), timeout=timeout):
        if r.ok is not None:
            parsed = _parse_alive(str(r.ok.key_expr))
            if parsed:
                tokens.append(parsed)
                n += 1
    state.reconcile_alive(tokens, misses=misses)
    import zenoh

    # No consolidation: replies on different keys must all arrive (and the status queryables answer
    # on the query's own wildcard key, which the default consolidation would fold into one reply).
    every = zenoh.ConsolidationMode.NONE
    for selector, model, apply in ((keys.any_vehicle_ocp(), OcpReply, state.add_reply),
                                   (keys.any_vehicle_status(), ServiceHealth, state.set_health),
                                   (keys.any_vehicle_supervisor(), SupervisorStatus, state.set_supervisor)):
        for r in session.get(selector, timeout=timeout, consolidation=every):
            if r.ok is None:
                continue
            try:
                apply(model.model_validate_json(r.ok.payload.to_bytes()))
                n += 1
            except ValidationError:
                state.bad_payloads += 1
    return n


class FleetMonitor:
    """Feeds a :class:`FleetState` from a Zenoh session: subscribers (callbacks only enqueue),
    one worker thread (parse + apply) and one poller thread (periodic queries and back-fill)."""

    def __init__(self, session, state: FleetState, *, poll_period_s: float = 1.0, query_timeout_s: float = 1.0,
                 queue_size: int = 8192, backfill_last: int = 1000):
        self.session = session
        self.state = state
        self.poll_period_s = poll_period_s
        self.query_timeout_s = query_timeout_s
        self.backfill_last = int(backfill_last)
        self._q: queue.Queue = queue.Queue(maxsize=queue_size)
        self._stop = threading.Event()
        self._decls: list[Any] = []
        self._threads = [threading.Thread(target=self._work, name="fleet-worker", daemon=True),
                         threading.Thread(target=self._poll, name="fleet-poller", daemon=True)]
        self.polls = 0

    # callbacks: enqueue only
    def _offer(self, item) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.state.dropped += 1

    def start(self) -> "FleetMonitor":
        import zenoh

        put = zenoh.SampleKind.PUT

        def on_alive(sample) -> None:
            self._offer(("alive", str(sample.key_expr), sample.kind == put, time.time()))

        def on_data(kind: str):
            def _cb(sample) -> None:
                self._offer((kind, str(sample.key_expr), sample.payload.to_bytes(), time.time()))
            return _cb

        for t in self._threads:
            t.start()
        s = self.session
        self._decls = [
            s.liveliness().declare_subscriber(keys.any_vehicle_alive(), on_alive, history=True),
            s.declare_subscriber(keys.any_vehicle_ocp(), on_data("ocp")),
            s.declare_subscriber(keys.any_vehicle_status(), on_data("status")),
            s.declare_subscriber(keys.any_vehicle_rejected(), on_data("rejected")),
            s.declare_subscriber(keys.any_vehicle_supervisor(), on_data("supervisor")),
        ]
        return self

    def stop(self) -> None:
        self._stop.set()
        undeclare_all(self._decls)
        self._offer(None)
        for t in self._threads:
            t.join(timeout=self.query_timeout_s + 1.0)

    def _apply(self, item) -> None:
        kind, key, data, wall = item
        st = self.state
        if kind == "alive":
            parsed = _parse_alive(key)
            if parsed:
                st.set_alive(parsed[0], parsed[1], data, wall)
            return
        try:
            if kind == "ocp":
                st.add_estimate(OcpEstimate.model_validate_json(data), wall)
            elif kind == "status":
                st.set_health(ServiceHealth.model_validate_json(data), wall)
            elif kind == "supervisor":
                st.set_supervisor(SupervisorStatus.model_validate_json(data), wall)
            elif kind == "rejected":
                vid, _rest = keys.split_key(key)
                try:
                    unpublished = Rejection.model_validate_json(data).suppressed
                except ValidationError:
                    unpublished = 0  # still a rejection of that vehicle; count it
                st.add_rejection(vid, wall, 1 + unpublished)
        except (ValidationError, ValueError):
            st.bad_payloads += 1

    def _work(self) -> None:
        while True:
            item = self._q.get()
            if item is None or self._stop.is_set():
                return
            self._apply(item)

    def _poll(self) -> None:
        while not self._stop.is_set():
            try:
                query_fleet(self.session, self.state, self.query_timeout_s, misses=2)
                for vid in self.state.needs_backfill():
                    if self._stop.is_set():
                        return
                    self._backfill(vid)
                self.state.forget_old()
                self.polls += 1
            except Exception:  # a closed session at shutdown, a transient error: try again later
                if self._stop.is_set():
                    return
            self._stop.wait(self.poll_period_s)

    def _backfill(self, vid: str) -> None:
        selector = f"{keys.ocp(vid)}?last={self.backfill_last}"
        for r in self.session.get(selector, timeout=self.query_timeout_s):
            if r.ok is None:
                continue
            try:
                self.state.add_reply(OcpReply.model_validate_json(r.ok.payload.to_bytes()))
            except ValidationError:
                self.state.bad_payloads += 1
        self.state.mark_backfilled(vid)
