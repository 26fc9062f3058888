"""Fleet state: everything known of every vehicle behind a router (liveliness, latest OCP, plot
history, service health, rejections) under one lock, turned into plain JSON rows.  It never
touches Zenoh: :mod:`soilocp.services.fleet.monitor` feeds it."""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Optional

import numpy as np

from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.schemas.messages import OcpReply, ServiceHealth, SupervisorStatus
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import net_traction

#: A plotted point per vehicle at most this often (the OCP stream is ~100 Hz).
HISTORY_PERIOD_S = 0.2
#: Plotted points kept per vehicle (3 minutes at HISTORY_PERIOD_S).
HISTORY_POINTS = 900
#: Freshness threshold until the vehicle's OCP queryable has told us its own stale_timeout_s.
DEFAULT_STALE_TIMEOUT_S = 0.5
#: Offline vehicles are forgotten after this long.
FORGET_AFTER_S = 3600.0
#: Wheel names in the order of every per-wheel tuple (soilocp.schemas.pipeline: 1 LR, 2 LF, 3 RF, 4 RR).
WHEELS = ("LR", "LF", "RF", "RR")

Status = str  # "fresh" | "stale" | "no estimate"


def _finite(x: Optional[float]) -> Optional[float]:
    return x if x is not None and math.isfinite(x) else None


#: A health report whose process started less than this much later than the newest known start of its
#: service is the same process (the report's own wall clock minus its uptime, which jitters by the
#: report's delivery and the sender's clock steps)
SAME_START_S = 1.0


@dataclass
class _Instances:
    """The processes one service's health reports came from: a report whose process started later than
    the newest known one (``time - uptime_s``), or that names another host or pid, is a new process,
    whoever started it (the supervisor of ``soilocp run``, systemd, Docker); an older process's late
    report is not."""

    host: str
    pid: int
    started: float  # the newest known process's start, by its own clock (report time - uptime)
    restarts: int = 0  # new processes seen after the first
    seen_wall: Optional[float] = None  # our clock when the newest new process was first seen
    uptime_then: float = 0.0  # its uptime in that report

    def update(self, h: ServiceHealth, now: float) -> None:
        started = h.time - h.uptime_s
        if started <= self.started + SAME_START_S and (h.host, h.pid) == (self.host, self.pid):
            return  # the same process (or an older report of it)
        if started < self.started - SAME_START_S:
            return  # a late report of a process that has since been replaced
        self.host, self.pid, self.started = h.host, h.pid, started
        self.restarts += 1
        self.seen_wall, self.uptime_then = now, h.uptime_s


@dataclass
class _Vehicle:
    vehicle_id: str
    first_seen: float
    alive: set[str] = field(default_factory=set)
    absent_polls: dict[str, int] = field(default_factory=dict)
    offline_since: Optional[float] = None
    latest: Optional[OcpEstimate] = None
    latest_wall: Optional[float] = None  # our best estimate of when the latest OCP was produced
    stale_timeout_s: float = DEFAULT_STALE_TIMEOUT_S
    publisher_says_stale: Optional[bool] = None
    ocp_count: int = 0
    health: dict[str, ServiceHealth] = field(default_factory=dict)
    health_wall: dict[str, float] = field(default_factory=dict)  # our clock when each health report arrived
    supervisor: Optional[SupervisorStatus] = None
    supervisor_wall: float = 0.0  # when that report arrived (its ages are as of then)
    #: per service, the new processes its health showed (:meth:`FleetState.set_health`)
    instances: dict[str, "_Instances"] = field(default_factory=dict)
    rejections_seen: int = 0
    last_seen: float = 0.0
    history: deque = field(default_factory=lambda: deque(maxlen=HISTORY_POINTS))
    history_epoch: int = 0  # bumped when points are inserted before existing ones (back-fill)
    backfilled: bool = False
    next_id: int = 0


