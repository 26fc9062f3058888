"""ROS 2 bags (rosbag2 directory with sqlite3 or MCAP storage, or a bare ``.mcap``) -> sensor log.

Read with ``rosbags`` (pure Python, no ROS installation).  Standard messages only:

* ``sensor_msgs/msg/Imu``: ``linear_acceleration`` is the specific force (REP-145: +9.81 on z at
  rest), ``angular_velocity.z`` the yaw rate, ``orientation`` gives roll and pitch (REP-103,
  pitch > 0 nose down); an IMU without orientation (covariance[0] = -1) gets them from gyro +
  accelerometer (:func:`soilocp.ingest.align.complementary_tilt`);
* ``sensor_msgs/msg/JointState``: ``velocity`` (rad/s) and ``effort`` x ``effort_scale`` (N m) of the
  mapped wheel joints, matched by name in every message (drivers do not keep the order);
* ``nav_msgs/msg/Odometry`` (``twist.twist.linear.x``) or ``geometry_msgs/msg/TwistStamped``
  (``twist.linear.x``): the ground speed.

Header stamps (Unix time) are the clock.  Structural problems (a missing topic, a wrong message
type, a wheel joint that is not in the bag) stop the import with :class:`BagImportError`.  Bad
messages (NaN in a used field, a zero stamp, a stamp out of time order: the longest in-order run
of each topic is kept, a wheel joint missing from one message) are dropped with a counted, specific reason, so that the good data around a bad stretch
is kept; the ticks that then have no fresh value are skipped (``align``).  ``strict`` makes the
first bad message an error instead.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Optional

import numpy as np

from soilocp.ingest.align import NS, Provenance, Stream, align_and_write, complementary_tilt
from soilocp.ingest.mapfile import TopicMap
from soilocp.ingest.positions import position_stream, read_position
from soilocp.ingest.topic_reader import BagImportError, BagIssues, TopicReader

EXPECTED_TYPES = {
    "imu": ("sensor_msgs/msg/Imu",),
    "joint_states": ("sensor_msgs/msg/JointState",),
    "ground_speed": ("nav_msgs/msg/Odometry", "geometry_msgs/msg/TwistStamped"),
    "position": ("nav_msgs/msg/Odometry",),
    "geo": ("sensor_msgs/msg/NavSatFix",),
}
PROGRESS_MIN_MESSAGES = 20_000  # a bar below this would only flicker


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * NS + int(header.stamp.nanosec)


def _quat_roll_pitch(x: float, y: float, z: float, w: float) -> tuple[float, float]:
    """Roll and pitch of a body-to-world quaternion, ZYX (REP-103): pitch > 0 = nose down."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch


def _imu(r: TopicReader, msg, st: int) -> None:
    if not r.accept_stamp(st):
        return
    la, av, q = msg.linear_acceleration, msg.angular_velocity, msg.orientation
    has_q = not (len(msg.orientation_covariance) and msg.orientation_covariance[0] == -1.0)
    named = {
        "linear_acceleration.x": la.x, "linear_acceleration.y": la.y, "linear_acceleration.z": la.z,
        "angular_velocity.x": av.x, "angular_velocity.y": av.y, "angular_velocity.z": av.z,
    }
    if has_q:
        named.update({"orientation.x": q.x, "orientation.y": q.y, "orientation.z": q.z, "orientation.w": q.w})
    if not r.check_finite(st, named):
        return
    roll, pitch = _quat_roll_pitch(q.x, q.y, q.z, q.w) if has_q else (math.nan, math.nan)
    r.keep(st, (la.x, la.y, la.z, av.x, av.y, av.z, roll, pitch, has_q))


def _joints(r: TopicReader, msg, st: int, wheels: tuple[str, ...], scale: float, seen: set) -> None:
    names = list(msg.name)
    seen.update(names)
    if not r.accept_stamp(st):
        return
    index = {n: i for i, n in enumerate(names)}
    vel, eff = np.asarray(msg.velocity, dtype=float), np.asarray(msg.effort, dtype=float)
    speeds, torques = [], []
    share = Counter(wheels)
    for w in wheels:
        i = index.get(w)
        if i is None:
            r.drop("name", f"wheel joint {w!r} missing from this message", st)
            return
        if i >= vel.size:
            r.drop(f"velocity[{w}]", f"absent (velocity has {vel.size} entries for {len(names)} names)", st)
            return
        if i >= eff.size:
            r.drop(f"effort[{w}]", f"absent (effort has {eff.size} entries for {len(names)} names)", st)
            return
        if not r.check_finite(st, {f"velocity[{w}]": float(vel[i]), f"effort[{w}]": float(eff[i])}):
            return
        speeds.append(float(vel[i]))
        torques.append(float(eff[i]) * scale / share[w])  # a side joint drives share[w] wheels
    r.keep(st, (*speeds, *torques))


