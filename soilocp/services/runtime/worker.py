"""Per-vehicle counters and the bounded worker: Zenoh callbacks only enqueue (one slow callback
would stall the whole session); one thread does the work; a full queue drops and counts."""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple, Optional

class WorkItem(NamedTuple):
    """One input queued by a Zenoh callback for a service's worker thread."""

    vehicle_id: str
    kind: str  # which of the service's inputs (a row's ``StageInput.kind``)
    payload: bytes
    wall: float  # receive time, s since the epoch
    key: str  # the sample's key where the service reads it (Service.needs_key), else the key subscribed


#: The :class:`Counters` fields that a ServiceHealth reports as they are.
HEALTH_COUNTERS = ("received", "published", "rejected", "dropped", "errors", "failure_rate", "last_seq", "last_stamp")


@dataclass
class Counters:
    """Per-vehicle counters of one service (plain ints: updated under the GIL by one writer each)."""

    received: int = 0
    published: int = 0
    rejected: int = 0
    dropped: int = 0
    errors: int = 0
    last_seq: Optional[int] = None
    last_stamp: Optional[float] = None
    last_input_wall: Optional[float] = None
    detail: dict[str, Any] = field(default_factory=dict)
    #: share of the recent inputs whose processing failed (exponential window of ~FAILURE_WINDOW inputs)
    failure_rate: float = 0.0

    def bump(self, name: str, n: int = 1) -> None:
        self.detail[name] = int(self.detail.get(name, 0)) + n

    def outcome(self, failed: bool) -> None:
        self.failure_rate += (float(failed) - self.failure_rate) / FAILURE_WINDOW


#: Inputs over which a service's failure rate is averaged; above FAILING_RATE its health says "failing".
FAILURE_WINDOW = 20
FAILING_RATE = 0.5


_STOP = object()  # wakes a blocked worker to stop


class BoundedWorker:
    """One thread draining a bounded FIFO queue; ``offer`` never blocks (a full queue drops).

    The queue is a ``queue.SimpleQueue`` (C, no condition variable): the hand-off from a Zenoh
    callback to the worker is on every hop of the pipeline, and it halves the wake-up latency of
    ``queue.Queue`` (p50 22 -> 13 us, p99 141 -> 72 us on the 2-core bench machine under load).
    Its bound is checked before the put, so concurrent callbacks may pass ``maxsize`` by at most
    one item each."""

    def __init__(self, name: str, handler: Callable[[Any], None], maxsize: int, on_drop: Callable[[Any], None],
                 on_error: Callable[[Any, BaseException], None]):
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize!r}")
        self._maxsize = maxsize
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._handler = handler
        self._on_drop = on_drop
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"worker-{name}", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, item: Any) -> bool:
        if self._q.qsize() >= self._maxsize:
            self._on_drop(item)
            return False
        self._q.put(item)
        return True

    def depth(self) -> int:
        return self._q.qsize()

    def _run(self) -> None:
        # a blocking get (no timeout): an idle worker does not wake up; stop() wakes it with _STOP
        get = self._q.get
        while True:
            item = get()
            if item is _STOP or self._stop.is_set():
                return
            try:
                self._handler(item)
            except Exception as exc:  # one bad item must not stop the service
                self._on_error(item, exc)

    def stop(self, timeout: float = 0.5) -> None:
        self._stop.set()
        self._q.put(_STOP)
        if self._thread.is_alive():
            self._thread.join(timeout)
