"""Map cells as GeoJSON (RFC 7946): one Polygon feature per cell.  WGS84 cells are in (lon, lat);
cells of a local frame are in that frame's metres (not RFC 7946's WGS84: the collection's
``soilocp_frame`` names the frame), for planners and GIS tools that take a local CRS."""

from __future__ import annotations

from typing import Sequence

from soilocp.schemas.map import MapCell

from soilocp.map.cells import cell_polygon
from soilocp.model.ocp import ocp_from_soil_strength


def feature(c: MapCell) -> dict:
    o = ocp_from_soil_strength(c.K)
    return {
        "type": "Feature",
        "id": c.cell,
        "geometry": {"type": "Polygon", "coordinates": [[list(p) for p in cell_polygon(c.cell, c.frame)]]},
        "properties": {"cell": c.cell, "frame": c.frame, "K": c.K, "K_lo": c.K_lo, "K_hi": c.K_hi,
                       "log_k_std": c.log_k_std, "mu_T": o.mu_T, "S_T": o.S_T, "S_E": o.S_E, "count": c.count,
                       "last_seen": c.last_seen, "vehicles": list(c.vehicles)},
    }


def feature_collection(cells: Sequence[MapCell]) -> dict:
    frames = sorted({c.frame for c in cells})
    return {"type": "FeatureCollection", "soilocp_frame": frames[0] if len(frames) == 1 else frames,
            "features": [feature(c) for c in cells]}