def _ground_speed(r: TopicReader, msg, st: int, msgtype: str) -> None:
    if not r.accept_stamp(st):
        return
    if msgtype == "nav_msgs/msg/Odometry":
        name, v = "twist.twist.linear.x", msg.twist.twist.linear.x
    else:
        name, v = "twist.linear.x", msg.twist.linear.x
    if r.check_finite(st, {name: v}):
        r.keep(st, (v,))


def message_stamp(msg, receive_ns: int, tmap: TopicMap) -> int:
    """The message's time on the map's clock: its header stamp, or (``clock: receive``) when it
    was received (the bag's log time; for the live reader, its arrival)."""
    return _stamp_ns(msg.header) if tmap.clock == "header" else int(receive_ns)


def convert_message(key: str, r: TopicReader, msg, msgtype: str, st: int, tmap: TopicMap, seen_joints: set) -> None:
    """One deserialised message of map role ``key`` (imu | joint_states | ground_speed | position | geo) into its
    reader's row, or dropped with a reason.  Bag import and live reader call this same function."""
    if key == "imu":
        _imu(r, msg, st)
    elif key == "joint_states":
        js = tmap.joint_states
        _joints(r, msg, st, js.wheels, js.effort_scale, seen_joints)
    elif key == "ground_speed":
        _ground_speed(r, msg, st, msgtype)
    else:  # position (Odometry pose) or geo (NavSatFix): soilocp.ingest.positions
        read_position(key, r, msg, st)


def _progress(total: int, label: str):
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if total < PROGRESS_MIN_MESSAGES:
        return None
    return Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    console=Console(stderr=True), transient=False)


