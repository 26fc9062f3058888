"""Live ROS 2 messages -> sensor samples, with the bag import's conversion and alignment.

A robot's topics arrive one message at a time, each at its own rate.  :class:`LiveAligner` turns
each deserialised message into a row with :func:`~soilocp.ingest.rosbag_import.convert_message`
(the bag import's own function), builds the streams with
:func:`~soilocp.ingest.rosbag_import.topic_stream` and picks ticks with
:func:`~soilocp.ingest.align.pick`: a live drive gives, tick for tick and seq for seq, the samples
``soilocp import`` gives for a bag of the same messages.

What differs is only *when* a tick can be written.  Tick ``t`` is final once every stream has a
message stamped after ``t`` (its newest value at or before ``t`` can no longer change).  A stream
that falls silent would hold every tick back, so a stream is also given up for ``t`` once another
stream is ``max_age + lag_s`` past ``t`` (its value there is then stale, and the tick is skipped
with the reason counted, as in the bag import).  When every stream is silent (the drive stopped,
a link broke) :meth:`LiveAligner.flush` writes the ticks up to where the bag import would end:
the last instant every stream is still fresh.

Messages are expected in stamp order per topic (one publisher, one link).  A message stamped
before the previous one of its topic is dropped with the bag import's reason ("goes backwards");
the bag import can instead keep the longest in-order run because it sees the whole log.  A clock
that jumps back for good (a simulation restarted) therefore needs a new reader.
"""

from __future__ import annotations

from collections import Counter
from typing import Optional

import numpy as np

from soilocp.schemas.sensor import SensorSample
from soilocp.ingest.align import NS, Provenance, Stream, pick, samples_from_aligned, tick_count
from soilocp.ingest.mapfile import TopicMap
from soilocp.ingest.rosbag_import import (EXPECTED_TYPES, convert_message, message_stamp, note_identifiability,
                                          topic_stream)
from soilocp.ingest.topic_reader import BagIssues, TopicReader

#: s of data time another stream may run ahead of a silent one before that one is given up for a tick
DEFAULT_LAG_S = 0.5


