"""What a starting service says in its log that ``soilocp run`` must not wait out.

A service that cannot start does not always exit: one whose external dependency is missing (the
robot's ROS 2 router, for ``ros2-out`` / ``ros2-in``) keeps retrying, logging why, and the run would
only notice when its liveliness wait times out.  :class:`LogWatch` reads the children's JSON log lines
as they are written and reports the first one that means the run cannot go on: an ``error`` or
``critical`` line, or an event of :data:`BLOCKING_EVENTS` (a wait on something the run does not start
itself).  Its own router is started by the run, so ``waiting_for_router`` is not one of them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Optional

#: events that mean a service waits on something the run does not start, with what to do about it
BLOCKING_EVENTS: dict[str, str] = {
    "waiting_for_ros2_router": "no ROS 2 Zenoh router (rmw_zenohd) answers there: start it on the robot, or give "
                               "--ros2-connect ENDPOINT where it listens (docs/ros2.md)",
}
FATAL_LEVELS = ("error", "critical")


@dataclass
class Problem:
    """A child's log line that stops the run: the child, the line's event and its own message, and a fix."""

    service: str
    event: str
    message: str
    fix: str = ""

    def __str__(self) -> str:
        text = f"{self.service} cannot start: {self.event}: {self.message}"
        return f"{text}; {self.fix}" if self.fix else text


def _message(rec: dict) -> str:
    """The line's own words: its error or message field, else every field but the bookkeeping ones."""
    for key in ("error", "message", "reason"):
        if rec.get(key):
            extra = {k: v for k, v in rec.items() if k in ("connect", "endpoint", "path") and v}
            where = "".join(f" ({k} {v})" for k, v in extra.items())
            return f"{rec[key]}{where}"
    rest = {k: v for k, v in rec.items() if k not in ("ts", "level", "service", "event")}
    return json.dumps(rest)[:300]


@dataclass
class LogWatch:
    """Reads the new lines of the logs of ``names`` (in ``log_dir``) at each :meth:`poll`."""

    log_dir: Path
    names: Iterable[str]
    offsets: dict[str, int] = field(default_factory=dict)

    def poll(self) -> Optional[Problem]:
        """The first blocking line written since the last poll (None: none)."""
        for name in list(self.names):
            path = Path(self.log_dir) / f"{name}.log"
            try:
                with open(path, "rb") as fh:
                    fh.seek(self.offsets.get(name, 0))
                    chunk = fh.read()
            except OSError:
                continue
            end = chunk.rfind(b"\n") + 1  # a line still being written is read next time
            self.offsets[name] = self.offsets.get(name, 0) + end
            for raw in chunk[:end].splitlines():
                problem = self._judge(name, raw)
                if problem is not None:
                    return problem
        return None

    @staticmethod
    def _judge(name: str, raw: bytes) -> Optional[Problem]:
        try:
            rec = json.loads(raw)
        except ValueError:
            return None  # a traceback or other plain text: an exit follows, which the run reports with the log tail
        if not isinstance(rec, dict):
            return None
        event = str(rec.get("event", ""))
        if event in BLOCKING_EVENTS:
            return Problem(name, event, _message(rec), BLOCKING_EVENTS[event])
        if rec.get("level") in FATAL_LEVELS:
            return Problem(name, event, _message(rec))
        return None
