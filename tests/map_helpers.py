"""Soil estimates for the map tests, made the way the soil stage makes them."""

from __future__ import annotations

import math
from typing import Optional, Sequence

from soilocp.schemas.pipeline import SoilEstimate
from soilocp.schemas.position import EstimatePlace


def estimate(vid: str, seq: int, k: Optional[float], log_k_std: Optional[float] = 0.1,
             xy: Optional[Sequence[tuple[float, float]]] = ((1.0, 1.0),), *, status: str = "ok", frame: str = "f",
             latlon: Optional[Sequence[tuple[float, float]]] = None, stamp: Optional[float] = None) -> SoilEstimate:
    pts = xy if xy is not None else latlon
    where = None
    if pts is not None:
        where = EstimatePlace(wheels=tuple(range(1, len(pts) + 1)), frame=frame if xy is not None else None,
                              xy=tuple(xy) if xy is not None else None, latlon=tuple(latlon) if latlon else None)
    return SoilEstimate(
        vehicle_id=vid, seq=seq, stamp=seq / 100.0 if stamp is None else stamp, slip=(0.1,) * 4,
        informative=(True,) * 4, soil_strength=k, soil_strength_std=None if k is None else k * (log_k_std or 0),
        log_k_std=log_k_std, soil_class="sand" if k is not None else None,
        soil_class_confidence=0.9 if k is not None else None, status=status, reason="", last_update_stamp=None,
        mu=(0.3,) * 4, where=where)


def item(e: SoilEstimate | bytes, key_vid: Optional[str] = None, t: float = 1_800_000_000.0):
    """(key, payload, received_at) as the map service queues it."""
    from soilocp.schemas import keys

    if isinstance(e, SoilEstimate):
        return keys.soil(key_vid or e.vehicle_id), e.model_dump_json().encode(), t
    return keys.soil(key_vid or "rover1"), e, t


def ln(x: float) -> float:
    return math.log(x)