class FleetState:
    """Everything known about the fleet; thread-safe; JSON-ready snapshots.  No Zenoh in here."""

    def __init__(self, *, clock: Callable[[], float] = time.time, constants: ModelConstants = DEFAULT_CONSTANTS,
                 history_period_s: float = HISTORY_PERIOD_S):
        if not history_period_s > 0:
            raise ValueError(f"history_period_s={history_period_s!r}: must be > 0 s")
        self.clock = clock
        self.constants = constants
        self.history_period_s = float(history_period_s)
        self._v: dict[str, _Vehicle] = {}
        self._lock = threading.Lock()
        self.dropped = 0  # inputs the monitor had to drop (queue full)
        self.bad_payloads = 0

    # --- updates (called by the monitor's worker / the one-shot collector) ---------------------
    def _vehicle(self, vid: str, now: float) -> _Vehicle:
        v = self._v.get(vid)
        if v is None:
            v = self._v[vid] = _Vehicle(vid, first_seen=now, last_seen=now)
        return v

    def set_alive(self, vid: str, service: str, present: bool, now: Optional[float] = None) -> None:
        """A liveliness token appeared (``present``) or vanished."""
        now = self.clock() if now is None else now
        with self._lock:
            self._set_alive(self._vehicle(vid, now), service, present, now)

    @staticmethod
    def _set_alive(v: _Vehicle, service: str, present: bool, now: float) -> None:
        v.absent_polls.pop(service, None)
        if present:
            v.alive.add(service)
            v.offline_since = None
            v.last_seen = now
        else:
            v.alive.discard(service)
            if not v.alive and v.offline_since is None:
                v.offline_since = now

    def reconcile_alive(self, tokens: Iterable[tuple[str, str]], now: Optional[float] = None,
                        misses: int = 2) -> None:
        """Liveliness get result (every ``(vid, service)`` alive now).  Adds what is missing at once;
        removes a service only after ``misses`` consecutive polls without it, so a token that
        appears between a get and its subscriber event never flickers to "missing"."""
        now = self.clock() if now is None else now
        seen: dict[str, set[str]] = {}
        for vid, service in tokens:
            seen.setdefault(vid, set()).add(service)
        with self._lock:
            for vid, services in seen.items():
                v = self._vehicle(vid, now)
                for s in services:
                    if s in v.alive:
                        v.absent_polls.pop(s, None)
                    else:
                        self._set_alive(v, s, True, now)
            for v in self._v.values():
                for s in [s for s in v.alive if s not in seen.get(v.vehicle_id, ())]:
                    v.absent_polls[s] = v.absent_polls.get(s, 0) + 1
                    if v.absent_polls[s] >= misses:
                        self._set_alive(v, s, False, now)

    def add_estimate(self, est: OcpEstimate, now: Optional[float] = None, produced_at: Optional[float] = None) -> None:
        """An OCP estimate (publication: ``produced_at`` = now; query reply: now - age_s)."""
        now = self.clock() if now is None else now
        wall = now if produced_at is None else produced_at
        with self._lock:
            v = self._vehicle(est.vehicle_id, now)
            v.last_seen = max(v.last_seen, now)
            newer = v.latest is None or (est.seq, est.stamp) >= (v.latest.seq, v.latest.stamp) \
                or est.stamp < v.latest.stamp - 1.0  # the vehicle restarted its stream
            if newer:
                v.latest = est
                v.latest_wall = wall if v.latest_wall is None else max(v.latest_wall, wall)
                v.ocp_count += 1
                self._add_point(v, wall, est)

    def add_reply(self, reply: OcpReply, now: Optional[float] = None) -> None:
        """Answer of a vehicle's OCP queryable: freshness as the publisher sees it, latest estimate,
        and (``?last=N``) a history used to back-fill the plots."""
        now = self.clock() if now is None else now
        with self._lock:
            v = self._vehicle(reply.vehicle_id, now)
            v.stale_timeout_s = reply.stale_timeout_s
            v.publisher_says_stale = reply.stale
            v.last_seen = max(v.last_seen, now)
        if reply.latest is None or reply.age_s is None:
            return
        produced = now - reply.age_s
        latest = reply.latest
        if reply.stale and reply.history:
            latest = reply.history[-1]  # the record as published, not the "stale"-flagged copy
        if reply.history:
            self._backfill(reply.vehicle_id, reply.history, produced, now)
        with self._lock:
            v = self._v[reply.vehicle_id]
            take = v.latest is None or latest.seq > v.latest.seq or latest.stamp < v.latest.stamp - 1.0
        if take:
            self.add_estimate(latest, now, produced_at=produced)
        else:
            with self._lock:  # the publication was newer; keep it, but the publisher's age bounds ours
                v.latest_wall = max(v.latest_wall or produced, produced)

    def _backfill(self, vid: str, history: list[OcpEstimate], latest_produced: float, now: float) -> None:
        """Insert older points (wall time from the sample stamps relative to the latest) before the
        first plotted point."""
        last_stamp = history[-1].stamp
        with self._lock:
            v = self._vehicle(vid, now)
            first_wall = v.history[0]["t"] if v.history else math.inf
            pts: list[dict[str, Any]] = []
            next_t = -math.inf
            for e in history:
                t = latest_produced - (last_stamp - e.stamp)
                if t >= first_wall - self.history_period_s / 2 or t < next_t - 1e-6:
                    continue
                next_t = t + self.history_period_s
                pts.append(self._point(v, t, e))
            if pts:
                room = HISTORY_POINTS - len(v.history)
                for p in reversed(pts[-room:] if room > 0 else []):
                    v.history.appendleft(p)
                v.history_epoch += 1
            v.backfilled = True

    def _point(self, v: _Vehicle, t: float, e: OcpEstimate) -> dict[str, Any]:
        v.next_id += 1
        return {"id": v.next_id, "t": round(t, 3), "K": _finite(e.soil_strength), "K_std": _finite(e.soil_strength_std),
                "mu_T": e.mu_T, "S_T": e.S_T, "S_E": e.S_E, "status": e.status}

    def _add_point(self, v: _Vehicle, wall: float, e: OcpEstimate) -> None:
        if v.history and wall < v.history[-1]["t"] + self.history_period_s - 1e-3:
            return
        v.history.append(self._point(v, wall, e))

    def set_health(self, h: ServiceHealth, now: Optional[float] = None) -> None:
        now = self.clock() if now is None else now
        with self._lock:
            v = self._vehicle(h.vehicle_id, now)
            v.health[h.service] = h
            v.health_wall[h.service] = now
            known = v.instances.get(h.service)
            if known is None:
                v.instances[h.service] = _Instances(h.host, h.pid, h.time - h.uptime_s)
            else:
                known.update(h, now)
            if h.service == "ocp" and h.stale is not None:
                v.publisher_says_stale = h.stale

    def set_supervisor(self, st: SupervisorStatus, now: Optional[float] = None) -> None:
        """The report of the vehicle's ``soilocp run`` supervisor (the newer of two reports wins)."""
        now = self.clock() if now is None else now
        with self._lock:
            v = self._vehicle(st.vehicle_id, now)
            if v.supervisor is None or st.pid != v.supervisor.pid or st.time >= v.supervisor.time:
                v.supervisor, v.supervisor_wall = st, now

    def add_rejection(self, vid: str, now: Optional[float] = None, count: int = 1) -> None:
        """Count ``count`` rejections of ``vid``: a published one and those left out before it."""
        now = self.clock() if now is None else now
        with self._lock:
            self._vehicle(vid, now).rejections_seen += count

    def needs_backfill(self) -> list[str]:
        with self._lock:
            return [vid for vid, v in self._v.items() if not v.backfilled and v.alive]

    def mark_backfilled(self, vid: str) -> None:
        with self._lock:
            if vid in self._v:
                self._v[vid].backfilled = True

    def forget_old(self, now: Optional[float] = None, after_s: float = FORGET_AFTER_S) -> None:
        now = self.clock() if now is None else now
        with self._lock:
            for vid in [vid for vid, v in self._v.items()
                        if v.offline_since is not None and now - v.offline_since > after_s]:
                del self._v[vid]

    # --- views ------------------------------------------------------------------------------
    def vehicle_ids(self) -> list[str]:
        with self._lock:
            return sorted(self._v)

    def _row(self, v: _Vehicle, now: float) -> dict[str, Any]:
        est = v.latest
        age = None if v.latest_wall is None else max(0.0, now - v.latest_wall)
        # Our own clock decides: the age of the newest record (publication, or the queryable's
        # age_s) against the vehicle's stale_timeout_s.  A silent publisher is stale here too.
        if est is None:
            status: Status = "no estimate"
        elif age is not None and age <= v.stale_timeout_s:
            status = "fresh"
        else:
            status = "stale"
        alive = [s for s in PIPELINE_SERVICES if s in v.alive]
        missing = [s for s in PIPELINE_SERVICES if s not in v.alive]
        gw = v.health.get("gateway")
        rejections = max(v.rejections_seen, gw.rejected if gw is not None else 0)
        conflicts = gw.detail.get("source_conflicts") if gw is not None else None
        conflicts = int(conflicts) if isinstance(conflicts, (int, float)) and not isinstance(conflicts, bool) else 0
        restarts, restarts_total = None, None
        if v.supervisor is not None:
            since = max(0.0, now - v.supervisor_wall)
            restarts = {p.name: {"restarts": p.restarts, "state": p.state, "pid": p.pid, "last_exit": p.last_exit,
                                 "last_restart_age_s": None if p.last_restart_age_s is None
                                 else round(p.last_restart_age_s + since, 3)}
                        for p in v.supervisor.processes if p.restarts or p.state == "died"}
            restarts_total = sum(p.restarts for p in v.supervisor.processes)
        seen = {name: {"restarts": i.restarts, "pid": i.pid, "host": i.host,
                       "last_restart_age_s": round(now - i.seen_wall + i.uptime_then, 3)}
                for name, i in sorted(v.instances.items()) if i.restarts}
        if not v.alive:
            state = "offline"
        elif missing:
            state = "degraded"
        else:
            state = "online"
        return {
            "vehicle_id": v.vehicle_id,
            "state": state,
            "offline_since": v.offline_since,
            "services_alive": alive,
            "services_missing": missing,
            "source_alive": "vehicle" in v.alive,
            "K": _finite(est.soil_strength) if est else None,
            "K_std": _finite(est.soil_strength_std) if est else None,
            "soil_class": est.soil_class if est else None,
            "soil_class_confidence": est.soil_class_confidence if est else None,
            "mu_T": est.mu_T if est else None,
            "S_T": est.S_T if est else None,
            "S_E": est.S_E if est else None,
            "estimate_status": est.status if est else None,
            "reason": est.reason if est else "",
            "status": status,
            "publisher_stale": v.publisher_says_stale,
            "age_s": None if age is None else round(age, 3),
            "stale_timeout_s": v.stale_timeout_s,
            "seq": est.seq if est else None,
            "stamp": est.stamp if est else None,
            "rejections": rejections,
            # ordering refusals of samples that arrived while the vehicle's accepted stream was live: a
            # second publisher on its raw key (soilocp.validation.SampleValidator.conflicts)
            "source_conflicts": conflicts,
            "second_source": conflicts > 0,
            # the supervisor of `soilocp run`: restarts in all, and per process that restarted or died
            # (null: no supervisor report, e.g. services run by systemd)
            "restarts_total": restarts_total,
            "restarts": restarts,
            # new processes of a service seen in its health reports while this monitor listened, whoever
            # restarted them (the supervisor, systemd, Docker): per service that restarted, how many times,
            # its pid and host now, and how long ago the newest started
            "restarts_seen_total": sum(x["restarts"] for x in seen.values()),
            "restarts_seen": seen,
            # each service's uptime as of now, from its last health report (a one-shot status, which saw no
            # restart happen, still shows a process younger than the others)
            "uptime_s": {name: round(h.uptime_s + max(0.0, now - v.health_wall.get(name, now)), 3)
                         for name, h in sorted(v.health.items())},
            "ocp_received": v.ocp_count,
            "first_seen": v.first_seen,
            "last_seen": v.last_seen,
        }

    def rows(self, now: Optional[float] = None) -> list[dict[str, Any]]:
        """One JSON-ready row per vehicle, sorted by id."""
        now = self.clock() if now is None else now
        with self._lock:
            return [self._row(self._v[vid], now) for vid in sorted(self._v)]

    def detail(self, vid: str, now: Optional[float] = None, *, after_id: int = 0,
               epoch: Optional[int] = None) -> Optional[dict[str, Any]]:
        """Row + plotted history (points with id > ``after_id``, or all of them when ``epoch``
        differs from the vehicle's history epoch) + per-wheel operating points + the traction-slip
        curve at the current K.  None for an unknown vehicle."""
        now = self.clock() if now is None else now
        with self._lock:
            v = self._v.get(vid)
            if v is None:
                return None
            row = self._row(v, now)
            full = epoch is None or epoch != v.history_epoch
            hist = [p for p in v.history if full or p["id"] > after_id]
            est = v.latest
            out = {**row, "history_epoch": v.history_epoch, "history_full": full, "history": hist,
                   "wheels": None, "health": {s: h.model_dump(mode="json") for s, h in v.health.items()}}
        if est is not None:
            out["wheels"] = [{"wheel": w, "slip": _finite(s), "mu": _finite(m)}
                             for w, s, m in zip(WHEELS, est.slip, est.mu)]
        out["curve"] = traction_curve(row["K"], row["K_std"], [w["slip"] for w in out["wheels"] or []],
                                      self.constants)
        return out


