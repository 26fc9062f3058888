"""The raw sensor sample: the public sensor-log contract (JSON Lines, one object per sample).

Drivers of real robots write it; ``soilocp estimate`` reads it; the gateway validates it on
``soilocp/<vehicle_id>/sensors/raw``.  Its keys are exactly those below (no extras, no version
field: the contract is versioned by :data:`SENSOR_SCHEMA_ID`).
"""

from __future__ import annotations

import math
import reprlib
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError

from soilocp.schemas.keys import VEHICLE_ID_PATTERN
from soilocp.schemas.position import GeoPosition, MapPosition

SENSOR_SCHEMA_ID = "soilocp.sensor_sample/1"

# Plausibility limits: beyond these a value is a broken driver, not a rover on rough ground.
MAX_SPECIFIC_FORCE = 200.0  # m/s^2, ~20 g
MAX_ANGLE = math.pi / 2  # rad; a rover past vertical is not driving
MAX_YAW_RATE = 20.0  # rad/s
MAX_WHEEL_SPEED = 1000.0  # rad/s
MAX_WHEEL_TORQUE = 10_000.0  # N m
MAX_GROUND_SPEED = 100.0  # m/s

VehicleId = Annotated[
    str,
    Field(
        pattern=VEHICLE_ID_PATTERN,
        description="Vehicle id, [A-Za-z0-9_-]{1,64}; part of every Zenoh key, so no '/', '*', '@', '$' or '?'",
    ),
]

_SF = Annotated[float, Field(ge=-MAX_SPECIFIC_FORCE, le=MAX_SPECIFIC_FORCE)]
_WS = Annotated[float, Field(ge=-MAX_WHEEL_SPEED, le=MAX_WHEEL_SPEED)]
_WT = Annotated[float, Field(ge=-MAX_WHEEL_TORQUE, le=MAX_WHEEL_TORQUE)]


class SensorSample(BaseModel):
    """One synchronous sample of the rover's proprioceptive sensors."""

    model_config = ConfigDict(
        extra="forbid",
        frozen=True,
        allow_inf_nan=False,
        title="SensorSample",
        json_schema_extra={"$id": SENSOR_SCHEMA_ID},
    )

    vehicle_id: VehicleId
    seq: StrictInt = Field(ge=0, description="Sequence number, strictly increasing per vehicle")
    stamp: float = Field(ge=0, description="Sample time, s (monotonic per vehicle)")
    specific_force: tuple[_SF, _SF, _SF] = Field(
        description=(
            "Accelerometer specific force [fx, fy, fz], m/s^2, body frame x forward, y left, z up "
            "(REP-103), IMU at the CoM: reads +9.81 on z at rest; at rest on a climb fx = -g sin(pitch) > 0"
        )
    )
    roll: float = Field(
        ge=-MAX_ANGLE, le=MAX_ANGLE, description="Roll, rad, right-handed about x (REP-103): > 0 = left side up"
    )
    pitch: float = Field(
        ge=-MAX_ANGLE,
        le=MAX_ANGLE,
        description="Pitch, rad, right-handed about y (REP-103): > 0 = nose DOWN; on a climb pitch < 0",
    )
    yaw_rate: float = Field(ge=-MAX_YAW_RATE, le=MAX_YAW_RATE, description="Yaw rate about z, rad/s, > 0 = turning left")
    wheel_speed: tuple[_WS, _WS, _WS, _WS] = Field(
        description="Wheel angular speeds [w1,w2,w3,w4], rad/s; 1 left-rear, 2 left-front, 3 right-front, 4 right-rear; "
        "may be encoder count differences over the last sample interval (quantised)"
    )
    wheel_torque: tuple[_WT, _WT, _WT, _WT] = Field(
        description="Wheel torques [t1,t2,t3,t4], N m (from motor current), same wheel order; > 0 drives forward"
    )
    ground_speed: Optional[float] = Field(
        ge=-MAX_GROUND_SPEED,
        le=MAX_GROUND_SPEED,
        description="Longitudinal speed of the CoM, m/s (GNSS / visual odometry), > 0 forward; null when the robot "
        "has no independent ground-speed sensor (wheel odometry is not one): slip (eq. 1) and K are then not "
        "identifiable and the estimates say so",
    )
    # Optional (absent from logs without positions, and then left out of the JSON): where the vehicle is,
    # so that each soil estimate can say where it was made (soilocp.schemas.position, docs/map.md).
    position: Optional[MapPosition] = Field(
        default=None, exclude_if=lambda v: v is None,
        description="CoM position in a named local map frame (m) and heading, e.g. from nav_msgs/Odometry; optional")
    geo: Optional[GeoPosition] = Field(
        default=None, exclude_if=lambda v: v is None,
        description="CoM position, WGS84 latitude/longitude (deg) and heading, e.g. from sensor_msgs/NavSatFix; optional")


#: The repr of a refused value in a message: what a reader needs (scalars and short vectors in full), its
#: cost bounded whatever the value (nesting, length).
_SHORT_REPR = reprlib.Repr()
_SHORT_REPR.maxlevel, _SHORT_REPR.maxstring, _SHORT_REPR.maxother = 2, 64, 64
_SHORT_REPR.maxlist = _SHORT_REPR.maxtuple = _SHORT_REPR.maxdict = 8


def format_validation_error(exc: ValidationError) -> str:
    """One line per problem: 'field.path: message (got value)'."""
    parts = []
    for err in exc.errors(include_url=False):
        loc = ".".join(str(p) for p in err.get("loc", ())) or "<sample>"
        got = err.get("input")
        # bounded: a full repr of a hostile input (an object nested 600 deep) costs milliseconds per error
        got_s = _SHORT_REPR.repr(got)
        if len(got_s) > 60:
            got_s = got_s[:57] + "..."
        parts.append(f"{loc}: {err.get('msg')} (got {got_s})")
    return "; ".join(parts)


def parse_sensor_line(text: str | bytes) -> SensorSample:
    """Parse one JSON object into a SensorSample; ValueError names the field, value and reason."""
    try:
        return SensorSample.model_validate_json(text)
    except ValidationError as exc:
        raise ValueError(format_validation_error(exc)) from exc
