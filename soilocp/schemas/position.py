"""Where a vehicle is, and where a soil estimate was made: the optional position fields of the
sensor log and of the soil estimate (the fleet soil map's input, docs/map.md).

Two kinds of position, either or both:

* :class:`MapPosition`: x, y in metres in a named local map frame (REP-105 ``map``/``odom``: x
  east or forward-at-start, y left of x, z up), e.g. from ``nav_msgs/Odometry``;
* :class:`GeoPosition`: WGS84 latitude / longitude in degrees, e.g. from ``sensor_msgs/NavSatFix``.

``heading`` (optional in both) is the yaw of the body x axis in that frame, rad, counter-clockwise
from the frame's x axis (for WGS84: from east, ENU as REP-103): it places each wheel's contact
patch from the vehicle geometry; without it every patch is taken at the vehicle's position.
"""

from __future__ import annotations

import math
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field

FRAME_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
#: m: a local frame beyond +-10,000 km is a broken driver, not a large field.
MAX_MAP_COORD = 1.0e7
MAX_HEADING = 4.0 * math.pi  # rad: unwrapped headings of up to two turns either way are accepted

_Heading = Optional[float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class MapPosition(_Strict):
    """Position of the vehicle's CoM in a named local map frame."""

    frame: str = Field(pattern=FRAME_PATTERN, description="Name of the local map frame, [A-Za-z0-9_.-]{1,64}")
    x: float = Field(ge=-MAX_MAP_COORD, le=MAX_MAP_COORD, description="m, along the frame's x axis")
    y: float = Field(ge=-MAX_MAP_COORD, le=MAX_MAP_COORD, description="m, along the frame's y axis (left of x)")
    heading: _Heading = Field(
        default=None, ge=-MAX_HEADING, le=MAX_HEADING,
        description="Yaw of the body x axis, rad, counter-clockwise from the frame's x axis (null: unknown)")


class GeoPosition(_Strict):
    """WGS84 position of the vehicle's CoM (GNSS)."""

    latitude: float = Field(ge=-90.0, le=90.0, description="deg, WGS84")
    longitude: float = Field(ge=-180.0, le=180.0, description="deg, WGS84")
    heading: _Heading = Field(
        default=None, ge=-MAX_HEADING, le=MAX_HEADING,
        description="Yaw of the body x axis, rad, counter-clockwise from east (ENU; null: unknown)")


_X = Annotated[float, Field(ge=-MAX_MAP_COORD, le=MAX_MAP_COORD)]
_LAT = Annotated[float, Field(ge=-90.0, le=90.0)]
_LON = Annotated[float, Field(ge=-180.0, le=180.0)]
_WHEEL = Annotated[int, Field(ge=1, le=4)]


class EstimatePlace(_Strict):
    """Where a soil estimate was made: the contact patches of the wheels that informed it (the
    wheels whose slip/traction pairs updated K at this sample), in the local frame and/or WGS84."""

    wheels: tuple[_WHEEL, ...] = Field(min_length=1, max_length=4,
                                    description="Wheel numbers (1 LR, 2 LF, 3 RF, 4 RR) that informed the estimate")
    frame: Optional[str] = Field(default=None, pattern=FRAME_PATTERN, description="Local frame of xy (null: none)")
    xy: Optional[tuple[tuple[_X, _X], ...]] = Field(
        default=None, description="Contact patch per listed wheel, (x, y) m in ``frame``")
    latlon: Optional[tuple[tuple[_LAT, _LON], ...]] = Field(
        default=None, description="Contact patch per listed wheel, (latitude, longitude) deg WGS84")
