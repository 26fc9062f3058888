"""The map back to the vehicle (opt-in): when the vehicle's front axle enters a mapped cell, its
soil belief starts over from the map's K for that cell, with the map's band
(:meth:`soilocp.estimation.soil_strength.SoilBank.start_belief`).  The belief then learns from the
vehicle's own wheels as usual; the map only replaces "nothing known" (or the last soil) at the
moment the ground may have changed.  Until the rear axle has left the ground the front axle just
left, the wheels whose contact patch is still there do not inform that belief: it is the new
cell's, and they stand on another soil.  The estimator takes a vehicle's prior as an input of its
step (:class:`soilocp.estimation.estimator.Estimator`, ``priors``), on every path.  docs/map.md measures what it buys."""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from soilocp.schemas.map import WGS84, MapCell
from soilocp.schemas.pipeline import ObserverOutput

from soilocp.map.cells import CellConfig, CellIndex
from soilocp.map.place import wgs84_radii, wheel_offsets
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams


_M_PER_DEG = 111_320.0  # metres per degree of latitude: distances for rearm_m in WGS84


class MapPrior:
    """``prior(obs) -> (ln K, 1-sigma of ln K)`` when the front axle enters a mapped cell, else None;
    :meth:`informing` says which wheels may inform the belief now.

    The front axle meets a new soil first, so the belief starts from the map's K there at once.
    The rear wheels stay on the cell just left for one wheelbase more: their slip and traction are
    of that soil, not the one the belief now stands for, so until they leave it they do not inform
    it (:meth:`informing`).  Letting them in pulled the one belief back to the old soil (grass ->
    firm in docs/map.md: 1.05 s with the map against 1.08 s without); starting the belief again
    when the rear axle enters instead won that crossing (0.44 s) but reported one sample 11 % low
    at each restart, which lost the sand -> grass one.
    Coming back into the cell just left, within ``rearm_m`` of where it was left, is no new ground:
    a front axle driving along a cell border wanders across it, and restarting the belief at each
    crossing would throw away what the wheels learnt (seen live, docs/map.md §4).
    ``cells``: the map around the route (a box query: :func:`soilocp.services.map.client.query_map` or
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
        self.vehicle = vehicle
        self._behind: Optional[str] = None  # the cell the front axle left when the belief took the map's
        self.withheld = 0  # wheel-samples kept out of the belief while on the cell left behind

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
        behind, self.current, self._behind = self.current, cell, None
        if left is not None and left[0] == cell and math.dist(left[1], here) <= self.rearm_m:
            return None  # back over the border it just crossed: not new ground
        c = self.cells.get(cell)
        if c is None:
            return None
        self.entered += 1
        self._behind = behind
        return math.log(c.K), c.log_k_std

    def informing(self, obs: ObserverOutput) -> Optional[np.ndarray]:
        """Which wheels (4 bools, wheel 1..4 order) may inform the belief now, or None: all.

        After the belief took the map's K for the cell the front axle entered, a wheel whose
        contact patch (:mod:`soilocp.map.place`: p_CoM + R(heading) (x_i, y_i)) is still in the
        cell the front axle left measures that soil, not this one: False, until no wheel is there
        (then None for good, until the next cell taken from the map).  Without a heading the patches
        are unknown: None."""
        if self._behind is None:
            return None
        p, g = obs.position, obs.geo
        if p is not None and p.heading is not None:
            cells = [self.index.local(p.frame, p.x + dx, p.y + dy).cell
                     for dx, dy in wheel_offsets(self.vehicle, p.heading, (1, 2, 3, 4))]
        elif p is None and g is not None and g.heading is not None:
            m, n = wgs84_radii(g.latitude)
            k_lon = 1.0 / (n * max(math.cos(math.radians(g.latitude)), 1e-9))
            cells = [self.index.geo(g.latitude + math.degrees(dn / m), g.longitude + math.degrees(de * k_lon)).cell
                     for de, dn in wheel_offsets(self.vehicle, g.heading, (1, 2, 3, 4))]
        else:
            return None
        on = np.array([c != self._behind for c in cells])
        if on.all():
            self._behind = None
            return None
        self.withheld += int((~on).sum())
        return on


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
