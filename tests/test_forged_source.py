"""A publisher that sends valid samples for a vehicle it is not, on a router without access control.

Real processes: a router and the gateway of ``rover1`` on an ephemeral loopback port; the vehicle is a
client session publishing a simulated drive at 100 Hz; the forger is another session publishing
valid samples of ``rover1`` (right id, right key, finite, in range) whose seqs run ahead of the
vehicle's.  Without authentication the gateway cannot tell whose sample is whose, but it can tell
that two streams share the key: the samples of one of them are refused for their order while the
other is live (``SampleValidator.conflicts``).  ``soilocp fleet status --json`` must show none for the
vehicle alone and for the vehicle restarting (a new session from seq 1 after its old one went quiet),
and must flag the forger (``second_source``, ``source_conflicts``) once it publishes.  Under mutual
TLS and access control the forger is refused by the router instead (tests/test_fleet_security.py).
"""

from __future__ import annotations

import threading
import time

import zenoh

from soilocp.schemas import keys
from soilocp.services.bench.stages import simulate_drive
from zenoh_helpers import Procs, client, endpoint, fleet_status, free_port, wait_alive, wait_for

VID = "rover1"


class Publisher(threading.Thread):
    """Puts ``payloads`` on the vehicle's raw key at ``rate`` Hz until they run out or ``stop``."""

    def __init__(self, session, payloads: list[bytes], rate: float):
        super().__init__(daemon=True)
        self.pub = session.declare_publisher(keys.raw(VID), congestion_control=zenoh.CongestionControl.BLOCK)
        self.payloads, self.rate = payloads, rate
        self.stop = threading.Event()
        self.sent = 0

    def run(self) -> None:
        t0 = time.monotonic()
        for k, p in enumerate(self.payloads):
            if self.stop.wait(max(0.0, t0 + k / self.rate - time.monotonic())):
                return
            self.pub.put(p)
            self.sent += 1


def test_a_second_publisher_of_a_vehicle_is_flagged_in_fleet_status(tmp_path):
    drive = simulate_drive(VID, 12.0)
    own = [s.model_dump_json().encode() for s in drive]
    # valid samples of the same vehicle, 500 seqs and 5 s ahead of its own
    forged = [s.model_copy(update={"seq": s.seq + 500, "stamp": s.stamp + 5.0}).model_dump_json().encode()
              for s in drive[300:]]
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("gateway", ["service", "gateway", "--vehicle-id", VID, "--connect", ep])
        with client(ep) as vehicle, client(ep) as forger:
            assert wait_alive(vehicle, VID, ["gateway"], timeout=60), procs.tail("gateway")
            # the vehicle alone, 2 s; then it restarts: quiet for 1 s, and a new session from seq 1
            p = Publisher(vehicle, own[:200], 100.0)
            p.run()
            time.sleep(1.0)
            p = Publisher(vehicle, own[:300], 100.0)
            p.run()
            alone, _ = fleet_status(ep, VID)
            assert alone["source_conflicts"] == 0 and not alone["second_source"], alone
            assert alone["rejections"] > 0, alone  # the restart's first samples, refused until adopted
            # the vehicle goes on; the forger joins it on the same key
            p = Publisher(vehicle, own[300:], 100.0)
            f = Publisher(forger, forged, 20.0)
            p.start()
            f.start()
            assert wait_for(lambda: f.sent >= 40, 30)
            both, table = fleet_status(ep, VID)
            p.stop.set()
            f.stop.set()
            p.join(5)
            f.join(5)
        assert both["second_source"] and both["source_conflicts"] >= 20, both
        assert "2nd source" in table, table
        print(f"\nvehicle alone and restarting: {alone['rejections']} rejections, source_conflicts "
              f"{alone['source_conflicts']}; with a forger ({f.sent} forged samples beside {p.sent} of the "
              f"vehicle's): {both['rejections']} rejections, source_conflicts {both['source_conflicts']}")
    finally:
        procs.close()
