"""What every soilocp service process shares: configuration, logging, the Zenoh session,
liveliness, health, signal handling and the bounded worker queue.

A service is a subclass of :class:`Service`: it declares its subscribers and publishers per
vehicle id in :meth:`Service.declare`, and does its work in :meth:`Service.handle`, which runs on
one worker thread fed by a bounded queue.  Zenoh callbacks only enqueue (one slow callback would
stall the whole session); a full queue drops the item and counts it.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from schemas import keys
from schemas.messages import ServiceHealth
from schemas.sensor import VehicleId

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

#: Environment variables (documented in docs/services.md; deploy/ configs, units and images use them).
ENV_CONFIG = "SOILOCP_CONFIG"
ENV_VEHICLE_ID = "SOILOCP_VEHICLE_ID"
ENV_CONNECT = "SOILOCP_CONNECT"
ENV_LISTEN = "SOILOCP_LISTEN"
ENV_MODE = "SOILOCP_MODE"
ENV_LOG_LEVEL = "SOILOCP_LOG_LEVEL"
ENV_STALE_TIMEOUT = "SOILOCP_STALE_TIMEOUT"
#: Set to 1 by ``soilocp run`` for its children: stop when the parent process goes away.
ENV_EXIT_WITH_PARENT = "SOILOCP_EXIT_WITH_PARENT"


class ConfigError(Exception):
    """A fatal configuration problem: the process prints one line and exits with status 2."""


# ----------------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------------
class ServiceConfig(BaseModel):
    """Settings of one service process (file < environment < command line)."""

    model_config = ConfigDict(extra="forbid")

    vehicle_ids: list[VehicleId] = Field(default_factory=lambda: ["rover1"], min_length=1)
    mode: Literal["client", "peer"] = "client"
    connect: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    listen: list[str] = Field(default_factory=list)
    multicast: bool = Field(False, description="Zenoh multicast scouting (off: explicit endpoints only)")
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    stale_timeout_s: float = Field(0.5, gt=0, le=3600, description="OCP publisher: stale after this much silence")
    queue_size: int = Field(4096, ge=1, le=1_000_000, description="Worker queue bound; beyond it inputs are dropped")
    join_buffer: int = Field(256, ge=1, le=100_000, description="Observer: samples waiting for their normal forces")
    join_timeout_s: float = Field(0.2, gt=0, description="Observer: give up on a sample's normal forces after this")
    history_size: int = Field(1000, ge=1, le=1_000_000, description="OCP publisher: estimates kept for ?last / ?since")
    status_period_s: float = Field(1.0, gt=0, le=3600, description="Period of the health publication")
    max_payload_bytes: int = Field(65536, ge=256, description="Gateway: larger raw payloads are rejected")
    connect_retry_s: float = Field(1.0, gt=0, le=60, description="Client: wait per connection attempt to the router")
    pipeline_config: Optional[str] = Field(None, description="Path of the physics PipelineConfig file (null: defaults)")

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, value: list[str]) -> list[str]:
        for ep in value:
            check_endpoint(ep)
        return value

    @property
    def vehicle_id(self) -> str:
        return self.vehicle_ids[0]


def check_endpoint(ep: object) -> str:
    """A Zenoh locator ``proto/address`` (e.g. ``tcp/127.0.0.1:7447``); ValueError otherwise."""
    if not isinstance(ep, str) or "/" not in ep or ep.startswith("/") or ep.endswith("/") or any(c.isspace() for c in ep):
        raise ValueError(f"endpoint {ep!r} is invalid: expected 'proto/address', e.g. {DEFAULT_ENDPOINT}")
    return ep


def _split_list(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def _read_config_file(path: str) -> dict[str, Any]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"config file {path}: cannot read: {exc.strerror or exc}") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"config file {path}: not valid JSON: {exc.msg} at line {exc.lineno}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path}: top level must be a JSON object, got {type(data).__name__}")
    return data


def _file_section(data: dict[str, Any], service: str, path: str) -> dict[str, Any]:
    """Merge a deployment file's common keys with its ``services.<service>`` section.

    ``vehicle_id`` (one id) is accepted as a shorthand for ``vehicle_ids``; the ``router`` and
    ``services`` sections belong to other processes and are skipped here.
    """
    out = {k: v for k, v in data.items() if k not in ("services", "router", "$comment")}
    sections = data.get("services", {})
    if not isinstance(sections, dict):
        raise ConfigError(f"config file {path}: 'services' must be an object of per-service sections")
    own = sections.get(service, {})
    if not isinstance(own, dict):
        raise ConfigError(f"config file {path}: 'services.{service}' must be an object")
    out.update(own)
    if "vehicle_id" in out:
        vid = out.pop("vehicle_id")
        out["vehicle_ids"] = vid if isinstance(vid, list) else [vid]
    return out


def load_service_config(
    service: str,
    *,
    config_path: Optional[str] = None,
    overrides: Optional[dict[str, Any]] = None,
    env: Optional[dict[str, str]] = None,
) -> ServiceConfig:
    """Build a :class:`ServiceConfig`: defaults < file < environment < ``overrides`` (command line).

    The file is ``config_path`` or ``$SOILOCP_CONFIG``.  Raises :class:`ConfigError` with a
    one-line message naming the setting, its value and the reason.
    """
    env = dict(os.environ) if env is None else env
    values: dict[str, Any] = {}
    path = config_path or env.get(ENV_CONFIG) or None
    if path:
        values.update(_file_section(_read_config_file(path), service, path))
    if env.get(ENV_VEHICLE_ID):
        values["vehicle_ids"] = _split_list(env[ENV_VEHICLE_ID])
    if env.get(ENV_CONNECT):
        values["connect"] = _split_list(env[ENV_CONNECT])
    if env.get(ENV_LISTEN):
        values["listen"] = _split_list(env[ENV_LISTEN])
    if env.get(ENV_MODE):
        values["mode"] = env[ENV_MODE].strip().lower()
    if env.get(ENV_LOG_LEVEL):
        values["log_level"] = env[ENV_LOG_LEVEL].strip().lower()
    if env.get(ENV_STALE_TIMEOUT):
        raw = env[ENV_STALE_TIMEOUT].strip()
        try:
            values["stale_timeout_s"] = float(raw)
        except ValueError:
            raise ConfigError(f"{ENV_STALE_TIMEOUT}={raw!r} is not a number of seconds") from None
    for k, v in (overrides or {}).items():
        if v is not None and v != () and v != []:
            values[k] = list(v) if isinstance(v, tuple) else v
    try:
        return ServiceConfig.model_validate(values)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in err.get("loc", ())) or "<config>"
        raise ConfigError(
            f"invalid setting {loc}={err.get('input')!r} for service {service}: {err.get('msg')}"
            + (f" (config file {path})" if path else "")
        ) from None


def zenoh_config(
    mode: str, connect: list[str], listen: list[str], *, multicast: bool = False, connect_timeout_ms: Optional[int] = None,
    tls_from_environment: bool = True,
):
    """A ``zenoh.Config`` with explicit endpoints (multicast scouting off unless asked for)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    if connect_timeout_ms is not None:
        conf.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_ms)))
    # After a lost link (router restarted), retry quickly: the default backoff grows to several
    # seconds, far longer than the stale timeout of the OCP output.
    conf.insert_json5("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}")
    # Links that leave a vehicle are tls/ (mutual TLS, docs/deploy.md): the certificate comes from
    # SOILOCP_TLS_CA/_CERT/_KEY; plain tcp/ endpoints of the same process ignore it.
    from services.security.fleet_security import apply_tls, tls_from_env

    if not tls_from_environment:  # the caller (the router) applies its own, file < environment
        return conf
    try:
        tls = tls_from_env()
        tls_eps = [ep for ep in [*connect, *listen] if ep.startswith("tls/")]
        if tls_eps and tls is None:
            raise ValueError(f"endpoints {tls_eps} use TLS but SOILOCP_TLS_CA, SOILOCP_TLS_CERT and "
                             "SOILOCP_TLS_KEY are not set")
        if tls is not None:
            apply_tls(conf, tls, listener=any(ep.startswith("tls/") for ep in listen))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return conf


