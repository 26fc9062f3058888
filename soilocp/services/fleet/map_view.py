"""The dashboard's map view: the fleet soil map's cells (asked of a map service over Zenoh) with
their polygons, and each vehicle's track (from the places its soil estimates carry).

Tracks: a subscriber on ``soilocp/*/soil`` whose callback only queues the payload (bounded, drops
counted); a worker parses each estimate's place and keeps one point per ``step_m`` moved (the
centroid of the informing wheels' patches), at most ``max_points`` per vehicle."""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections import deque
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.schemas.map import WGS84


class TrackRecorder:
    def __init__(self, session, *, step_m: float = 0.5, max_points: int = 5000, queue_size: int = 20000):
        self.session, self.step_m, self.max_points = session, step_m, max_points
        self.inbox: queue.Queue = queue.Queue(maxsize=queue_size)
        self.tracks: dict[tuple[str, str], deque] = {}  # (vehicle, frame) -> points
        self.dropped = 0
        self.lock = threading.Lock()
        self.stop_event = threading.Event()
        self._sub = None
        self._thread = threading.Thread(target=self._run, name="map-tracks", daemon=True)

    def start(self) -> "TrackRecorder":
        self._thread.start()
        self._sub = self.session.declare_subscriber(keys.any_vehicle_soil(), self._on_sample)
        return self

    def _on_sample(self, sample) -> None:
        try:
            self.inbox.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while not self.stop_event.is_set():
            try:
                key, payload = self.inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                self.add(keys.split_key(key)[0], json.loads(payload).get("where"))
            except (ValueError, AttributeError, TypeError):
                continue  # the map service refuses and counts bad estimates; a track just skips them

    def add(self, vid: str, where: Optional[dict]) -> None:
        if not where:
            return
        pts = []
        if where.get("xy") and where.get("frame"):
            pts.append((where["frame"], where["xy"], False))
        if where.get("latlon"):
            pts.append((WGS84, where["latlon"], True))
        for frame, ps, geo in pts:
            n = len(ps)
            a, b = sum(p[0] for p in ps) / n, sum(p[1] for p in ps) / n
            point = (b, a) if geo else (a, b)  # (lon, lat) for WGS84, as the cells' centres
            with self.lock:
                tr = self.tracks.setdefault((vid, frame), deque(maxlen=self.max_points))
                if tr:
                    last = tr[-1]
                    d = math.hypot(point[0] - last[0], point[1] - last[1])
                    if geo:
                        d *= 111_000.0  # degrees -> m, good enough to thin a track
                    if d < self.step_m:
                        continue
                tr.append(point)

    def view(self, frame: str) -> dict[str, list]:
        with self.lock:
            return {vid: [list(p) for p in tr] for (vid, f), tr in self.tracks.items() if f == frame}

    def stop(self) -> None:
        self.stop_event.set()
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception:
                pass
        self._thread.join(2.0)


def map_view(session, tracks: Optional[TrackRecorder], map_id: str, frame: str, bbox, timeout: float = 3.0
             ) -> dict[str, Any]:
    """What the map page draws: cells (polygon, K, band, count, vehicles) and tracks, or an error."""
    from soilocp.services.map.client import query_map
    from soilocp.map.cells import cell_polygon

    out: dict[str, Any] = {"time": time.time(), "map_id": map_id, "frame": frame, "bbox": list(bbox), "cells": [],
                           "tracks": tracks.view(frame) if tracks is not None else {}, "error": None}
    if session is None:
        out["error"] = "not connected to the router yet"
        return out
    try:
        rep = query_map([], map_id, frame, bbox, timeout, session=session)
    except RuntimeError as exc:
        out["error"] = str(exc)
        return out
    out["cells"] = [{"cell": c.cell, "polygon": cell_polygon(c.cell, c.frame), "K": c.K, "K_lo": c.K_lo,
                     "K_hi": c.K_hi, "log_k_std": c.log_k_std, "count": c.count, "vehicles": c.vehicles,
                     "age_s": max(0.0, out["time"] - c.last_seen)} for c in rep.cells]
    out["truncated"] = rep.truncated
    return out
