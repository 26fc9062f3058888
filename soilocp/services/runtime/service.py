"""What every soilocp service process shares: configuration, logging, the Zenoh session,
liveliness, health, signal handling and the bounded worker queue.

A service is a subclass of :class:`Service`: it declares its subscribers and publishers per
vehicle id in :meth:`Service.declare`, and does its work in :meth:`Service.handle`, which runs on
one worker thread fed by a bounded queue.  Zenoh callbacks only enqueue (one slow callback would
stall the whole session); a full queue drops the item and counts it.  (Handling each input in the
Zenoh callback instead, as a bare zenoh-python relay does, was measured: no gain in CPU per sample beyond
the run-to-run spread, and under overload the backlog moved into the router's links, p50 > 1 s at 1 kHz;
docs/performance.md.)
"""

from __future__ import annotations

import gc
import os
import socket
import threading
import time
from typing import Any, ClassVar

from soilocp.schemas import keys
from soilocp.schemas.messages import ServiceHealth
from soilocp.services.runtime.config import ConfigError, ServiceConfig
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.process import install_stop_handlers, open_session, undeclare_all, watch_parent
from soilocp.services.runtime.worker import FAILING_RATE, HEALTH_COUNTERS, BoundedWorker, Counters, WorkItem

class Service:
    """Base of the pipeline services: per-vehicle declarations, one worker, health and liveliness."""

    name: ClassVar[str] = "service"
    #: whether :meth:`handle` reads each sample's own key (``WorkItem.key``, ``str(sample.key_expr)``: 0.8 us a
    #: message); else ``WorkItem.key`` is the key the subscriber was declared on
    needs_key: ClassVar[bool] = False

    def __init__(self, cfg: ServiceConfig, log: JsonLog):
        self.cfg = cfg
        self.log = log
        self.started_wall = time.time()
        self.counters: dict[str, Counters] = {vid: Counters() for vid in cfg.vehicle_ids}
        self._declared: list[Any] = []
        self.session = None
        self.worker = BoundedWorker(self.name, self._handle_safe, cfg.queue_size, self._dropped, self._failed)
        self._drop_logged = 0
        self.stop_event: threading.Event = threading.Event()  # replaced by the runner's
        self.exit_code = 0

    # --- to implement --------------------------------------------------------------------------
    def declare(self, session, vehicle_id: str) -> None:
        """Declare subscribers/publishers/queryables for one vehicle (keep them with :meth:`keep`)."""
        raise NotImplementedError

    def handle(self, item: WorkItem) -> None:
        """Process one queued :class:`WorkItem` on the worker thread."""
        raise NotImplementedError

    def tick(self, now: float) -> None:
        """Periodic hook on the main thread (about every 50 ms); may set ``self.stop_event``."""

    def ticks(self) -> bool:
        """Whether :meth:`tick` has work in this process (else the main thread wakes only for the health)."""
        return type(self).tick is not Service.tick

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        """Extra fields of :class:`ServiceHealth` (``state``, ``stale``...)."""
        return {}

    # --- helpers -------------------------------------------------------------------------------
    def keep(self, entity: Any) -> Any:
        self._declared.append(entity)
        return entity

    def subscribe(self, session, key: str, vehicle_id: str, kind: str) -> None:
        """Subscribe ``key``; the callback only enqueues a :class:`WorkItem`."""
        counters = self.counters[vehicle_id]
        offer = self.worker.offer
        clock = time.time

        needs_key = self.needs_key

        def _cb(sample) -> None:
            counters.received += 1
            offer(WorkItem(vehicle_id, kind, sample.payload.to_bytes(), clock(),
                           str(sample.key_expr) if needs_key else key))

        self.keep(session.declare_subscriber(key, _cb))

    def publisher(self, session, key: str):
        """A reliable publisher that blocks rather than drops under congestion (pipeline data);
        ``express`` from the service's config."""
        import zenoh

        return self.keep(session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                   express=self.cfg.express))

    def _handle_safe(self, item: WorkItem) -> None:
        self.handle(item)
        vid = item.vehicle_id if isinstance(item, WorkItem) else self.cfg.vehicle_id
        c = self.counters.get(vid)
        if c is not None:
            c.outcome(False)

    def _dropped(self, item: Any) -> None:
        vid = item.vehicle_id if isinstance(item, WorkItem) else self.cfg.vehicle_id
        c = self.counters.get(vid)
        if c is not None:
            c.dropped += 1
            c.bump("queue_full")
        self._drop_logged += 1
        if self._drop_logged <= 10 or self._drop_logged % 1000 == 0:
            self.log.warning("queue_full_drop", vehicle_id=vid, dropped_total=self._drop_logged)

    def _failed(self, item: Any, exc: BaseException) -> None:
        vid = item.vehicle_id if isinstance(item, WorkItem) else self.cfg.vehicle_id
        c = self.counters.get(vid)
        if c is not None:
            c.errors += 1
            c.outcome(True)
            n = c.errors
        else:
            n = 0
        if n <= 20 or n % 1000 == 0:
            self.log.error("processing_error", vehicle_id=vid, error=f"{type(exc).__name__}: {exc}"[:500], errors=n)

    def health(self, vehicle_id: str, state: str = "running") -> ServiceHealth:
        c = self.counters[vehicle_id]
        now = time.time()
        fields: dict[str, Any] = dict(
            service=self.name,
            vehicle_id=vehicle_id,
            pid=os.getpid(),
            host=socket.gethostname(),
            state=state,
            uptime_s=max(0.0, now - self.started_wall),
            **{name: getattr(c, name) for name in HEALTH_COUNTERS},
            queue_depth=self.worker.depth(),
            last_input_age_s=None if c.last_input_wall is None else max(0.0, now - c.last_input_wall),
            detail=dict(c.detail),
            time=now,
        )
        fields.update(self.health_extra(vehicle_id))
        if fields["state"] == "running" and c.failure_rate > FAILING_RATE:
            fields["state"] = "failing"  # alive, but most inputs fail: never look healthy
        if state == "stopping":
            fields["state"] = "stopping"
        return ServiceHealth(**fields)

    def close(self) -> None:
        undeclare_all(self._declared)