# ----------------------------------------------------------------------------------------------
# logging: one JSON object per line on stderr
# ----------------------------------------------------------------------------------------------
_LEVELS = {"debug": 10, "info": 20, "warning": 30, "error": 40}


class JsonLog:
    """Structured logs: ``{"ts":..., "level":..., "service":..., "event":..., ...}`` per line on stderr."""

    def __init__(self, service: str, level: str = "info", stream=None):
        self.service = service
        self.threshold = _LEVELS.get(level, 20)
        self.stream = stream if stream is not None else sys.stderr
        self._lock = threading.Lock()

    def log(self, level: str, event: str, **fields: Any) -> None:
        if _LEVELS[level] < self.threshold:
            return
        rec = {"ts": round(time.time(), 6), "level": level, "service": self.service, "event": event}
        rec.update(fields)
        line = json.dumps(rec, default=str, allow_nan=True)
        with self._lock:
            try:
                self.stream.write(line + "\n")
                self.stream.flush()
            except (OSError, ValueError):  # stderr closed (parent gone): logging must never kill a service
                pass

    def debug(self, event: str, **f: Any) -> None:
        self.log("debug", event, **f)

    def info(self, event: str, **f: Any) -> None:
        self.log("info", event, **f)

    def warning(self, event: str, **f: Any) -> None:
        self.log("warning", event, **f)

    def error(self, event: str, **f: Any) -> None:
        self.log("error", event, **f)


