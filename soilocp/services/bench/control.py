"""Bench part 5: control-loop latency, sample -> slip set-point, through the deployed processes.

The router, the five pipeline services and the controller service (``--control ocp_traction``)
run as in ``soilocp run --control``; the bench plays the vehicle: it publishes a simulated drive's
samples on the raw key at 100 Hz and times each :class:`soilocp.schemas.messages.SlipSetpoint` that comes
back carrying a sample's seq (the set-point computed from that sample's OCP).  That is the loop a
closed-loop vehicle sees: six pipeline hops plus OCP -> controller -> vehicle (two more).
"""

from __future__ import annotations

import threading
import time
from typing import Any

from soilocp.schemas import keys

from soilocp.services.bench.live import Rig, _paced, _sleep_until, _wait_all, arrivals, open_client, summarize

CONTROL_HOPS = 8  # raw, clean, normal_forces, observer, soil, ocp, control/slip: client->router->client hops


def control_rig(vehicle_ids: list[str]) -> Rig:
    rig = Rig.standard(vehicle_ids)
    rig.services = [*rig.services, ("controller", "soilocp.cli", ["service", "controller", "--control", "ocp_traction"])]
    return rig


def control_loop_latency(payloads: list[tuple[int, bytes]], rate: float, duration: float,
                         warmup_s: float = 0.5, drain_s: float = 3.0, make_rig=control_rig) -> dict[str, Any]:
    """Publish ``(seq, payload)`` at ``rate`` Hz for vehicle ``bench`` and time the set-points (ms)
    through ``make_rig([vid])`` (the pipeline and the controller; :mod:`soilocp.services.bench.floor`'s relays)."""
    import zenoh

    vid = "bench"
    rig = make_rig([vid])
    sent: dict[int, float] = {}
    got: dict[int, float] = {}
    lock = threading.Lock()

    try:
        rig.start()
        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 90.0)
            sub = session.declare_subscriber(keys.control_slip(vid), arrivals(got, lock, first=True))
            pub = session.declare_publisher(keys.raw(vid), congestion_control=zenoh.CongestionControl.BLOCK)
            try:
                time.sleep(0.3)
                n = min(int(round(rate * duration)), len(payloads))
                t0 = time.perf_counter() + 0.05
                for k, _i, due in _paced(1, n, rate, t0):
                    _sleep_until(due)
                    seq, payload = payloads[k]
                    sent[seq] = time.perf_counter()
                    pub.put(payload)
                _wait_all(lambda: len(got) >= len(sent), drain_s)
            finally:
                sub.undeclare()
                pub.undeclare()
    finally:
        rig.stop()
    with lock:
        lat = [(got[s] - t) * 1e3 for s, t in sent.items() if s in got and t - t0 >= warmup_s]
        missing = sum(1 for s in sent if s not in got)
    st = summarize(lat)
    st.update(rate_hz=rate, sent=len(sent), received=len(sent) - missing, drops=missing, hops=CONTROL_HOPS)
    return st
