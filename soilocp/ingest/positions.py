"""Where the vehicle is, from a ROS 2 bag: ``nav_msgs/Odometry`` pose (x, y, yaw in its frame)
and ``sensor_msgs/NavSatFix`` (latitude, longitude).  Both are optional streams: the aligner
attaches them to the ticks where they are fresh and leaves the others without a position
(:func:`soilocp.ingest.align.align`), never skipping a tick for them."""

from __future__ import annotations

import math
import re

import numpy as np

from soilocp.schemas.position import FRAME_PATTERN

from soilocp.ingest.align import Stream
from soilocp.ingest.topic_reader import BagImportError

_FRAME_RE = re.compile(FRAME_PATTERN)


def _yaw(q) -> float:
    """Yaw (rad, counter-clockwise about z) of a body-to-world quaternion, ZYX (REP-103)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def read_position(key: str, r, msg, st: int) -> None:
    """One Odometry (key ``position``) or NavSatFix (key ``geo``) message into reader ``r``'s rows,
    or dropped with its reason."""
    if not r.accept_stamp(st):
        return
    if key == "position":
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        if not r.check_finite(st, {"pose.pose.position.x": p.x, "pose.pose.position.y": p.y,
                                   "pose.pose.orientation.z": q.z, "pose.pose.orientation.w": q.w}):
            return
        r.keep(st, (p.x, p.y, _yaw(q), str(msg.header.frame_id)))
        return
    if msg.status.status < 0:
        r.drop("status.status", "no fix (status < 0)", st)
        return
    if not r.check_finite(st, {"latitude": msg.latitude, "longitude": msg.longitude}):
        return
    if not (-90.0 <= msg.latitude <= 90.0 and -180.0 <= msg.longitude <= 180.0):
        r.drop("latitude/longitude", f"outside WGS84 ({msg.latitude}, {msg.longitude})", st)
        return
    r.keep(st, (msg.latitude, msg.longitude))


def position_stream(key: str, r, tmap) -> Stream:
    """The optional stream of a position reader (values position_x/_y/_heading/_frame, or
    latitude/longitude); an empty one when every message was dropped."""
    st, rows = r.in_order()
    m = getattr(tmap, key)
    if key == "position":
        frames = [m.frame or row[3] for row in rows]
        for f in set(frames):
            if not _FRAME_RE.match(f):
                raise BagImportError(f"{m.topic}: header.frame_id {f!r} is not a usable map frame name "
                                     f"({FRAME_PATTERN}); name one with position.frame in the map file")
        a = np.asarray([row[:3] for row in rows], dtype=float).reshape(-1, 3)
        vals = {"position_x": a[:, 0], "position_y": a[:, 1], "position_heading": a[:, 2],
                "position_frame": np.asarray(frames, dtype=object)}
    else:
        a = np.asarray(rows, dtype=float).reshape(-1, 2)
        vals = {"latitude": a[:, 0], "longitude": a[:, 1]}
    return Stream(f"{key} ({m.topic})", st, vals, m.max_age, optional=True)
