"""Map cells: H3 hexagons for WGS84 positions, squares for a named local frame.

* WGS84: the H3 cell (Uber's hexagonal hierarchical index, PyPI ``h3``) at ``h3_resolution``
  (12 by default: hexagons of ~307 m^2, edge ~9.4 m) that contains (lat, lon); its centre is
  reported as (lon, lat), the GeoJSON order.
* Local frame: the square of side ``cell_size`` m, [ix s, (ix + 1) s) x [iy s, (iy + 1) s),
  ix = floor(x / s); id ``<frame>/<s>/<ix>/<iy>`` (the size is part of the id, so two maps with
  different sizes never mix cells).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field

from soilocp.schemas.map import WGS84

#: H3 resolutions that make sense for soil under wheels (res 15 is ~1 m^2, res 9 ~0.1 km^2).
H3_MIN_RES, H3_MAX_RES = 7, 15


class CellConfig(BaseModel):
    """How the map cuts the ground into cells."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    cell_size: float = Field(5.0, ge=0.1, le=10_000, description="Square cell side in a local frame, m")
    h3_resolution: int = Field(12, ge=H3_MIN_RES, le=H3_MAX_RES, description="H3 resolution of WGS84 cells")


@dataclass(frozen=True)
class CellRef:
    """A cell: its id, frame and centre ((x, y) m, or (lon, lat) deg for WGS84)."""

    cell: str
    frame: str
    cx: float
    cy: float


class CellIndex:
    """Point -> cell for both kinds, with the centres cached (a vehicle stays in a cell for many samples)."""

    def __init__(self, config: Optional[CellConfig] = None):
        self.config = config or CellConfig()
        self._size = self.config.cell_size
        self._size_txt = f"{self._size:g}"
        self._res = self.config.h3_resolution
        self._h3 = None
        self._cache: dict[tuple, CellRef] = {}

    def local(self, frame: str, x: float, y: float) -> CellRef:
        s = self._size
        ix, iy = math.floor(x / s), math.floor(y / s)
        k = (frame, ix, iy)
        c = self._cache.get(k)
        if c is None:  # vehicles stay in a cell for hundreds of estimates: build each cell once
            if len(self._cache) > 200_000:
                self._cache.clear()
            c = self._cache[k] = CellRef(f"{frame}/{self._size_txt}/{ix}/{iy}", frame, (ix + 0.5) * s, (iy + 0.5) * s)
        return c

    def geo(self, lat: float, lon: float) -> CellRef:
        if self._h3 is None:
            import h3

            self._h3 = h3
        c = self._h3.latlng_to_cell(lat, lon, self._res)
        clat, clon = self._h3.cell_to_latlng(c)
        return CellRef(c, WGS84, clon, clat)


def cell_polygon(cell: str, frame: str) -> list[tuple[float, float]]:
    """The cell's boundary, closed ring: (lon, lat) for an H3 cell, (x, y) m for a square."""
    if frame == WGS84:
        import h3

        ring = [(lon, lat) for lat, lon in h3.cell_to_boundary(cell)]
    else:
        _f, size, ix, iy = cell.rsplit("/", 3)
        s, i, j = float(size), int(ix), int(iy)
        ring = [(i * s, j * s), ((i + 1) * s, j * s), ((i + 1) * s, (j + 1) * s), (i * s, (j + 1) * s)]
    return ring + [ring[0]]
