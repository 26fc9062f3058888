"""The cells of a fleet soil map around each vehicle, for a service that steps soil beliefs from a
map prior (``map_prior`` in its config, or ``SOILOCP_MAP_PRIOR=<map id>``; docs/map.md §4): the
soil-strength service (:mod:`soilocp.services.stages.soil_strength`) and the batched one
(:mod:`soilocp.services.stages.batch`).

The library's :class:`soilocp.map.prior.MapPrior` decides when the vehicle enters a mapped cell and
hands the estimator the map's K and band (``Estimator(config, n, priors)``, as the offline path
``soilocp estimate --map-prior``).  :class:`MapPriorFeed` only keeps the prior's cells: a thread asks the map service
(``soilmap/<map_id>/query``, :func:`soilocp.services.map.client.query_map`) for the box around the
vehicle's last position, never the worker, which does not wait for the network.  Counted in the
health detail: ``map_prior_entered`` (priors given), ``map_prior_cells``, ``map_prior_queries``,
``map_prior_failures``."""

from __future__ import annotations

import math
import threading
import time
from typing import Optional

_M_PER_DEG = 111_320.0  # metres per degree of latitude (and of longitude at the equator)


class MapPriorFeed:
    """Each vehicle's :class:`MapPrior` and the map's cells around it, kept up to date by a thread
    of its own; for any service that steps soil beliefs (the soil-strength service, the batched
    one).  ``owner``: the service (its ``session``, ``stop_event``, ``counters``, ``log``)."""

    def __init__(self, owner, mp, vehicle_ids, vehicle):
        from soilocp.map.cells import CellConfig
        from soilocp.map.prior import MapPrior

        self.owner, self.mp = owner, mp
        cells = CellConfig(cell_size=mp.cell_size, h3_resolution=mp.h3_resolution)
        self.priors = {vid: MapPrior([], cells, vehicle=vehicle, min_count=mp.min_count) for vid in vehicle_ids}
        self._where: dict[str, tuple] = {}  # vehicle -> (frame, x, y) of its last position (frame "wgs84": lon, lat)
        self._asked: dict[str, tuple] = {}  # vehicle -> (frame, x, y, wall time) of the last box asked
        self._wake = threading.Event()
        self._thread: Optional[threading.Thread] = None
        for vid in vehicle_ids:
            owner.counters[vid].detail.update(map_prior_entered=0, map_prior_cells=0, map_prior_queries=0,
                                              map_prior_failures=0)
        owner.log.info("map_prior", map_id=mp.map_id, radius_m=mp.radius_m)

    def saw(self, vehicle_id: str, message) -> None:
        """A message with the vehicle's position (``position`` / ``geo``): ask for its box when due."""
        p, g = message.position, message.geo
        where = (p.frame, p.x, p.y) if p is not None else ("wgs84", g.longitude, g.latitude) if g is not None else None
        if where is not None:
            self._where[vehicle_id] = where
            if self._due(vehicle_id, where):
                self._start()
                self._wake.set()

    def count(self, vehicle_id: str, seq: int, before: int) -> None:
        """After a step: count and log the priors given since ``before`` (``prior.entered``)."""
        prior = self.priors[vehicle_id]
        if prior.entered == before:
            return
        self.owner.counters[vehicle_id].detail["map_prior_entered"] = prior.entered
        if prior.entered <= 20 or prior.entered % 100 == 0:
            self.owner.log.info("map_prior_used", vehicle_id=vehicle_id, seq=seq, cell=prior.current,
                                K=getattr(prior.cells.get(prior.current), "K", None), entered=prior.entered)

    def _due(self, vid: str, where: tuple) -> bool:
        last = self._asked.get(vid)
        if last is None or last[0] != where[0]:
            return True
        half = self._half_sides(where)
        moved = abs(where[1] - last[1]) > half[0] / 2 or abs(where[2] - last[2]) > half[1] / 2
        return moved or time.time() - last[3] > self.mp.refresh_s

    def _half_sides(self, where: tuple) -> tuple[float, float]:
        r = self.mp.radius_m
        if where[0] != "wgs84":
            return r, r
        return r / (_M_PER_DEG * max(0.01, math.cos(math.radians(where[2])))), r / _M_PER_DEG

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._asker, name="map-prior", daemon=True)
            self._thread.start()

    def _asker(self) -> None:
        """Ask the map for the box around each vehicle that is due (on this thread, not the worker's)."""
        from soilocp.services.map.client import query_map

        owner = self.owner
        while not owner.stop_event.is_set():
            self._wake.wait(1.0)
            self._wake.clear()
            for vid, where in list(self._where.items()):
                if not self._due(vid, where):
                    continue
                self._asked[vid] = (*where, time.time())
                hx, hy = self._half_sides(where)
                box = (where[1] - hx, where[2] - hy, where[1] + hx, where[2] + hy)
                c = owner.counters[vid]
                try:
                    reply = query_map([], self.mp.map_id, where[0], box, self.mp.timeout_s, session=owner.session)
                except Exception as exc:  # no map service, a refusal: the belief starts as without a map
                    c.detail["map_prior_failures"] = c.detail.get("map_prior_failures", 0) + 1
                    if c.detail["map_prior_failures"] <= 10:
                        owner.log.warning("map_prior_query_failed", vehicle_id=vid, error=str(exc)[:300])
                    continue
                cells = reply.cells
                self.priors[vid].update_cells(cells)
                c.detail["map_prior_queries"] = c.detail.get("map_prior_queries", 0) + 1
                c.detail["map_prior_cells"] = len(self.priors[vid].cells)
                owner.log.info("map_prior_cells", vehicle_id=vid, frame=where[0], cells=len(cells),
                               truncated=reply.truncated)
