"""The map back to the vehicle (opt-in): when the vehicle's front axle enters a mapped cell, its
soil belief starts over from the map's K for that cell, with the map's band
(:meth:`soilocp.estimation.soil_strength.SoilBank.start_belief`).  The belief then learns from the
vehicle's own wheels as usual; the map only replaces "nothing known" (or the last soil) at the
moment the ground may have changed.  docs/map.md measures what it buys."""

from __future__ import annotations

import math
from typing import Optional, Sequence

from schemas.map import WGS84, MapCell
from schemas.pipeline import ObserverOutput

from soilocp.map.cells import CellConfig, CellIndex
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams


class MapPrior:
    """``prior(obs) -> (ln K, 1-sigma of ln K)`` when the front axle enters a mapped cell, else None.

    The front axle meets a new soil first, so the belief starts from the map's K there at once.
    (The rear wheels, on the old soil for one wheelbase more, then pull the one belief back: on the
    grass -> firm crossing of docs/map.md this costs the map its lead.  Starting again when the rear
    axle enters was tried: it wins that crossing, 0.44 s against 1.05 s, but the estimator reports
    one sample 11 % low at each such restart, which loses the sand -> grass one.)
    ``cells``: the map around the route (a box query: :func:`services.map.client.query_map` or
    :meth:`MapStore.query_box`).  ``min_count``: a cell seen by fewer estimates is not trusted."""

    def __init__(self, cells: Sequence[MapCell], cell_config: Optional[CellConfig] = None,
                 vehicle: VehicleParams = DEFAULT_VEHICLE, min_count: int = 1):
        self.index = CellIndex(cell_config or CellConfig())
        self.cells = {c.cell: c for c in cells if c.count >= min_count}
        self.ahead = vehicle.b  # CoM to the front axle, m
        self.current: Optional[str] = None
        self.entered = 0  # priors given

    def __call__(self, obs: ObserverOutput) -> Optional[tuple[float, float]]:
        p, g = obs.position, obs.geo
        if p is not None:
            h = p.heading
            x, y = (p.x, p.y) if h is None else (p.x + self.ahead * math.cos(h), p.y + self.ahead * math.sin(h))
            cell = self.index.local(p.frame, x, y).cell
        elif g is not None:
            cell = self.index.geo(g.latitude, g.longitude).cell
        else:
            return None
        if cell == self.current:
            return None
        self.current = cell
        c = self.cells.get(cell)
        if c is None:
            return None
        self.entered += 1
        return math.log(c.K), c.log_k_std


def map_prior_from_store(url: str, frame: str, bbox, now: float, **kw) -> MapPrior:
    """A :class:`MapPrior` from the cells of a store in a box (offline use)."""
    from soilocp.map.store import open_store

    st = open_store(url)
    try:
        cells, _ = st.query_box(frame, bbox, now)
        return MapPrior(cells, st.cell_config, **kw)
    finally:
        st.close()


__all__ = ["MapPrior", "map_prior_from_store", "WGS84"]
