"""Write a sensor log as a ROS 2 bag, the way a typical robot records it (for tests and demos).

Three topics at their own rates, header stamps in Unix time: ``/imu/data`` (sensor_msgs/Imu,
every sample), ``/joint_states`` (sensor_msgs/JointState, every ``joint_every``-th sample, the
joint order shuffled per message as some drivers do) and ``/odom`` (nav_msgs/Odometry, every
``odom_every``-th sample).  ``mutate(topic, index, msg)`` may return a changed message or None
(drop it), to build hostile bags.

    python -m soilocp.ingest.bag_writer SENSORS.jsonl BAG_DIR [--storage mcap|sqlite3]
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Callable, Iterable, Optional

import numpy as np

from soilocp.schemas.sensor import SensorSample

WHEEL_JOINTS = ("rear_left_wheel", "front_left_wheel", "front_right_wheel", "rear_right_wheel")  # wheels 1..4
UNIX_BASE = 1_700_000_000  # s; a recent Unix time, so the stamps look like a real robot's


def _quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def write_bag(
    samples: Iterable[SensorSample],
    path: str | Path,
    *,
    storage: str = "mcap",
    joint_every: int = 2,
    odom_every: int = 5,
    unix_base: int = UNIX_BASE,
    shuffle_seed: Optional[int] = 0,
    joint_names: tuple[str, str, str, str] = WHEEL_JOINTS,
    mutate: Optional[Callable[[str, int, object], object]] = None,
    types: Optional[dict[str, str]] = None,
) -> Path:
    """Write ``samples`` to a rosbag2 directory ``path`` (storage ``mcap`` or ``sqlite3``)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vec, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    rng = np.random.default_rng(shuffle_seed) if shuffle_seed is not None else None
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    types = {"/imu/data": "sensor_msgs/msg/Imu", "/joint_states": "sensor_msgs/msg/JointState",
             "/odom": "nav_msgs/msg/Odometry", **(types or {})}
    zeros9, zeros36 = np.zeros(9), np.zeros(36)
    yaw = 0.0
    last_stamp = None
    with Writer(Path(path), version=9, storage_plugin=plugin) as w:
        conns = {t: w.add_connection(t, mt, typestore=ts) for t, mt in types.items()}

        def put(topic, i, stamp_ns, msg, mt):
            if mutate is not None:
                msg = mutate(topic, i, msg)
                if msg is None:
                    return
            # log time = receive time: a little after the header stamp
            w.write(conns[topic], stamp_ns + 2_000_000, ts.serialize_cdr(msg, mt))

        for i, s in enumerate(samples):
            ns = unix_base * 1_000_000_000 + int(round(s.stamp * 1e9))
            def hdr():  # one header per message, so that a mutation touches only its own message
                return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="base_link")

            if last_stamp is not None:
                yaw += s.yaw_rate * (s.stamp - last_stamp)
            last_stamp = s.stamp
            qx, qy, qz, qw = _quat(s.roll, s.pitch, yaw)
            imu = T["sensor_msgs/msg/Imu"](
                header=hdr(), orientation=Quat(x=qx, y=qy, z=qz, w=qw), orientation_covariance=zeros9,
                angular_velocity=Vec(x=0.0, y=0.0, z=s.yaw_rate), angular_velocity_covariance=zeros9,
                linear_acceleration=Vec(x=s.specific_force[0], y=s.specific_force[1], z=s.specific_force[2]),
                linear_acceleration_covariance=zeros9)
            put("/imu/data", i, ns, imu, types["/imu/data"])
            if i % joint_every == 0:
                order = rng.permutation(4) if rng is not None else np.arange(4)
                js = T["sensor_msgs/msg/JointState"](
                    header=hdr(), name=[joint_names[j] for j in order], position=np.zeros(4),
                    velocity=np.array([s.wheel_speed[j] for j in order]), effort=np.array([s.wheel_torque[j] for j in order]))
                put("/joint_states", i, ns, js, types["/joint_states"])
            if i % odom_every == 0:
                lin = Vec(x=s.ground_speed, y=0.0, z=0.0)
                if types["/odom"] == "nav_msgs/msg/Odometry":
                    # a sample with a position: the pose in its map frame (the header names the frame)
                    p = s.position
                    oq = _quat(s.roll, s.pitch, p.heading) if p is not None and p.heading is not None else (qx, qy, qz, qw)
                    oh = hdr()
                    if p is not None:
                        oh.frame_id = p.frame
                    od = T["nav_msgs/msg/Odometry"](
                        header=oh, child_frame_id="base_link",
                        pose=T["geometry_msgs/msg/PoseWithCovariance"](
                            pose=T["geometry_msgs/msg/Pose"](
                                position=T["geometry_msgs/msg/Point"](x=p.x if p else 0.0, y=p.y if p else 0.0, z=0.0),
                                orientation=Quat(x=oq[0], y=oq[1], z=oq[2], w=oq[3])), covariance=zeros36),
                        twist=T["geometry_msgs/msg/TwistWithCovariance"](
                            twist=T["geometry_msgs/msg/Twist"](linear=lin, angular=Vec(x=0.0, y=0.0, z=s.yaw_rate)),
                            covariance=zeros36))
                else:
                    od = T["geometry_msgs/msg/TwistStamped"](
                        header=hdr(), twist=T["geometry_msgs/msg/Twist"](linear=lin, angular=Vec(x=0.0, y=0.0, z=s.yaw_rate)))
                put("/odom", i, ns, od, types["/odom"])
            if s.geo is not None and i % odom_every == 0:  # GNSS at the odometry's rate
                if "/fix" not in conns:
                    conns["/fix"] = w.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=ts)
                fix = T["sensor_msgs/msg/NavSatFix"](
                    header=hdr(), status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                    latitude=s.geo.latitude, longitude=s.geo.longitude, altitude=0.0,
                    position_covariance=zeros9, position_covariance_type=0)
                put("/fix", i, ns, fix, "sensor_msgs/msg/NavSatFix")
    return Path(path)


def main(argv: list[str]) -> int:
    import argparse

    from soilocp.schemas.sensor import parse_sensor_line

    ap = argparse.ArgumentParser(prog="python -m soilocp.ingest.bag_writer", description=__doc__.split("\n\n")[0])
    ap.add_argument("sensors")
    ap.add_argument("bag")
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    a = ap.parse_args(argv)
    with open(a.sensors, encoding="utf-8") as f:
        samples = [parse_sensor_line(line) for line in f if line.strip()]
    write_bag(samples, a.bag, storage=a.storage)
    print(f"{len(samples)} samples -> {a.bag} ({a.storage})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
