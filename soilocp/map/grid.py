"""A local frame's square cells as a raster, for Foxglove's 3D panel and planners
(``foxglove.Grid``, :func:`soilocp.export.channels.map_grid_message`).

Row-major from the grid's corner (the lower-left cell's corner, min ix s, min iy s): cell (ix, iy)
is column ix - ix0 of row iy - iy0.  Fields per cell, float32: mu_T (max traction coefficient from
K, eq. 8 of the paper via :func:`soilocp.model.ocp.ocp_from_soil_strength`), K, K_lo, K_hi,
log_k_std; NaN where the map holds no cell.  WGS84 (H3) cells are not a raster: they stay GeoJSON."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from soilocp.schemas.map import WGS84, MapCell

from soilocp.model.ocp import ocp_from_soil_strength

FIELDS = ("mu_T", "K", "K_lo", "K_hi", "log_k_std")


@dataclass(frozen=True)
class MapRaster:
    frame: str
    cell_size: float
    origin: tuple[float, float]  # the corner of cell (ix0, iy0), m in the frame
    values: np.ndarray  # (rows, columns, len(FIELDS)) float32, NaN where no cell


def raster(cells: Sequence[MapCell]) -> MapRaster:
    """The square cells of one local frame as a raster (ValueError for WGS84, mixed frames or sizes)."""
    frames = {c.frame for c in cells}
    if len(frames) != 1 or WGS84 in frames:
        raise ValueError(f"a grid needs the square cells of one local frame, got frames {sorted(frames)}")
    ids = [c.cell.rsplit("/", 3) for c in cells]  # <frame>/<size>/<ix>/<iy>
    sizes = {float(i[1]) for i in ids}
    if len(sizes) != 1:
        raise ValueError(f"cells of several sizes {sorted(sizes)}")
    s = sizes.pop()
    ix = np.array([int(i[2]) for i in ids])
    iy = np.array([int(i[3]) for i in ids])
    ix0, iy0 = int(ix.min()), int(iy.min())
    out = np.full((int(iy.max()) - iy0 + 1, int(ix.max()) - ix0 + 1, len(FIELDS)), np.nan, dtype=np.float32)
    for c, x, y in zip(cells, ix - ix0, iy - iy0):
        out[y, x] = (ocp_from_soil_strength(c.K).mu_T, c.K, c.K_lo, c.K_hi, c.log_k_std)
    return MapRaster(frames.pop(), s, (ix0 * s, iy0 * s), out)