# ----------------------------------------------------------------------------------------------
# signals
# ----------------------------------------------------------------------------------------------
def install_stop_handlers(stop: threading.Event, log: Optional[JsonLog] = None, *, grace_s: float = 1.8) -> None:
    """SIGINT/SIGTERM set ``stop``; a second signal, or a shutdown hanging past ``grace_s``, exits at once.

    SIGTERM is handled explicitly: as PID 1 in a container the default action is ignored.
    """

    def _force_exit_later() -> None:
        time.sleep(grace_s)
        if log:
            log.error("forced_exit", reason=f"shutdown took longer than {grace_s} s")
        os._exit(0)

    def _handler(signum, _frame) -> None:
        if stop.is_set():
            os._exit(130 if signum == signal.SIGINT else 143)
        if log:
            log.info("signal", signal=signal.Signals(signum).name)
        stop.set()
        threading.Thread(target=_force_exit_later, name="shutdown-watchdog", daemon=True).start()

    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)


def watch_parent(stop: threading.Event, log: Optional[JsonLog] = None, *, period_s: float = 0.5) -> None:
    """If ``$SOILOCP_EXIT_WITH_PARENT`` is 1, set ``stop`` once the parent process is gone
    (the process is re-parented), so that children of a killed ``soilocp run`` never linger."""
    if os.environ.get(ENV_EXIT_WITH_PARENT) != "1":
        return
    parent = os.getppid()

    def _watch() -> None:
        while not stop.wait(period_s):
            if os.getppid() != parent:
                if log:
                    log.warning("parent_gone", parent_pid=parent)
                stop.set()
                time.sleep(1.8)  # same grace as a signal, then go
                os._exit(0)

    threading.Thread(target=_watch, name="parent-watch", daemon=True).start()


def open_session(
    mode: str,
    connect: list[str],
    listen: list[str],
    *,
    multicast: bool,
    stop: threading.Event,
    log: JsonLog,
    retry_s: float = 1.0,
):
    """Open a Zenoh session; in client mode, retry until a router answers or ``stop`` is set.

    Each attempt waits ``retry_s`` for the router (``connect/timeout_ms``), so a service started
    before its router waits for it and still reacts to SIGTERM within ~``retry_s``.  Returns None
    if stopped before connecting.
    """
    import zenoh

    attempt = 0
    while not stop.is_set():
        attempt += 1
        timeout_ms = int(retry_s * 1000) if mode == "client" else None
        conf = zenoh_config(mode, connect, listen, multicast=multicast, connect_timeout_ms=timeout_ms)
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            if mode != "client":
                raise
            if attempt == 1 or attempt % 10 == 0:
                log.warning("waiting_for_router", connect=connect, attempt=attempt, error=str(exc)[:200])
            stop.wait(0.1)
            continue
        log.info("session_open", mode=mode, connect=connect, listen=listen, zid=str(session.zid()), attempts=attempt)
        return session
    return None


# ----------------------------------------------------------------------------------------------
# counters and the bounded worker
# ----------------------------------------------------------------------------------------------
@dataclass
class Counters:
    """Per-vehicle counters of one service (plain ints: updated under the GIL by one writer each)."""

    received: int = 0
    published: int = 0
    rejected: int = 0
    dropped: int = 0
    errors: int = 0
    last_seq: Optional[int] = None
    last_stamp: Optional[float] = None
    last_input_wall: Optional[float] = None
    detail: dict[str, Any] = field(default_factory=dict)
    #: share of the recent inputs whose processing failed (exponential window of ~FAILURE_WINDOW inputs)
    failure_rate: float = 0.0

    def bump(self, name: str, n: int = 1) -> None:
        self.detail[name] = int(self.detail.get(name, 0)) + n

    def outcome(self, failed: bool) -> None:
        self.failure_rate += (float(failed) - self.failure_rate) / FAILURE_WINDOW


