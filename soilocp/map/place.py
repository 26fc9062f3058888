"""Contact patches: where each wheel touches the ground, from the vehicle's position, heading and
geometry (:attr:`VehicleParams.wheel_x` / ``wheel_y``, wheels 1 LR, 2 LF, 3 RF, 4 RR).

Patch of wheel i in the map frame (planar rigid-body transform, yaw ``heading`` counter-clockwise
from the frame's x axis)::

    p_i = p_CoM + R(heading) (x_i, y_i)

For WGS84 the same east/north offset is turned into degrees on the local tangent plane with the
WGS84 radii of curvature (meridional M, prime vertical N at the latitude): dlat = dn / M,
dlon = de / (N cos(lat)); at wheelbase offsets (< 1 m) the error is below a micrometre.
Without a heading every patch is the CoM position (the offsets are unknown).
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

from soilocp.schemas.position import EstimatePlace, GeoPosition, MapPosition

from soilocp.model.vehicle import VehicleParams

WGS84_A = 6378137.0  # m, semi-major axis
WGS84_E2 = 6.69437999014e-3  # first eccentricity squared


def wgs84_radii(latitude_deg: float) -> tuple[float, float]:
    """Meridional (M) and prime-vertical (N) radii of curvature of WGS84 at a latitude, m."""
    s = math.sin(math.radians(latitude_deg))
    w = 1.0 - WGS84_E2 * s * s
    n = WGS84_A / math.sqrt(w)
    return n * (1.0 - WGS84_E2) / w, n


def wheel_offsets(vehicle: VehicleParams, heading: Optional[float], wheels: Sequence[int]) -> list[tuple[float, float]]:
    """Offsets (m) of the listed wheels' contact patches from the CoM, rotated into the map frame
    by ``heading`` (rad); all (0, 0) when the heading is unknown."""
    if heading is None:
        return [(0.0, 0.0)] * len(wheels)
    c, s = math.cos(heading), math.sin(heading)
    xs, ys = vehicle.wheel_x, vehicle.wheel_y
    return [(c * xs[w - 1] - s * ys[w - 1], s * xs[w - 1] + c * ys[w - 1]) for w in wheels]


def estimate_place(vehicle: VehicleParams, position: Optional[MapPosition], geo: Optional[GeoPosition],
                   used: Sequence[bool]) -> Optional[EstimatePlace]:
    """Where an estimate was made: the contact patches of the wheels flagged in ``used`` (4 bools,
    the wheels that updated K at this sample).  None when no wheel informed it or there is no
    position."""
    wheels = tuple(i + 1 for i, u in enumerate(used) if u)
    if not wheels or (position is None and geo is None):
        return None
    xy = latlon = None
    frame = None
    if position is not None:
        frame = position.frame
        xy = tuple((position.x + dx, position.y + dy) for dx, dy in wheel_offsets(vehicle, position.heading, wheels))
    if geo is not None:
        m, n = wgs84_radii(geo.latitude)
        k_lon = 1.0 / (n * max(math.cos(math.radians(geo.latitude)), 1e-9))
        latlon = tuple((geo.latitude + math.degrees(dn / m), geo.longitude + math.degrees(de * k_lon))
                       for de, dn in wheel_offsets(vehicle, geo.heading, wheels))
    return EstimatePlace(wheels=wheels, frame=frame, xy=xy, latlon=latlon)


def local_to_geo(origin: tuple[float, float], east: float, north: float) -> tuple[float, float]:
    """(lat, lon) deg of a point ``east``, ``north`` m from ``origin`` (lat, lon) on the local tangent
    plane (WGS84 radii at the origin; for fields of a few hundred metres the plane's error is
    d^2 / 2R, millimetres)."""
    lat0, lon0 = origin
    m, n = wgs84_radii(lat0)
    return lat0 + math.degrees(north / m), lon0 + math.degrees(east / (n * math.cos(math.radians(lat0))))


def geo_to_local(origin: tuple[float, float], lat: float, lon: float) -> tuple[float, float]:
    """Inverse of :func:`local_to_geo`: (east, north) m of (lat, lon) from ``origin``."""
    lat0, lon0 = origin
    m, n = wgs84_radii(lat0)
    return math.radians(lon - lon0) * n * math.cos(math.radians(lat0)), math.radians(lat - lat0) * m