def read_bag(path: str | Path, tmap: TopicMap, *, strict: bool = False, progress: bool = True):
    """Streams of one bag per the map, and the dropped-message issues; BagImportError on structure."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    p = Path(path)
    if not p.exists():
        raise BagImportError(f"{str(p)!r}: no such bag (a rosbag2 directory or a .mcap file)")
    wanted = {"imu": tmap.imu, "joint_states": tmap.joint_states}
    if tmap.ground_speed is not None:
        wanted["ground_speed"] = tmap.ground_speed
    for opt in ("position", "geo"):  # optional streams of where the vehicle is (docs/map.md)
        if getattr(tmap, opt) is not None:
            wanted[opt] = getattr(tmap, opt)
    issues = BagIssues()
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own errors for unreadable bags
        raise BagImportError(f"{str(p)!r}: not a readable ROS 2 bag: {exc}") from None
    try:
        by_topic: dict[str, list] = {}
        for c in reader.connections:
            by_topic.setdefault(c.topic, []).append(c)
        conns, readers, types = [], {}, {}
        for key, m in wanted.items():
            cs = by_topic.get(m.topic)
            if not cs:
                raise BagImportError(
                    f"{m.topic}: topic not in the bag (map key {key}.topic); topics in the bag: "
                    + ", ".join(f"{t} ({v[0].msgtype})" for t, v in sorted(by_topic.items())))
            for c in cs:
                if c.msgtype not in EXPECTED_TYPES[key]:
                    raise BagImportError(
                        f"{m.topic}: message type {c.msgtype} cannot feed {key} (map key {key}.topic): "
                        f"needs {' or '.join(EXPECTED_TYPES[key])}")
            conns += [c for c in cs if c not in conns]
            types[m.topic] = cs[0].msgtype
            # one topic may feed two roles (an Odometry's twist and its pose): one reader per role
            readers.setdefault(m.topic, []).append((key, TopicReader(key, m.topic, issues, strict)))
        total = sum(c.msgcount for c in conns)
        js = tmap.joint_states
        seen_joints: set = set()
        bar = _progress(total, f"importing {p.name}") if progress else None
        task = bar.add_task("read", total=total) if bar else None
        if bar:
            bar.start()
        try:
            for n, (conn, log_time, raw) in enumerate(reader.messages(connections=conns), 1):
                msg = reader.deserialize(raw, conn.msgtype)
                st = message_stamp(msg, log_time, tmap)
                for key, r in readers[conn.topic]:
                    convert_message(key, r, msg, conn.msgtype, st, tmap, seen_joints)
                if bar and n % 2000 == 0:
                    bar.update(task, completed=n)
        finally:
            if bar:
                bar.update(task, completed=total)
                bar.stop()
    finally:
        reader.close()
    for i, w in enumerate(js.wheels):
        if seen_joints and w not in seen_joints:
            raise BagImportError(
                f"{js.topic}: name: joint {w!r} (map key joint_states.wheels[{i}]) is not in the bag; "
                f"joint names there: {sorted(seen_joints)}")
    return readers, types, issues


def topic_stream(key: str, topic: str, st: np.ndarray, rows: list, tmap: TopicMap, prov: Provenance,
                 tilt_prev: Optional[tuple[int, float, float]] = None) -> Stream:
    """The stream of one topic's kept rows (stamps ``st``, in order); notes in ``prov`` what the
    rows say about the log (attitude from gyro + accelerometer, per-side drive).  ``tilt_prev``:
    the complementary filter's state before these rows (live reader, batch by batch)."""
    if key == "imu":
        a = np.asarray([row[:8] for row in rows], dtype=float)
        has_q = np.asarray([row[8] for row in rows], dtype=bool)
        roll, pitch = a[:, 6], a[:, 7]
        if tmap.imu.attitude == "estimate" or not has_q.all():
            roll, pitch = complementary_tilt(st, a[:, 3:6], a[:, 0:3], prev=tilt_prev)
            prov.attitude = "gyro+accelerometer (complementary filter)"
        vals = {"specific_force": a[:, 0:3], "yaw_rate": a[:, 5], "roll": roll, "pitch": pitch}
        return Stream(f"imu ({topic})", st, vals, tmap.imu.max_age)
    a = np.asarray(rows, dtype=float)
    if key == "joint_states":
        if len(set(tmap.joint_states.wheels)) < 4:
            prov.drive = "per_side"
        vals = {"wheel_speed": a[:, :4], "wheel_torque": a[:, 4:]}
        if tmap.ground_speed is None:  # no independent ground speed: null in the log
            vals["ground_speed"] = np.full(len(rows), np.nan)
        return Stream(f"joint_states ({topic})", st, vals, tmap.joint_states.max_age)
    return Stream(f"ground_speed ({topic})", st, {"ground_speed": a[:, 0]}, tmap.ground_speed.max_age)


def note_identifiability(tmap: TopicMap, prov: Provenance) -> None:
    """What the map alone says the chain cannot identify (no ground speed: slip and K)."""
    if tmap.ground_speed is None:
        prov.ground_speed = "absent"
        prov.identifiable = False
        prov.reasons.append("no independent ground speed in the source (slip, eq. 1, needs it)")


def _streams(readers: dict, tmap: TopicMap) -> tuple[list[Stream], Provenance]:
    prov = Provenance(source="rosbag2")
    streams = []
    for topic, key, r in ((t, k, r) for t, roles in readers.items() for k, r in roles):
        if key in ("position", "geo"):
            streams.append(position_stream(key, r, tmap))
            continue
        st, rows = r.in_order()
        if not rows:
            raise BagImportError(f"{topic}: no usable message (map key {key}.topic): all were dropped, see the reasons")
        streams.append(topic_stream(key, topic, st, rows, tmap, prov))
    note_identifiability(tmap, prov)
    return streams, prov


def import_bag(path: str | Path, tmap: TopicMap, out: str | Path, *, strict: bool = False,
               progress: bool = True) -> tuple[Provenance, list[str]]:
    """Import a bag to the sensor log ``out`` (+ ``out.provenance.json``); returns (provenance, issue lines)."""
    readers, _types, issues = read_bag(path, tmap, strict=strict, progress=progress)
    try:
        streams, prov = _streams(readers, tmap)
    except BagImportError as exc:  # e.g. every message of a topic dropped: say why
        raise BagImportError("; ".join([str(exc), *issues.lines()])) from None
    prov.source = f"rosbag2 {Path(path).name}"
    dropped = {f"{t}: {f}: {r}": n for (t, f, r), n in issues.counts.items()}
    align_and_write(streams, tmap, prov, out, dropped, BagImportError)
    return prov, issues.lines()
