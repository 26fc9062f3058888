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


_M_PER_DEG = 111_320.0  # metres per degree of latitude: distances for rearm_m in WGS84


class MapPrior:
    """``prior(obs) -> (ln K, 1-sigma of ln K)`` when the front axle enters a mapped cell, else None.

    The front axle meets a new soil first, so the belief starts from the map's K there at once.
    (The rear wheels, on the old soil for one wheelbase more, then pull the one belief back: on the
    grass -> firm crossing of docs/map.md this costs the map its lead.  Starting again when the rear
    axle enters was tried: it wins that crossing, 0.44 s against 1.05 s, but the estimator reports
    one sample 11 % low at each such restart, which loses the sand -> grass one.)
    Coming back into the cell just left, within ``rearm_m`` of where it was left, is no new ground:
    a front axle driving along a cell border wanders across it, and restarting the belief at each
    crossing would throw away what the wheels learnt (seen live, docs/map.md §4).
    ``cells``: the map around the route (a box query: :func:`services.map.client.query_map` or
    :meth:`MapStore.query_box`).  ``min_count``: a cell seen by fewer estimates is not trusted."""

    def __init__(self, cells: Sequence[MapCell], cell_config: Optional[CellConfig] = None,
                 vehicle: VehicleParams = DEFAULT_VEHICLE, min_count: int = 1, rearm_m: float = 2.0):
        self.index = CellIndex(cell_config or CellConfig())
        self.min_count = min_count
        self.cells = {c.cell: c for c in cells if c.count >= min_count}
        self.ahead = vehicle.b  # CoM to the front axle, m
        self.current: Optional[str] = None
        self.rearm_m = rearm_m
        self._left: Optional[tuple[str, tuple[float, float]]] = None  # the cell just left and where
        self.entered = 0  # priors given

    def update_cells(self, cells: Sequence[MapCell]) -> None:
        """Replace the cells (a newer answer of the map around the vehicle); one assignment, so a
        thread may call it while another steps the estimator.  The cell the vehicle is in is not
        entered again."""
        self.cells = {c.cell: c for c in cells if c.count >= self.min_count}

    def __call__(self, obs: ObserverOutput) -> Optional[tuple[float, float]]:
        p, g = obs.position, obs.geo
        if p is not None:
            h = p.heading
            x, y = (p.x, p.y) if h is None else (p.x + self.ahead * math.cos(h), p.y + self.ahead * math.sin(h))
            cell = self.index.local(p.frame, x, y).cell
            here = (x, y)
        elif g is not None:
            cell = self.index.geo(g.latitude, g.longitude).cell
            here = (g.longitude * _M_PER_DEG * math.cos(math.radians(g.latitude)), g.latitude * _M_PER_DEG)
        else:
            return None
        if cell == self.current:
            return None
        left, self._left = self._left, (self.current, here) if self.current is not None else None
        self.current = cell
        if left is not None and left[0] == cell and math.dist(left[1], here) <= self.rearm_m:
            return None  # back over the border it just crossed: not new ground
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
