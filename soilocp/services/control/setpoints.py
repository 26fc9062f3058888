"""The latest set-point of one vehicle, heard on its control key: what the simulated vehicles under closed-loop
control (:mod:`.vehicle_control`, :mod:`.vehicle_drive`) follow."""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Optional


class LatestSetpoint:
    """The latest set-point message of one vehicle and when it came (thread-safe: the Zenoh callback only stores
    it), with counts: taken, ``bad`` (malformed, or another vehicle's) and taken by source.  A subclass names
    its ``message`` model, the ``clock`` its times are on and each message's ``source``."""

    message: Any  # the pydantic model of the set-point
    clock: Callable[[], float] = staticmethod(time.perf_counter)

    def __init__(self, vehicle_id: str):
        self.vehicle_id = vehicle_id
        self._lock = threading.Lock()
        self._latest = None
        self._wall: Optional[float] = None
        self.received = 0
        self.bad = 0
        self.sources: dict[str, int] = {}

    @staticmethod
    def source(sp) -> str:
        """What a set-point is counted under in ``sources``."""
        return sp.source

    def offer(self, payload: bytes, wall: Optional[float] = None) -> None:
        """Take a set-point payload heard at ``wall`` (default: the clock's now), or count it as bad."""
        wall = self.clock() if wall is None else wall
        try:
            sp = self.message.model_validate_json(payload)
        except ValueError:
            sp = None
        with self._lock:
            if sp is None or sp.vehicle_id != self.vehicle_id:
                self.bad += 1
                return
            self._latest, self._wall = sp, wall
            self.received += 1
            name = self.source(sp)
            self.sources[name] = self.sources.get(name, 0) + 1
            self.taken(sp, wall)

    def taken(self, sp, wall: float) -> None:
        """Called under the lock with each set-point taken (a subclass measures its loop latency)."""

    def latest(self) -> tuple[Any, Optional[float]]:
        """The latest set-point and when it came (None, None before the first)."""
        with self._lock:
            return self._latest, self._wall
