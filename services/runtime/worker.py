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
    key: str


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


class BoundedWorker:
    """One thread draining a bounded FIFO queue; ``offer`` never blocks (a full queue drops).

    The queue is a ``queue.SimpleQueue`` (C, no condition variable): the hand-off from a Zenoh
    callback to the worker is on every hop of the pipeline, and it halves the wake-up latency of
    ``queue.Queue`` (p50 22 -> 13 us, p99 141 -> 72 us on the 2-core bench machine under load).
    Its bound is checked before the put, so concurrent callbacks may pass ``maxsize`` by at most
    one item each.

    ``inline``: an item offered while nothing is queued and the handler is not running is handled
    at once by the offering thread (the Zenoh callback), which saves the wake-up of the worker
    thread and a second take of the GIL on every message at a steady low rate; while the handler
    runs or items wait, offers queue as before, so the order is kept, a burst still ends in the
    bounded queue, and the handler never runs twice at once."""

    def __init__(self, name: str, handler: Callable[[Any], None], maxsize: int, on_drop: Callable[[Any], None],
                 on_error: Callable[[Any, BaseException], None], *, inline: bool = False):
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize!r}")
        self._maxsize = maxsize
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._handler = handler
        self._on_drop = on_drop
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=_run_worker, args=(self,), name=f"worker-{name}", daemon=True)
        self.inline = inline
        self._busy = threading.Lock()  # held while the handler runs (inline mode)
        self._count = threading.Lock()
        self._pending = 0  # items queued and not yet handled (inline mode)

    def start(self) -> None:
        self._thread.start()

    def offer(self, item: Any) -> bool:
        if self.inline:
            if not self._pending and not self._stop.is_set() and self._busy.acquire(blocking=False):
                try:
                    if not self._pending:  # nothing got queued meanwhile: this one is next
                        self._call(item)
                        return True
                finally:
                    self._busy.release()
            if self._q.qsize() >= self._maxsize:
                self._on_drop(item)
                return False
            with self._count:
                self._pending += 1
            self._q.put(item)
            return True
        if self._q.qsize() >= self._maxsize:
            self._on_drop(item)
            return False
        self._q.put(item)
        return True

    def depth(self) -> int:
        return self._q.qsize()

    def _call(self, item: Any) -> None:
        try:
            self._handler(item)
        except Exception as exc:  # one bad item must not stop the service
            self._on_error(item, exc)

    def stop(self, timeout: float = 0.5) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)


def _run_worker(w: BoundedWorker) -> None:
    while not w._stop.is_set():
        try:
            item = w._q.get(timeout=0.1)
        except queue.Empty:
            continue
        if w.inline:
            with w._busy:
                w._call(item)
                with w._count:
                    w._pending -= 1
        else:
            w._call(item)
