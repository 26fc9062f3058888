"""The fleet soil map behind the secure fleet router (mutual TLS + access control, docs/map.md):
a map service with its own certificate (CN = the map id) reads every vehicle's soil estimates and
answers the dashboard; a vehicle writes only its own estimates (another vehicle's key is dropped by
the router, another vehicle's id on its own key is rejected by the map service) and cannot write
the map's keys; a dashboard only reads.  Negative checks wait for a positive control sent after
the forbidden message (it must arrive), then a grace period."""

from __future__ import annotations

import time

import pytest

from map_helpers import estimate
from soilocp.schemas import keys
from soilocp.schemas.map import MapCellUpdate, MapQueryReply, MapRejection
from test_fleet_security import FLEET_SECURE, GRACE_S, Inbox, SecureFleet, _certs
from zenoh_helpers import wait_for


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    base = tmp_path_factory.mktemp("secure-map")
    f = SecureFleet(base)
    _certs(f.certs, "issue", str(f.certs), "fleet")  # the map service's certificate: CN = its map id
    try:
        f.procs.spawn("fleet-router", ["router", "--config", str(FLEET_SECURE)],
                      env={"SOILOCP_LISTEN": f.ep, "SOILOCP_FLEET_MAPS": "fleet", **f.env("fleet-router")})
        assert wait_for(lambda: '"event": "running"' in f.procs.log_text("fleet-router")
                        or f.procs.procs["fleet-router"].poll() is not None, 60), "fleet router did not start"
        assert f.procs.procs["fleet-router"].poll() is None, f.procs.log_text("fleet-router")
        f.procs.spawn("map", ["service", "map", "--map-id", "fleet", "--connect", f.ep,
                              "--store", f"sqlite:{base / 'map.db'}"], env=f.env("fleet"))
        yield f
    finally:
        f.procs.close(timeout=20.0)


def _put_est(session, key_vid: str, vid: str, seq: int, k: float, x: float) -> None:
    session.put(keys.soil(key_vid), estimate(vid, seq, k, 0.1, xy=((x, 1.0),), frame="sec").model_dump_json())


def test_map_service_behind_the_secure_fleet_router(fleet):
    cells, rejected, forged = Inbox(), Inbox(), Inbox()
    with fleet.session("dashboard") as dash, fleet.session("dashboard") as watcher, fleet.session("rover1") as r1, \
            fleet.session("rover2") as r2:
        # a second dashboard session watches (a session's own puts are delivered to it locally, never via the router)
        watcher.declare_subscriber(keys.map_key("fleet", "cells"), cells)
        watcher.declare_subscriber(keys.map_key("fleet", "rejected"), rejected)
        watcher.declare_subscriber(keys.map_key("fleet", "status"), forged)
        assert wait_for(lambda: list(dash.liveliness().get(keys.map_key("fleet", "alive"), timeout=1)), 60), \
            fleet.procs.tail("map")
        time.sleep(1.0)  # the map's subscription reaches the vehicles through the router

        def acked() -> dict[str, int]:
            out: dict[str, int] = {}
            for _k, p in cells.items:
                for v, (_s, n) in MapCellUpdate.model_validate_json(p).applied.items():
                    out[v] = max(out.get(v, 0), n)
            return out

        # a vehicle's own estimate reaches the map and is acknowledged (the dashboard reads the acknowledgement)
        _put_est(r1, "rover1", "rover1", 1, 50.0, 1.0)
        assert wait_for(lambda: acked().get("rover1") == 1, 30), fleet.procs.tail("map")
        # rover1 under rover2's key: the router drops it; rover1 naming rover2 on its own key: the map rejects it;
        # rover1 and the dashboard forging the map's own keys: dropped.  Control: rover2's own estimate.
        _put_est(r1, "rover2", "rover2", 5, 300.0, 11.0)
        _put_est(r1, "rover1", "rover2", 6, 300.0, 16.0)
        r1.put(keys.map_key("fleet", "status"), b'{"forged": "by rover1"}')
        dash.put(keys.map_key("fleet", "status"), b'{"forged": "by the dashboard"}')
        dash.put(keys.soil("rover1"), estimate("rover1", 7, 300.0, 0.1, xy=((21.0, 1.0),), frame="sec").model_dump_json())
        _put_est(r2, "rover2", "rover2", 1, 80.0, 6.0)
        assert wait_for(lambda: acked().get("rover2") == 1, 30), fleet.procs.tail("map")
        assert wait_for(lambda: rejected.items, 10)
        time.sleep(GRACE_S)
        (rej,) = [MapRejection.model_validate_json(p) for _k, p in rejected.items]
        assert rej.code == "vehicle_mismatch" and rej.vehicle_id == "rover1"
        assert acked() == {"rover1": 1, "rover2": 1}  # nothing forged was committed
        assert forged.items and all(b"forged" not in p for _k, p in forged.items)  # the map's own status did arrive

        # the dashboard reads the map; what it holds is only the two vehicles' own estimates
        reps = [r.ok.payload.to_bytes() for r in dash.get(keys.map_key("fleet", "query") + "?frame=sec;bbox=0,0,30,5",
                                                          timeout=5) if r.ok is not None]
        got = {c.cell: (round(c.K), c.vehicles) for c in MapQueryReply.model_validate_json(reps[0]).cells}
        assert got == {"sec/5/0/0": (50, ["rover1"]), "sec/5/1/0": (80, ["rover2"])}, got
        # a vehicle cannot read the map (vehicles get nothing from the fleet but interest)
        assert [r for r in r1.get(keys.map_key("fleet", "query") + "?frame=sec;bbox=0,0,30,5", timeout=2)
                if r.ok is not None] == []
