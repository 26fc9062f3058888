"""The one liveliness wait: which services of which vehicles hold their tokens
(``soilocp/<vid>/alive/<service>``), and waiting until a wanted set does.  Used by ``soilocp
run``, the bench, the synthetic vehicle (before it publishes) and the integration tests."""

from __future__ import annotations

import threading
import time
from typing import Callable, Collection, Iterable, Optional

from soilocp.schemas import keys


def alive_services(session, vehicle_id: Optional[str] = None, *, timeout: float = 1.0) -> set[tuple[str, str]]:
    """``{(vehicle_id, service)}`` holding a token now: one vehicle's, or every vehicle's."""
    selector = keys.any_vehicle_alive() if vehicle_id is None else keys.vehicle_alive_all(vehicle_id)
    seen: set[tuple[str, str]] = set()
    for reply in session.liveliness().get(selector, timeout=timeout):
        if reply.ok is not None:
            try:
                seen.add(keys.service_of_alive_key(str(reply.ok.key_expr)))
            except ValueError:  # a token under our keys that is not a service's: not ours to judge
                pass
    return seen


def wait_alive(session, vehicle_ids: Iterable[str], services: Iterable[str], timeout: float, *,
               stop: Optional[threading.Event] = None, dead: Callable[[], Collection[str]] = list,
               interval: float = 0.2) -> set[tuple[str, str]]:
    """Wait until every ``(vehicle, service)`` holds its token; returns what is still missing
    (empty: ready).  Gives up early when ``stop`` is set or ``dead()`` names a process."""
    vids = list(vehicle_ids)
    want = {(v, s) for v in vids for s in services}
    deadline = time.monotonic() + timeout
    while True:
        one = vids[0] if len(vids) == 1 else None
        missing = want - alive_services(session, one)
        if not missing or time.monotonic() > deadline or dead() or (stop is not None and stop.is_set()):
            return missing
        if stop is not None:
            stop.wait(interval)
        else:
            time.sleep(interval)
