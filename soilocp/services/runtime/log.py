"""Structured logs: one JSON object per line on stderr."""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

_LEVELS = {"debug": 10, "info": 20, "warning": 30, "error": 40}


class JsonLog:
    """Structured logs: ``{"ts":..., "level":..., "service":..., "event":..., ...}`` per line on stderr."""

    def __init__(self, service: str, level: str = "info", stream=None):
        self.service = service
        self.threshold = _LEVELS.get(level, 20)
        self.stream = stream if stream is not None else sys.stderr
        self._lock = threading.Lock()

    def log(self, level: str, event: str, **fields: Any) -> None:
        if _LEVELS[level] < self.threshold:
            return
        rec = {"ts": round(time.time(), 6), "level": level, "service": self.service, "event": event}
        rec.update(fields)
        line = json.dumps(rec, default=str, allow_nan=True)
        with self._lock:
            try:
                self.stream.write(line + "\n")
                self.stream.flush()
            except (OSError, ValueError):  # stderr closed (parent gone): logging must never kill a service
                pass

    def debug(self, event: str, **f: Any) -> None:
        self.log("debug", event, **f)

    def info(self, event: str, **f: Any) -> None:
        self.log("info", event, **f)

    def warning(self, event: str, **f: Any) -> None:
        self.log("warning", event, **f)

    def error(self, event: str, **f: Any) -> None:
        self.log("error", event, **f)