def run_service(service_cls: type[Service], cfg: ServiceConfig, **kwargs: Any) -> int:
    """Run one service until SIGINT/SIGTERM (or until it stops itself); returns the exit status.

    ``kwargs`` go to the service's constructor.  A ValueError/OSError from the constructor (bad
    pipeline config, missing replay file) is a fatal configuration error.
    """
    log = JsonLog(service_cls.name, cfg.log_level)
    stop = threading.Event()
    install_stop_handlers(stop, log)
    watch_parent(stop, log)
    log.info("starting", vehicle_ids=cfg.vehicle_ids, mode=cfg.mode, connect=cfg.connect, listen=cfg.listen, pid=os.getpid())
    try:
        svc = service_cls(cfg, log, **kwargs)
    except (ValueError, OSError) as exc:  # e.g. a bad pipeline config file
        raise ConfigError(f"{service_cls.name}: {exc}") from exc
    session = open_session(cfg.mode, cfg.connect, cfg.listen, multicast=cfg.multicast, stop=stop, log=log,
                           retry_s=cfg.connect_retry_s, batching=cfg.batching)
    if session is None:
        log.info("stopped", reason="signal before connecting")
        return 0
    import zenoh

    tokens = []
    status_pubs: dict[str, Any] = {}
    try:
        svc.session = session
        svc.stop_event = stop
        svc.worker.start()
        for vid in cfg.vehicle_ids:
            svc.declare(session, vid)
            status_pubs[vid] = session.declare_publisher(keys.status(vid, svc.name),
                                                         congestion_control=zenoh.CongestionControl.DROP)

            def _status_query(query, _vid=vid, _key=keys.status(vid, svc.name)) -> None:
                try:  # reply on the concrete key: the query may be a wildcard (soilocp/*/status/*)
                    query.reply(_key, svc.health(_vid).model_dump_json())
                except Exception as exc:  # a failed reply must not disturb the service
                    log.warning("status_reply_failed", error=str(exc)[:200])

            svc.keep(session.declare_queryable(keys.status(vid, svc.name), _status_query))
        # The token goes last: once it is visible, the inputs are already subscribed.
        for vid in cfg.vehicle_ids:
            tokens.append(session.liveliness().declare_token(keys.alive(vid, svc.name)))
        # what start-up built (modules, schemas, the physics) lives as long as the process: out of the
        # collector's sight, a full collection scans only what came since (else 10-40 ms per pass, on
        # whichever message the pass happens to fall)
        gc.collect()
        gc.freeze()
        log.info("running", vehicle_ids=cfg.vehicle_ids)
        # the main thread wakes every 50 ms for a service with a tick, else only for its health (an idle wake-up
        # per 50 ms is a fifth of a 100 Hz stream's)
        ticks = svc.ticks()
        period = 0.05 if ticks else min(cfg.status_period_s, 0.5)
        next_status = 0.0
        while not stop.wait(period):
            now = time.time()
            if ticks:
                svc.tick(now)
            if now >= next_status:
                next_status = now + cfg.status_period_s
                for vid, pub in status_pubs.items():
                    pub.put(svc.health(vid).model_dump_json())
        for vid, pub in status_pubs.items():
            try:
                pub.put(svc.health(vid, state="stopping").model_dump_json())
            except Exception:
                pass
    finally:
        for tok in tokens:
            try:
                tok.undeclare()
            except Exception:
                pass
        svc.worker.stop()
        svc.close()
        for pub in status_pubs.values():
            try:
                pub.undeclare()
            except Exception:
                pass
        session.close()
        totals = {vid: {"received": c.received, "published": c.published, "rejected": c.rejected,
                        "dropped": c.dropped, "errors": c.errors} for vid, c in svc.counters.items()}
        log.info("stopped", totals=totals, exit_code=svc.exit_code)
    return svc.exit_code
