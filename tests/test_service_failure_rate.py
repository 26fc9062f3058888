"""A live service fed a poisoned stretch stays alive, says it is failing (health state and failure
rate, not just liveliness), and recovers when good inputs return: real router, real processes."""

from __future__ import annotations

import time

import pytest
import zenoh

from soilocp.schemas import keys
from soilocp.schemas.messages import ServiceHealth
from zenoh_helpers import Procs, client, endpoint, free_port, get_payloads, wait_alive, wait_for, write_log

pytestmark = pytest.mark.timeout(240)


def _health(session, vid: str, svc: str):
    got = get_payloads(session, keys.status(vid, svc), timeout=3.0)
    return ServiceHealth.model_validate_json(got[0]) if got else None


def test_poisoned_stretch_observer_reports_failing_then_recovers(tmp_path):
    vid = "poison1"
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    lines = write_log(tmp_path / "drive.jsonl", vid, duration=6.0, scenario="sand")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        for name in ("normal-force", "observer"):
            procs.spawn(name, ["service", name, "--vehicle-id", vid, "--connect", ep])
        with client(ep) as s:
            assert wait_alive(s, vid, ("normal-force", "observer"), timeout=120.0)
            outputs = []
            sub = s.declare_subscriber(keys.observer(vid), lambda smp: outputs.append(1))
            pub = s.declare_publisher(keys.clean(vid), congestion_control=zenoh.CongestionControl.BLOCK)
            time.sleep(0.3)

            def feed(chunk):
                for line in chunk:
                    pub.put(line)
                    time.sleep(0.004)

            feed(lines[:150])
            assert wait_for(lambda: len(outputs) >= 150, 60.0), len(outputs)
            h = _health(s, vid, "observer")
            assert h is not None and h.state == "running" and h.errors == 0

            # the poisoned stretch: inputs the observer cannot process (not a sensor sample)
            for i in range(60):
                pub.put(b'{"vehicle_id": "poison1", "seq": "not a number"}' if i % 2 else b"\x00garbage")
                time.sleep(0.004)
            h = wait_for(lambda: (x := _health(s, vid, "observer")) and x.errors >= 60 and x, 30.0)
            assert h, "observer never counted the poisoned inputs"
            assert h.state == "failing" and h.failure_rate > 0.5, h
            assert procs.alive()["observer"]

            # good data again: the service recovers by itself and reports it
            before = len(outputs)
            feed(lines[150:450])
            assert wait_for(lambda: len(outputs) >= before + 300, 60.0), (before, len(outputs))
            h = wait_for(lambda: (x := _health(s, vid, "observer")) and x.state == "running" and x, 30.0)
            assert h and h.failure_rate < 0.1 and h.errors == 60, h
            sub.undeclare()
        assert all(procs.alive().values()), procs.alive()
    finally:
        procs.close()
