"""The map file (YAML): which topic or CSV column of a real robot's log feeds which sensor-log field.

One map serves ``soilocp import``, ``soilocp estimate --map`` and ``soilocp run --replay --map``.
Example for a ROS 2 robot (the README's "Your robot's data" has the full story)::

    vehicle_id: rover1
    rate_hz: 100                       # output sample rate on the common clock
    imu: {topic: /imu/data}            # sensor_msgs/Imu
    joint_states:                      # sensor_msgs/JointState
      topic: /joint_states
      wheels: [rear_left_wheel, front_left_wheel, front_right_wheel, rear_right_wheel]
      effort_scale: 1.0                # effort x scale = N m at the wheel
    ground_speed: {topic: /odom}       # nav_msgs/Odometry or geometry_msgs/TwistStamped

``wheels`` lists joint names in the product's wheel order 1 left-rear, 2 left-front,
3 right-front, 4 right-rear.  A skid-steer robot with one motor per side names its side joint
twice (``[left_wheel, left_wheel, right_wheel, right_wheel]``): both wheels then read that joint's
speed, and its effort (the side's total torque) is split evenly between them.

Alignment (method: last value held up to a maximum age): every output tick takes, for each
stream, the newest message stamped at or before the tick; if that message is older than the
stream's ``max_age`` (seconds) the stream is stale at that tick and the sample is skipped with a
counted reason.  Defaults: IMU 0.05 s, joint states 0.1 s, ground speed 0.25 s (several periods of
typical 100 / 50 / 10-20 Hz streams, short next to the soil-strength time scale of seconds).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from soilocp.schemas.sensor import VEHICLE_ID_PATTERN

DEFAULT_MAX_AGE = {"imu": 0.05, "joint_states": 0.1, "ground_speed": 0.25, "wheels": 0.5, "position": 0.5, "geo": 1.5}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ImuMap(_Strict):
    topic: str = Field(min_length=1)
    max_age: float = Field(DEFAULT_MAX_AGE["imu"], gt=0, description="s; older = stale")
    #: "message": roll and pitch from the message's orientation (REP-103);
    #: "estimate": from gyro + accelerometer (complementary filter), for IMUs without orientation.
    #: With "message", an orientation covariance[0] of -1 (REP-145: no orientation) switches to "estimate".
    attitude: Literal["message", "estimate"] = "message"


class JointStatesMap(_Strict):
    topic: str = Field(min_length=1)
    wheels: tuple[str, str, str, str] = Field(description="joint names for wheels 1 LR, 2 LF, 3 RF, 4 RR")
    #: JointState.effort x effort_scale = torque at the wheel, N m.  For motor drivers that put the
    #: motor current in effort, this is the motor-current -> wheel-torque constant (motor torque
    #: constant x gear ratio x efficiency, N m per A): ``soilocp calibrate`` can fit it where ground
    #: truth of speed exists.
    effort_scale: float = Field(1.0, gt=0)
    max_age: float = Field(DEFAULT_MAX_AGE["joint_states"], gt=0)


class GroundSpeedMap(_Strict):
    topic: str = Field(min_length=1)
    max_age: float = Field(DEFAULT_MAX_AGE["ground_speed"], gt=0)


class PositionMap(_Strict):
    """Optional: the vehicle's pose in a local map frame from ``nav_msgs/Odometry`` (pose.pose:
    x, y and the yaw of its orientation).  A stale or absent pose leaves a sample without position
    (it is never a reason to skip a tick)."""

    topic: str = Field(min_length=1)
    #: The map frame's name; None: the messages' header.frame_id.
    frame: Optional[str] = Field(None, pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    max_age: float = Field(DEFAULT_MAX_AGE["position"], gt=0)


class GeoMap(_Strict):
    """Optional: WGS84 latitude/longitude from ``sensor_msgs/NavSatFix`` (messages without a fix,
    status.status < 0, are dropped with their reason)."""

    topic: str = Field(min_length=1)
    max_age: float = Field(DEFAULT_MAX_AGE["geo"], gt=0)


class CsvImuMap(_Strict):
    time: str = "time"
    specific_force: tuple[str, str, str] = ("ax", "ay", "az")
    gyro: tuple[str, str, str] = ("wx", "wy", "wz")
    max_age: float = Field(DEFAULT_MAX_AGE["imu"], gt=0)


class CsvWheelsMap(_Strict):
    time: str = "time"
    speed: tuple[str, str, str, str] = Field(description="columns for wheels 1..4; repeat a column for per-side data")
    speed_unit: Literal["rad/s", "m/s"] = "rad/s"
    current: tuple[str, str, str, str] = Field(description="columns of motor current (or torque) for wheels 1..4")
    #: Motor current x current_to_torque = torque at the wheel, N m (per column, i.e. per motor;
    #: a column shared by two wheels is split evenly).  None: unknown, and then the torque channel
    #: is a current with an unknown scale, so traction and K are not identifiable.
    current_to_torque: Optional[float] = Field(None, gt=0)
    #: The current is unsigned (BorealTC, many motor drivers): take the sign of the wheel speed.
    unsigned_current: bool = True
    max_age: float = Field(DEFAULT_MAX_AGE["wheels"], gt=0)


class CsvGroundSpeedMap(_Strict):
    time: str = "time"
    column: str = Field(min_length=1, description="longitudinal CoM speed, m/s (GNSS / visual odometry)")
    max_age: float = Field(DEFAULT_MAX_AGE["ground_speed"], gt=0)


class CsvMap(_Strict):
    """Columns per role; each role is one CSV file given on the command line as ``--csv ROLE=FILE``."""

    imu: CsvImuMap = CsvImuMap()
    wheels: CsvWheelsMap
    #: None: the log has no independent ground speed: it is null in the log and K is not identifiable.
    ground_speed: Optional[CsvGroundSpeedMap] = None


class TopicMap(_Strict):
    vehicle_id: str = Field("rover1", pattern=VEHICLE_ID_PATTERN)
    rate_hz: float = Field(100.0, gt=0, le=2000)
    #: header: the messages' header stamps (the sensor's time, Unix); receive: the bag's log time
    #: (when the recorder got the message), for drivers that leave header.stamp at zero.
    clock: Literal["header", "receive"] = "header"
    wheel_radius: Optional[float] = Field(None, gt=0, description="m; needed for speeds in m/s and wheel odometry")
    imu: Optional[ImuMap] = None
    joint_states: Optional[JointStatesMap] = None
    ground_speed: Optional[GroundSpeedMap] = None
    position: Optional[PositionMap] = None  # nav_msgs/Odometry pose: where, for the fleet soil map (docs/map.md)
    geo: Optional[GeoMap] = None  # sensor_msgs/NavSatFix
    csv: Optional[CsvMap] = None

    @field_validator("vehicle_id", mode="before")
    @classmethod
    def _vid_str(cls, v):
        return str(v) if isinstance(v, (int, float)) else v

    @model_validator(mode="after")
    def _complete(self):
        if self.csv is None and (self.imu is None or self.joint_states is None):
            raise ValueError("a bag map needs 'imu' and 'joint_states' (or give a 'csv' section for CSV logs)")
        if self.csv is not None and self.csv.wheels.speed_unit == "m/s" and self.wheel_radius is None:
            raise ValueError("csv.wheels.speed_unit is m/s: give wheel_radius (m) to turn it into rad/s")
        return self


def load_map(path: str | Path) -> TopicMap:
    """Read and check a map file; ValueError names the file, the key and the reason."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"map file {str(p)!r} does not exist") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"map file {str(p)!r} is not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"map file {str(p)!r}: expected a mapping of keys, got {type(data).__name__}")
    try:
        return TopicMap.model_validate(data)
    except ValidationError as exc:
        probs = "; ".join(
            f"{'.'.join(str(x) for x in e['loc']) or '<map>'}: {e['msg']}" for e in exc.errors(include_url=False)
        )
        raise ValueError(f"map file {str(p)!r}: {probs}") from None