#: Inputs over which a service's failure rate is averaged; above FAILING_RATE its health says "failing".
FAILURE_WINDOW = 20
FAILING_RATE = 0.5


class BoundedWorker:
    """One thread draining a bounded FIFO queue; ``offer`` never blocks (a full queue drops)."""

    def __init__(self, name: str, handler: Callable[[Any], None], maxsize: int, on_drop: Callable[[Any], None],
                 on_error: Callable[[Any, BaseException], None]):
        self._q: queue.Queue = queue.Queue(maxsize=maxsize)
        self._handler = handler
        self._on_drop = on_drop
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"worker-{name}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, item: Any) -> bool:
        try:
            self._q.put_nowait(item)
            return True
        except queue.Full:
            self._on_drop(item)
            return False

    def depth(self) -> int:
        return self._q.qsize()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._q.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                self._handler(item)
            except Exception as exc:  # one bad item must not stop the service
                self._on_error(item, exc)

    def stop(self, timeout: float = 0.5) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)


# ----------------------------------------------------------------------------------------------
# the service base class and its runner
# ----------------------------------------------------------------------------------------------
class Service:
    """Base of the pipeline services: per-vehicle declarations, one worker, health and liveliness."""

    name: ClassVar[str] = "service"

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

    def handle(self, item: Any) -> None:
        """Process one queued item on the worker thread: ``(vehicle_id, kind, payload, wall_time, key)``."""
        raise NotImplementedError

    def tick(self, now: float) -> None:
        """Periodic hook on the main thread (about every 50 ms); may set ``self.stop_event``."""

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        """Extra fields of :class:`ServiceHealth` (``state``, ``stale``...)."""
        return {}

    # --- helpers -------------------------------------------------------------------------------
    def keep(self, entity: Any) -> Any:
        self._declared.append(entity)
        return entity

    def subscribe(self, session, key: str, vehicle_id: str, kind: str) -> None:
        """Subscribe ``key``; the callback only enqueues ``(vehicle_id, kind, payload, wall, key)``."""
        counters = self.counters[vehicle_id]
        offer = self.worker.offer

        def _cb(sample) -> None:
            counters.received += 1
            offer((vehicle_id, kind, sample.payload.to_bytes(), time.time(), str(sample.key_expr)))

        self.keep(session.declare_subscriber(key, _cb))

    def publisher(self, session, key: str):
        """A reliable publisher that blocks rather than drops under congestion (pipeline data)."""
        import zenoh

        return self.keep(session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK))

    def _handle_safe(self, item: Any) -> None:
        self.handle(item)
        vid = item[0] if isinstance(item, tuple) and item else self.cfg.vehicle_id
        c = self.counters.get(vid)
        if c is not None:
            c.outcome(False)

    def _dropped(self, item: Any) -> None:
        vid = item[0] if isinstance(item, tuple) and item else self.cfg.vehicle_id
        c = self.counters.get(vid)
        if c is not None:
            c.dropped += 1
            c.bump("queue_full")
        self._drop_logged += 1
        if self._drop_logged <= 10 or self._drop_logged % 1000 == 0:
            self.log.warning("queue_full_drop", vehicle_id=vid, dropped_total=self._drop_logged)

    def _failed(self, item: Any, exc: BaseException) -> None:
        vid = item[0] if isinstance(item, tuple) and item else self.cfg.vehicle_id
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
            received=c.received,
            published=c.published,
            rejected=c.rejected,
            dropped=c.dropped,
            errors=c.errors,
            failure_rate=c.failure_rate,
            queue_depth=self.worker.depth(),
            last_seq=c.last_seq,
            last_stamp=c.last_stamp,
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
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:  # already gone with the session: nothing left to release
                pass
        self._declared.clear()


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
                           retry_s=cfg.connect_retry_s)
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
        log.info("running", vehicle_ids=cfg.vehicle_ids)
        next_status = 0.0
        while not stop.wait(0.05):
            now = time.time()
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
