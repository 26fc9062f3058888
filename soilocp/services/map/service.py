"""The map service process: subscribes every vehicle's soil estimates (``soilocp/*/soil``), commits
them in batches (:class:`soilocp.map.updater.MapUpdater`), then publishes the changed cells (the
acknowledgement: nothing is published before its commit), answers box queries and reports status.

Threads: Zenoh callbacks only enqueue (a slow callback would stall the session), but for a box
query that the replies laid out in memory answer as they are (nothing committed since they were
brought up to date: ~1 ms for ten thousand cells, no hand-over to another thread); one writer
drains the estimate queue into transactions of up to ``batch_max``; one reader answers the
other queries from the query queue on its own database connection, and between queries brings the
replies up to date (this service's commits before their acknowledgement; another writer's on a
shared PostgreSQL database within ~50 ms) and lays out the ageing clock's next step; the main
thread publishes status.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections import Counter
from typing import Any, Optional

from pydantic_core import to_json

from soilocp.schemas import keys
from soilocp.schemas.map import WGS84, MapCellUpdate, MapRejection, MapStatus

from soilocp.services.map.config import MapServiceConfig
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.process import install_stop_handlers, open_session, watch_parent
from soilocp.map.store import MapStore, open_store
from soilocp.map.updater import MapUpdater

#: Rejections published per second at most (all are counted): a flood must not become a second flood.
MAX_REJECTIONS_PER_S = 50


def parse_query(parameters: str) -> tuple[str, tuple[float, float, float, float], Optional[int]]:
    """``frame=F;bbox=xmin,ymin,xmax,ymax[;limit=N]`` -> (frame, bbox, limit); ValueError says why.
    The frame defaults to wgs84 (bbox in lon/lat deg)."""
    params: dict[str, str] = {}
    for part in (parameters or "").split(";"):
        if part:
            k, _, v = part.partition("=")
            params[k.strip()] = v.strip()
    frame = params.get("frame", WGS84)
    if "bbox" not in params:
        raise ValueError("query needs bbox=xmin,ymin,xmax,ymax (and frame=NAME for a local frame)")
    try:
        box = tuple(float(q) for q in params["bbox"].split(","))
    except ValueError:
        raise ValueError(f"bbox={params['bbox']!r}: four numbers xmin,ymin,xmax,ymax") from None
    if len(box) != 4 or not all(abs(q) < 1e8 for q in box) or box[0] > box[2] or box[1] > box[3]:
        raise ValueError(f"bbox={params['bbox']!r}: four finite numbers with xmin <= xmax and ymin <= ymax")
    limit = int(params["limit"]) if "limit" in params else None
    return frame, box, limit  # type: ignore[return-value]


class MapService:
    def __init__(self, cfg: MapServiceConfig, log: JsonLog, store: Optional[MapStore] = None):
        self.cfg, self.log = cfg, log
        self.store = store or open_store(cfg.store, cfg.cells, cfg.fusion)
        self.updater = MapUpdater(self.store)
        self.inbox: queue.Queue = queue.Queue(maxsize=cfg.queue_size)
        self.queries: queue.Queue = queue.Queue(maxsize=256)
        self.received = self.applied = self.dropped = self.batches = 0
        self.skipped: Counter = Counter()
        self.rejected: Counter = Counter()
        self.stop = threading.Event()
        self.session = None
        self._pub_cells = self._pub_rejected = self._pub_status = None
        self._rej_window = (0.0, 0)
        self.failed = threading.Event()
        self._replies_lock = threading.Lock()  # the store's reply cache: one caller at a time
        self._dirty = threading.Event()  # a commit the replies have not read back yet
        self._dirty.set()
        self._n_cells = 0

    # --- callbacks (enqueue only) --------------------------------------------------------------
    def _on_estimate(self, sample) -> None:
        self.received += 1
        try:
            self.inbox.put_nowait((str(sample.key_expr), sample.payload.to_bytes(), time.time()))
        except queue.Full:
            self.dropped += 1

    def _on_query(self, query) -> None:
        # answered here, without a hand-over to the query worker, when the replies are laid out and
        # nothing was committed since (one slice per run of cells: ~1 ms for ten thousand cells)
        if not self._dirty.is_set() and self._replies_lock.acquire(blocking=False):
            try:
                if self._answer(query, ready_only=True):
                    return
            finally:
                self._replies_lock.release()
        try:
            self.queries.put_nowait(query)
        except queue.Full:
            query.reply_err("map service busy: too many queries waiting")

    def _on_status_query(self, query) -> None:
        try:
            query.reply(keys.map_key(self.cfg.map_id, "status"), self.status().model_dump_json())
        except Exception as exc:
            self.log.warning("status_reply_failed", error=str(exc)[:200])

    # --- worker threads ------------------------------------------------------------------------
    def _writer(self) -> None:
        cfg = self.cfg
        while not self.stop.is_set():
            try:
                first = self.inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            items = [first]
            deadline = time.monotonic() + cfg.batch_wait_s
            while len(items) < cfg.batch_max:
                try:
                    items.append(self.inbox.get_nowait())
                except queue.Empty:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    time.sleep(min(left, 0.005))
            try:
                res = self.updater.apply(items)
            except Exception as exc:  # the database failed: nothing of this batch was acknowledged
                self.log.error("commit_failed", error=f"{type(exc).__name__}: {exc}"[:500], estimates=len(items))
                self.failed.set()
                self.stop.set()
                return
            self._dirty.set()  # before the acknowledgement: a query after it must read this commit back
            self.batches += 1
            self.applied += sum(1 for _ in items) - len(res.refused) - sum(res.skipped.values())
            self.skipped.update(res.skipped)
            for r in res.refused:
                self.rejected[r.code] += 1
                self._publish_rejection(r)
            if res.cells:
                now = time.time()
                msg = MapCellUpdate(map_id=cfg.map_id, batch=self.batches, applied=res.applied,
                                    cells=self.store.cells_by_id(res.cells, now), time=now)
                self._pub_cells.put(msg.model_dump_json())

    def _publish_rejection(self, r) -> None:
        now = time.time()
        start, n = self._rej_window
        if now - start >= 1.0:
            start, n = now, 0
        n += 1
        self._rej_window = (start, n)
        if n <= 10 or self.rejected[r.code] % 1000 == 1:
            self.log.warning("estimate_rejected", key=r.key, code=r.code, field=r.field, message=r.message[:200])
        if n > MAX_REJECTIONS_PER_S:
            return
        self._pub_rejected.put(MapRejection(map_id=self.cfg.map_id, vehicle_id=r.vehicle_id, seq=r.seq, code=r.code,
                                            field=r.field, message=r.message, key=r.key,
                                            received_at=r.received_at).model_dump_json())

    def _reader(self) -> None:
        """The query worker: answers the queries the callback could not, and between queries takes in
        the commits and lays out the ageing clock's next step (:meth:`MapStore.prepare_replies`)."""
        while not self.stop.is_set():
            try:
                query = self.queries.get(timeout=0.05)
            except queue.Empty:
                query = None
            with self._replies_lock:
                self._dirty.clear()  # before reading: a commit landing meanwhile sets it again
                if query is not None:
                    self._answer(query, ready_only=False)
                if query is None or self.queries.empty():
                    try:
                        self.store.prepare_replies()
                    except Exception as exc:  # the next query tries again, and answers with the error
                        self._dirty.set()
                        self.log.warning("query_prepare_failed", error=f"{type(exc).__name__}: {exc}"[:300])

    def _answer(self, query, ready_only: bool) -> bool:
        """Reply to one box query (under ``_replies_lock``); False (nothing sent) when ``ready_only``
        and the replies are not laid out for it."""
        try:
            frame, box, limit = parse_query(str(query.selector.parameters))
            # the columns come from the store's own fusion (finite, positive by construction), written
            # as JSON from memory (soilocp.map.replies): MapQueryReply's fields, not re-validated per query
            got = self.store.query_json(frame, box, time.time(), limit or self.cfg.query_limit, ready_only=ready_only)
            if got is None:
                return False
            cols, _n, cut, aged_to = got
            head = to_json({"schema_version": 1, "map_id": self.cfg.map_id, "frame": frame, "bbox": box,
                            "truncated": cut, "time": aged_to})
            query.reply(keys.map_key(self.cfg.map_id, "query"), b"".join((head[:-1], b',"columns":', cols, b"}")))
        except ValueError as exc:
            query.reply_err(str(exc))
        except Exception as exc:
            self.log.error("query_failed", error=f"{type(exc).__name__}: {exc}"[:300])
            try:
                query.reply_err(f"query failed: {type(exc).__name__}")
            except Exception:
                pass
        query.drop()
        return True

    def status(self) -> MapStatus:
        return MapStatus(map_id=self.cfg.map_id, pid=os.getpid(), store=_public_url(self.store.url),
                         received=self.received, applied=self.applied, skipped=dict(self.skipped),
                         rejected=dict(self.rejected), dropped=self.dropped, batches=self.batches,
                         cells=self._cells_count(), queue_depth=self.inbox.qsize(), time=time.time())

    def _cells_count(self) -> int:
        return self._n_cells

    # --- run -----------------------------------------------------------------------------------
    def run(self) -> int:
        import zenoh

        cfg, log = self.cfg, self.log
        install_stop_handlers(self.stop, log)
        watch_parent(self.stop, log)
        session = open_session(cfg.mode, cfg.connect, cfg.listen, multicast=cfg.multicast, stop=self.stop, log=log,
                               retry_s=cfg.connect_retry_s)
        if session is None:
            return 0
        declared: list[Any] = []
        token = None
        self._n_cells = self.store.count_cells()
        threads = [threading.Thread(target=self._writer, name="map-writer", daemon=True),
                   threading.Thread(target=self._reader, name="map-reader", daemon=True)]
        try:
            mk = lambda tail: keys.map_key(cfg.map_id, tail)  # noqa: E731
            self._pub_cells = session.declare_publisher(mk("cells"), congestion_control=zenoh.CongestionControl.BLOCK)
            self._pub_rejected = session.declare_publisher(mk("rejected"))
            self._pub_status = session.declare_publisher(mk("status"))
            declared += [self._pub_cells, self._pub_rejected, self._pub_status]
            for t in threads:
                t.start()
            declared.append(session.declare_queryable(mk("query"), self._on_query))
            declared.append(session.declare_queryable(mk("status"), self._on_status_query))
            declared.append(session.declare_subscriber(keys.any_vehicle_soil(), self._on_estimate))
            with self._replies_lock:  # the replies laid out before the token says the service is here
                self._dirty.clear()  # before reading: a commit landing meanwhile sets it again
                try:
                    self.store.prepare_replies()
                except Exception as exc:  # the query worker tries again, and a query answers with the error
                    self._dirty.set()
                    log.warning("query_prepare_failed", error=f"{type(exc).__name__}: {exc}"[:300])
            token = session.liveliness().declare_token(mk("alive"))
            log.info("running", map_id=cfg.map_id, store=_public_url(self.store.url), cells=self._n_cells,
                     pid=os.getpid())
            next_status = 0.0
            while not self.stop.wait(0.05):
                now = time.time()
                if now >= next_status:
                    next_status = now + cfg.status_period_s
                    self._n_cells = self.store.count_cells()
                    self._pub_status.put(self.status().model_dump_json())
        finally:
            if token is not None:
                token.undeclare()
            for e in reversed(declared):
                try:
                    e.undeclare()
                except Exception:
                    pass
            self.stop.set()
            for t in threads:
                if t.is_alive():
                    t.join(2.0)
            session.close()
            log.info("stopped", received=self.received, applied=self.applied, rejected=dict(self.rejected),
                     dropped=self.dropped, batches=self.batches)
        return 1 if self.failed.is_set() else 0


def _public_url(url: str) -> str:
    from soilocp.map.store import _redact

    return _redact(url)


def run_map_service(cfg: MapServiceConfig) -> int:
    log = JsonLog("map", cfg.log_level)
    svc = MapService(cfg, log)
    try:
        return svc.run()
    finally:
        svc.store.close()