class LiveAligner:
    """Mapped topics' messages in, :class:`SensorSample` out (see the module docstring)."""

    def __init__(self, tmap: TopicMap, *, lag_s: float = DEFAULT_LAG_S, source: str = "ros2 live"):
        if tmap.imu is None or tmap.joint_states is None:
            raise ValueError("a live ROS 2 map needs 'imu' and 'joint_states' (a 'csv' map cannot be read live)")
        if not lag_s >= 0:
            raise ValueError(f"lag_s {lag_s!r}: must be >= 0 s")
        self.tmap = tmap
        self.lag_ns = int(round(lag_s * NS))
        self.roles = {"imu": tmap.imu, "joint_states": tmap.joint_states}
        if tmap.ground_speed is not None:
            self.roles["ground_speed"] = tmap.ground_speed
        self.issues = BagIssues()
        self.readers = {k: TopicReader(k, m.topic, self.issues, strict=False) for k, m in self.roles.items()}
        self.prov = Provenance(source=source)
        note_identifiability(tmap, self.prov)
        self.skipped: Counter = Counter()
        self.samples = 0
        self._seen_joints: set = set()
        self._last: dict[str, int] = {}  # newest kept stamp per role
        self._buf: dict[str, Optional[Stream]] = {k: None for k in self.roles}
        self._tilt_prev: Optional[tuple[int, float, float]] = None
        self._start: Optional[int] = None  # ns of tick 0
        self._next = 0  # next tick index to write

    @property
    def topics(self) -> dict[str, str]:
        """role -> topic name."""
        return {k: m.topic for k, m in self.roles.items()}

    def role_of(self, topic: str) -> Optional[str]:
        return next((k for k, m in self.roles.items() if m.topic == topic), None)

    def add(self, role: str, msg, msgtype: str, receive_ns: int) -> None:
        """One deserialised message of ``role``; a bad one is dropped with its reason."""
        if msgtype not in EXPECTED_TYPES[role]:
            self.issues.add(self.roles[role].topic, "type", f"{msgtype} cannot feed {role}: needs "
                            + " or ".join(EXPECTED_TYPES[role]), receive_ns)
            return
        st = message_stamp(msg, receive_ns, self.tmap)
        r = self.readers[role]
        last = self._last.get(role)
        if last is not None and st < last:
            r.drop("header.stamp", "goes backwards (earlier than the previous message)", st,
                   f"by {(last - st) / NS:.3f} s")
            return
        n = len(r.rows)
        convert_message(role, r, msg, msgtype, st, self.tmap, self._seen_joints)
        if len(r.rows) > n:
            self._last[role] = st

    def ready(self) -> list[SensorSample]:
        """The samples of every tick that no later message can change (see the module docstring)."""
        self._absorb()
        if self._start is None:
            return []
        horizon = max(self._last.values())
        bound = min(max(self._last[k] - 1, horizon - int(round(m.max_age * NS)) - self.lag_ns)
                    for k, m in self.roles.items())
        return self._write_until(bound)

    def flush(self) -> list[SensorSample]:
        """Every stream is silent: write the ticks up to the last instant all streams are fresh
        (where the bag import's log ends).  Later messages continue on the same clock."""
        self._absorb()
        if self._start is None:
            return []
        bound = min(self._last[k] + int(m.max_age * NS) for k, m in self.roles.items())
        return self._write_until(bound)

    def dropped(self) -> dict[str, int]:
        return {f"{t}: {f}: {r}": n for (t, f, r), n in self.issues.counts.items()}

    # --- internals -------------------------------------------------------------------------------
    def _absorb(self) -> None:
        """Move the readers' new rows into the streams (one conversion per batch, as the bag import)."""
        for role, r in self.readers.items():
            if not r.rows:
                continue
            st = np.asarray(r.stamps, dtype=np.int64)
            s = topic_stream(role, r.topic, st, r.rows, self.tmap, self.prov,
                             tilt_prev=self._tilt_prev if role == "imu" else None)
            if role == "imu":
                self._tilt_prev = (int(st[-1]), float(s.values["roll"][-1]), float(s.values["pitch"][-1]))
            r.stamps.clear()
            r.rows.clear()
            old = self._buf[role]
            if old is None:
                self._buf[role] = s
            else:
                self._buf[role] = Stream(s.name, np.concatenate([old.stamps, s.stamps]),
                                         {k: np.concatenate([old.values[k], v]) for k, v in s.values.items()},
                                         s.max_age)
        if self._start is None and all(b is not None for b in self._buf.values()):
            self._start = max(int(b.stamps[0]) for b in self._buf.values())
        elif self._start is None:
            # a stream that never starts must not make the others grow without bound: before the
            # clock starts, a stream's values older than its max age + lag cannot be fresh at any tick
            for k, b in self._buf.items():
                if b is not None:
                    keep = b.stamps >= b.stamps[-1] - int(round(self.roles[k].max_age * NS)) - self.lag_ns
                    if not keep[0]:
                        self._buf[k] = Stream(b.name, b.stamps[keep], {f: v[keep] for f, v in b.values.items()},
                                              b.max_age)

    def _write_until(self, bound: int) -> list[SensorSample]:
        n = tick_count(self._start, bound, self.tmap.rate_hz) - self._next
        if n <= 0:
            return []
        streams = [self._buf[k] for k in self.roles]
        al = pick(streams, self._start, self._next, n, self.tmap.rate_hz)
        self.skipped.update(al.skipped)
        out = list(samples_from_aligned(al, self.tmap.vehicle_id, self.skipped))
        self._next += n
        self.samples += len(out)
        last_tick = self._start + int(round((self._next - 1) * NS / self.tmap.rate_hz))
        for k, s in self._buf.items():  # keep each stream's value held at the last tick, and what follows
            i = max(int(np.searchsorted(s.stamps, last_tick, side="right")) - 1, 0)
            if i:
                self._buf[k] = Stream(s.name, s.stamps[i:], {f: v[i:] for f, v in s.values.items()}, s.max_age)
        return out
