"""A field for the simulated fleet: soil strength as a function of position (rectangular regions of
known K in a named local frame), and the straight drives across it.

The simulator lays terrain out by distance along the path (:class:`soilocp.sim.scenarios.Scenario`);
a straight drive from a start pose crosses the regions in an order and over lengths that follow
from the geometry, so :func:`straight_drive` turns (field, start pose, length) into a Scenario
whose segments are exactly the regions the line crosses, and the simulator's true positions
(``simulate(..., start=StartPose(...))``) are on that line.  :meth:`Field.soil_at` is then the
truth a fleet map is judged against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from soilocp.schemas.position import FRAME_PATTERN

from soilocp.model.constants import REFERENCE_SOILS
from soilocp.sim.scenarios import Scenario, Segment


@dataclass(frozen=True)
class StartPose:
    """Where a simulated drive starts: CoM (x, y) m in ``frame``, heading rad (counter-clockwise
    from the frame's x axis).  ``geo_origin`` (lat, lon deg) places the frame's origin on WGS84,
    with x east and y north: the samples then carry latitude/longitude too."""

    frame: str = "field"
    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    geo_origin: Optional[tuple[float, float]] = None

    def __post_init__(self) -> None:
        import re

        if not re.match(FRAME_PATTERN, self.frame):
            raise ValueError(f"start frame {self.frame!r} must match {FRAME_PATTERN}")
        for name in ("x", "y", "heading"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"start {name} must be finite, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class Region:
    """An axis-aligned rectangle [x0, x1) x [y0, y1) of one soil."""

    soil_class: str
    x0: float
    x1: float
    y0: float
    y1: float
    soil_strength: float = 0.0  # 0: the reference K of soil_class

    @property
    def k(self) -> float:
        return self.soil_strength or REFERENCE_SOILS[self.soil_class]

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x < self.x1 and self.y0 <= y < self.y1


@dataclass(frozen=True)
class Field:
    """Soil by position: the first region that contains a point, else ``background``."""

    regions: tuple[Region, ...]
    background: str = "EST"
    frame: str = "field"
    extra: dict = field(default_factory=dict)

    def soil_at(self, x: float, y: float) -> tuple[str, float]:
        for r in self.regions:
            if r.contains(x, y):
                return r.soil_class, r.k
        return self.background, REFERENCE_SOILS[self.background]


def straight_drive(fld: Field, start: StartPose, length: float, *, name: str = "field-drive", speed: float = 1.0,
                   step: float = 0.05, **scenario_kw) -> Scenario:
    """The Scenario of a straight drive of ``length`` m from ``start`` across ``fld``: the soil
    along the line, sampled every ``step`` m, as segments by distance (the simulator's terrain)."""
    if not (length > 0 and step > 0):
        raise ValueError(f"length and step must be > 0 m, got {length!r}, {step!r}")
    c, s = math.cos(start.heading), math.sin(start.heading)
    n = int(math.ceil(length / step))
    segs: list[list] = []
    for i in range(n + 1):
        d = i * step
        soil, k = fld.soil_at(start.x + c * d, start.y + s * d)
        if segs and segs[-1][0] == soil and segs[-1][1] == k:
            continue
        if segs:
            segs[-1][3] = d - segs[-1][2]
        segs.append([soil, k, d, math.inf])
    segments = tuple(Segment(soil, k, length=ln) for soil, k, _d, ln in segs)
    return Scenario(name, f"straight drive of {length:g} m across a field from ({start.x:g}, {start.y:g})",
                    segments, speed=speed, duration=scenario_kw.pop("duration", length / speed), **scenario_kw)


def true_position(start: StartPose, x: float, y: float, heading: float) -> dict:
    """The sensor-sample position fields of a simulated CoM at (x, y) m, heading rad, in
    ``start.frame``; with ``start.geo_origin`` also WGS84 (x east, y north on the local tangent
    plane, :func:`soilocp.map.place.local_to_geo`)."""
    from soilocp.schemas.position import GeoPosition, MapPosition

    out: dict = {"position": MapPosition(frame=start.frame, x=x, y=y, heading=heading)}
    if start.geo_origin is not None:
        from soilocp.map.place import local_to_geo

        lat, lon = local_to_geo(start.geo_origin, x, y)
        out["geo"] = GeoPosition(latitude=lat, longitude=lon, heading=heading)
    return out


#: Environment: the synthetic vehicle's start pose (``soilocp run --synthetic`` / ``soilocp service
#: vehicle --scenario``), e.g. ``field:0,7.5,0`` or ``field:0,7.5,0@47.0,8.0``: its samples then carry positions.
ENV_START_POSE = "SOILOCP_START_POSE"


def parse_start_pose(text: str) -> StartPose:
    """``FRAME:X,Y[,HEADING][@LAT,LON]`` -> StartPose (m, m, rad; the WGS84 origin of the frame).
    ValueError says what is wrong."""
    frame, sep, rest = str(text).partition(":")
    if not sep:
        raise ValueError(f"start pose {text!r}: expected FRAME:X,Y[,HEADING][@LAT,LON], e.g. field:0,7.5,0")
    pose, _, geo = rest.partition("@")
    try:
        nums = [float(q) for q in pose.split(",")]
        origin = tuple(float(q) for q in geo.split(",")) if geo else None
    except ValueError:
        raise ValueError(f"start pose {text!r}: X, Y, HEADING and LAT, LON must be numbers") from None
    if len(nums) not in (2, 3) or (origin is not None and len(origin) != 2):
        raise ValueError(f"start pose {text!r}: expected FRAME:X,Y[,HEADING][@LAT,LON]")
    if origin is not None and not (-90 <= origin[0] <= 90 and -180 <= origin[1] <= 180):
        raise ValueError(f"start pose {text!r}: the origin must be a WGS84 latitude, longitude")
    return StartPose(frame=frame, x=nums[0], y=nums[1], heading=nums[2] if len(nums) == 3 else 0.0, geo_origin=origin)
