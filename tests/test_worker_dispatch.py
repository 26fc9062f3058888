"""The worker's two dispatch modes: inline (the offering thread handles an item when the worker is
idle) keeps the queue's guarantees: inputs handled in the order offered, never two at once, a burst
queued and bounded, drops counted, a failing item reported and the next one handled."""

from __future__ import annotations

import threading
import time

import pytest

from services.runtime.worker import BoundedWorker


def _worker(inline: bool, handler, maxsize=10_000):
    dropped, failed = [], []
    w = BoundedWorker("t", handler, maxsize, dropped.append, lambda item, exc: failed.append((item, str(exc))),
                      inline=inline)
    return w, dropped, failed


@pytest.mark.parametrize("inline", [False, True])
def test_order_kept_and_never_two_at_once_with_concurrent_offers(inline):
    seen: list[tuple[int, int]] = []
    running = threading.Lock()
    overlaps = []

    def handler(item):
        if not running.acquire(blocking=False):
            overlaps.append(item)
            return
        try:
            if item[1] % 97 == 0:
                time.sleep(0.002)  # now and then a slow one: the others queue behind it
            seen.append(item)
        finally:
            running.release()

    w, dropped, _ = _worker(inline, handler)
    w.start()
    threads = [threading.Thread(target=lambda p=p: [w.offer((p, i)) for i in range(3000)]) for p in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    deadline = time.monotonic() + 20
    while len(seen) < 9000 and time.monotonic() < deadline:
        time.sleep(0.01)
    w.stop()
    assert not overlaps and not dropped and len(seen) == 9000
    for p in range(3):  # each producer's items in its order
        assert [i for q, i in seen if q == p] == list(range(3000))


def test_inline_handles_on_the_offering_thread_when_idle_and_queues_when_busy():
    where = []
    gate = threading.Event()

    def handler(item):
        where.append((item, threading.current_thread().name))
        if item == "slow":
            gate.wait(5)

    w, dropped, failed = _worker(True, handler, maxsize=2)
    w.start()
    assert w.offer("a") and where == [("a", threading.current_thread().name)]  # inline, at once
    t = threading.Thread(target=w.offer, args=("slow",), name="zenoh-cb")
    t.start()
    while not where or where[-1][0] != "slow":
        time.sleep(0.001)
    assert w.offer("b") and w.offer("c")  # the handler is busy: queued, for the worker
    assert not w.offer("d") and dropped == ["d"]  # bounded as ever, the drop counted
    gate.set()
    t.join(5)
    deadline = time.monotonic() + 5
    while len(where) < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [x for x, _ in where] == ["a", "slow", "b", "c"]
    assert {n for x, n in where if x in ("b", "c")} == {"worker-t"}
    w.stop()
    assert not failed


def test_a_failing_item_is_reported_and_the_next_handled_inline():
    out = []

    def handler(item):
        if item == 2:
            raise ValueError("bad")
        out.append(item)

    w, _, failed = _worker(True, handler)
    w.start()
    for i in range(4):
        w.offer(i)
    w.stop()
    assert out == [0, 1, 3] and failed == [(2, "bad")]