def traction_curve(k: Optional[float], k_std: Optional[float], wheel_slips: Iterable[Optional[float]] = (),
                   constants: ModelConstants = DEFAULT_CONSTANTS, points: int = 111) -> Optional[dict[str, Any]]:
    """Net traction mu(S) at the current K (eq. 6, via :func:`soilocp.model.traction.net_traction`, with
    docs/method.md §8's bridge at S=0), plus the curves at K - std and K + std (K - std floored at
    K/10 so the band stays defined).  Slip axis: -0.1..1, widened to every wheel's slip (within
    -1..1).  None without a K."""
    if k is None or not (k > 0):
        return None
    lo_s, hi_s = -0.1, 1.0
    for s in wheel_slips:
        if s is not None and math.isfinite(s):
            lo_s, hi_s = min(lo_s, max(s, -1.0)), max(hi_s, min(s, 1.0))
    slip = np.linspace(lo_s, hi_s, points)
    std = k_std if k_std is not None and k_std >= 0 else 0.0
    k_lo, k_hi = max(k - std, k / 10.0), k + std

    def _r(a) -> list[float]:
        return [round(float(x), 5) for x in a]

    return {"K": k, "K_lo": k_lo, "K_hi": k_hi, "slip": _r(slip), "mu": _r(net_traction(slip, k, constants)),
            "mu_lo": _r(net_traction(slip, k_lo, constants)), "mu_hi": _r(net_traction(slip, k_hi, constants))}


# ----------------------------------------------------------------------------------------------
# Zenoh side
# ----------------------------------------------------------------------------------------------
