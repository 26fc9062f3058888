"""The map service as an OS process over a real Zenoh router: kill -9 during updates loses no
acknowledged update (SQLite and PostgreSQL), bad estimates are rejected with a reason and
counted over Zenoh, and ``soilocp map query`` / ``export --geojson`` read it (docs/map.md)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time

import pytest

from map_helpers import estimate
from soilocp.schemas import keys
from soilocp.schemas.map import MapCellUpdate, MapRejection
from soilocp.map.store import open_store
from zenoh_helpers import Procs, client, endpoint, free_port, wait_for


def _map_alive(s, map_id: str, timeout: float = 60.0) -> bool:
    return bool(wait_for(lambda: list(s.liveliness().get(keys.map_key(map_id, "alive"), timeout=1)), timeout))


class Acks:
    """What the map service acknowledged: per vehicle its committed total, per cell its count and vehicles."""

    def __init__(self):
        self.lock = threading.Lock()
        self.totals: dict[str, int] = {}
        self.cells: dict[str, tuple[int, set]] = {}
        self.batches = 0

    def __call__(self, sample) -> None:
        m = MapCellUpdate.model_validate_json(sample.payload.to_bytes())
        with self.lock:
            self.batches += 1
            for v, (_seq, total) in m.applied.items():
                self.totals[v] = max(self.totals.get(v, 0), total)
            for c in m.cells:
                n, vs = self.cells.get(c.cell, (0, set()))
                self.cells[c.cell] = (max(n, c.count), vs | set(c.vehicles))


def _flood(ep: str, stop: threading.Event, sent: list, seed: int = 0) -> None:
    """Three vehicles publish estimates over a 60 m x 60 m area as fast as the link takes them."""
    import zenoh

    rng = random.Random(seed)
    with client(ep) as s:
        pubs = {v: s.declare_publisher(keys.soil(v), congestion_control=zenoh.CongestionControl.BLOCK)
                for v in ("v1", "v2", "v3")}
        seq = 0
        while not stop.is_set():
            seq += 1
            for v, p in pubs.items():
                p.put(estimate(v, seq, rng.uniform(40, 300), rng.uniform(0.05, 0.5),
                               xy=((rng.uniform(0, 60), rng.uniform(0, 60)),)).model_dump_json())
            sent[0] += 3
        for p in pubs.values():
            p.undeclare()


def _kill9_run(tmp_path, store_url: str) -> None:
    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    stop = threading.Event()
    sent = [0]
    try:
        procs.spawn("router", ["router", "--listen", ep])
        proc = procs.spawn("map", ["service", "map", "--map-id", "k", "--connect", ep, "--store", store_url])
        acks = Acks()
        with client(ep) as s:
            sub = s.declare_subscriber(keys.map_key("k", "cells"), acks)
            assert _map_alive(s, "k"), procs.tail("map")
            flood = threading.Thread(target=_flood, args=(ep, stop, sent), daemon=True)
            flood.start()
            # kill -9 while the estimates pour in, after some batches were acknowledged
            assert wait_for(lambda: acks.batches >= 8 and sum(acks.totals.values()) >= 2000, 120), procs.tail("map")
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(10)
            with acks.lock:
                totals, cells = dict(acks.totals), dict(acks.cells)
            stop.set()
            flood.join(30)
            sub.undeclare()
        assert proc.returncode == -signal.SIGKILL
        st = open_store(store_url)
        ledger = st.ledger()
        got = {c.cell: c for c in st.all_cells(time.time())}
        st.close()
        print(f"kill -9 after {sum(totals.values())} acknowledged of {sent[0]} sent; store holds "
              f"{sum(n for _s, n in ledger.values())}; {len(cells)} acknowledged cells")
        for v, n in totals.items():
            assert ledger[v][1] >= n, (v, ledger, totals)
        for cell, (n, vs) in cells.items():
            assert cell in got and got[cell].count >= n and set(got[cell].vehicles) >= vs, (cell, got.get(cell), n, vs)
        # the service comes back on the same store and keeps counting from what was committed
        procs.spawn("map2", ["service", "map", "--map-id", "k", "--connect", ep, "--store", store_url])
        acks2 = Acks()
        with client(ep) as s:
            sub = s.declare_subscriber(keys.map_key("k", "cells"), acks2)
            assert _map_alive(s, "k"), procs.tail("map2")
            s.put(keys.soil("v1"), estimate("v1", 10**6, 77.0, 0.1, xy=((1.0, 1.0),)).model_dump_json())
            assert wait_for(lambda: acks2.totals.get("v1"), 30), procs.tail("map2")
            sub.undeclare()
        assert acks2.totals["v1"] == ledger["v1"][1] + 1
    finally:
        stop.set()
        procs.close()


def test_kill9_sqlite_loses_no_acknowledged_update(tmp_path):
    _kill9_run(tmp_path, f"sqlite:{tmp_path / 'map.db'}")


def test_kill9_postgresql_loses_no_acknowledged_update(tmp_path):
    from pg_helpers import APT_HINT, PgServer, pg_bindir

    if pg_bindir() is None:
        pytest.skip(f"PostgreSQL + PostGIS not installed: CI installs them with `{APT_HINT}`")
    pg = PgServer(free_port()).start()
    try:
        _kill9_run(tmp_path, pg.new_database("kill9"))
    finally:
        pg.stop()


def _cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "soilocp.cli", *args], capture_output=True, text=True, timeout=timeout)


def test_rejections_status_query_and_export(tmp_path):
    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    db = f"sqlite:{tmp_path / 'map.db'}"
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store", db, "--cell-size", "2"])
        rejected, acks = [], Acks()
        with client(ep) as s:
            subs = [s.declare_subscriber(keys.map_key("m", "rejected"),
                                         lambda x: rejected.append(MapRejection.model_validate_json(x.payload.to_bytes()))),
                    s.declare_subscriber(keys.map_key("m", "cells"), acks)]
            assert _map_alive(s, "m"), procs.tail("map")
            good = estimate("r1", 1, 120.0, 0.2, xy=((3.0, 3.0), (3.5, 3.0)))
            s.put(keys.soil("r1"), good.model_dump_json())
            s.put(keys.soil("r1"), b"\x00garbage")
            s.put(keys.soil("r1"), estimate("r2", 2, 80.0).model_dump_json())  # r1 writing r2's estimate
            s.put(keys.soil("r1"), good.model_dump_json().replace('"soil_strength":120.0', '"soil_strength":-1.0'))
            s.put(keys.soil("r1"), estimate("r1", 3, 50.0, status="not_observable").model_dump_json())
            assert wait_for(lambda: len(rejected) >= 3 and acks.totals.get("r1"), 30), procs.tail("map")
            assert [r.code for r in rejected] == ["malformed_json", "vehicle_mismatch", "out_of_range"]
            assert all(r.vehicle_id == "r1" and r.key == keys.soil("r1") and r.message for r in rejected)
            assert rejected[2].field == "soil_strength"

            def status():
                out = [json.loads(r.ok.payload.to_bytes()) for r in s.get(keys.map_key("m", "status"), timeout=3)
                       if r.ok is not None]
                return out[0] if out and out[0]["received"] >= 5 and out[0]["skipped"] else None

            st = wait_for(status, 20)
            assert st["applied"] == 1 and st["skipped"] == {"status_not_observable": 1}
            assert st["rejected"] == {"malformed_json": 1, "vehicle_mismatch": 1, "out_of_range": 1}
            # a query with a bad box is refused with a reason
            errs = [r.err.payload.to_string() for r in s.get(keys.map_key("m", "query") + "?frame=f;bbox=1,2,x", timeout=3)
                    if r.err is not None]
            assert errs and "bbox" in errs[0]
            for sub in subs:
                sub.undeclare()
        q = _cli("map", "query", "--connect", ep, "--map-id", "m", "--frame", "f", "--bbox", "0,0,10,10", "--json")
        assert q.returncode == 0, q.stderr
        cells = json.loads(q.stdout)["cells"]
        assert [c["cell"] for c in cells] == ["f/2/1/1"] and cells[0]["K"] == pytest.approx(120.0, rel=1e-3)
        assert cells[0]["count"] == 1 and cells[0]["vehicles"] == ["r1"]
        out = tmp_path / "map.geojson"
        e = _cli("map", "export", "--store", db, "--geojson", str(out))
        assert e.returncode == 0, e.stderr
        gj = json.loads(out.read_text())
        (f,) = gj["features"]
        assert gj["type"] == "FeatureCollection" and gj["soilocp_frame"] == "f"
        assert f["geometry"]["coordinates"][0] == [[2.0, 2.0], [4.0, 2.0], [4.0, 4.0], [2.0, 4.0], [2.0, 2.0]]
        from soilocp.model.ocp import ocp_from_soil_strength

        assert f["properties"]["mu_T"] == pytest.approx(ocp_from_soil_strength(f["properties"]["K"]).mu_T)
        bad = _cli("map", "query", "--connect", endpoint(free_port()), "--bbox", "0,0,1,1", "--timeout", "1")
        assert bad.returncode == 1 and "no router answered" in bad.stderr
    finally:
        procs.close()


def test_a_query_after_an_acknowledgement_sees_it(tmp_path):
    """Box replies are laid out in memory and answered in the Zenoh callback while nothing was
    committed since; a commit marks them out of date before it is acknowledged, so a query sent
    on the acknowledgement finds the new cell, every time (and queries in between, none
    changed, answer the same cells)."""
    from soilocp.schemas.map import MapQueryReply

    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store",
                            f"sqlite:{tmp_path / 'map.db'}", "--cell-size", "2"])
        acks, acked = Acks(), threading.Event()

        def on_ack(sample):
            acks(sample)
            acked.set()

        sel = keys.map_key("m", "query") + "?frame=f;bbox=0,0,100,100"
        with client(ep) as s:
            sub = s.declare_subscriber(keys.map_key("m", "cells"), on_ack)
            assert _map_alive(s, "m"), procs.tail("map")

            def cells():
                (r,) = [MapQueryReply.model_validate_json(x.ok.payload.to_bytes()) for x in s.get(sel, timeout=5)]
                return r.columns.cell

            assert cells() == []
            for i in range(1, 16):
                acked.clear()
                s.put(keys.soil("r1"), estimate("r1", i, 100.0 + i, 0.2, xy=((2.0 * i + 1, 1.0),)).model_dump_json())
                assert acked.wait(20) and acks.totals.get("r1") == i, procs.tail("map")
                got = cells()  # sent on the acknowledgement
                assert got == [f"f/2/{j}/0" for j in range(1, i + 1)], (i, got)
                assert cells() == got  # nothing committed since: the same
            sub.undeclare()
    finally:
        procs.close()


@pytest.mark.e2e
def test_live_vehicle_services_feed_the_map(tmp_path):
    """`soilocp run --synthetic mixed` with a start pose (SOILOCP_START_POSE): the live observer and
    soil-strength services carry the places, the map service fuses them; its cells hold sand then
    gravel along the drive."""
    from soilocp.sim.scenarios import get_scenario

    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "live", "--connect", ep, "--store", f"sqlite:{tmp_path / 'm.db'}"])
        with client(ep) as s:
            assert _map_alive(s, "live"), procs.tail("map")
        vport = free_port()
        run = procs.spawn("rover", ["run", "--synthetic", "mixed", "--vehicle-id", "rover1", "--duration", "24",
                                    "--listen", endpoint(vport), "--plain"],
                          env={"SOILOCP_START_POSE": "field:0,0,0", "SOILOCP_ROUTER_CONNECT": ep})
        run.wait(240)
        assert run.returncode == 0, procs.tail("rover", 40)
        time.sleep(1.0)
        st = open_store(f"sqlite:{tmp_path / 'm.db'}")
        cells = {c.cell: c for c in st.all_cells(time.time(), "field")}
        st.close()
        print({k: (round(c.K, 1), round(c.K_lo, 1), round(c.K_hi, 1), c.count) for k, c in cells.items()})
        segs = get_scenario("mixed").segments
        sand, gravel = segs[0].soil_strength, segs[1].soil_strength
        # the drive runs along y = 0: wheels on both sides of it, cell rows iy = -1 and 0
        for ix, k_true in ((1, sand), (3, gravel)):
            for iy in (-1, 0):
                c = cells[f"field/5/{ix}/{iy}"]
                assert abs(c.K / k_true - 1) < 0.15 and c.K_lo <= k_true <= c.K_hi, c
                assert c.vehicles == ["rover1"]
    finally:
        procs.close()


def test_live_soil_strength_starts_from_the_map(tmp_path):
    """Opt-in map prior, real processes: a map service holds cells along the drive (K = 123, a value
    no soil of the drive has); `soilocp run` with SOILOCP_MAP_PRIOR=<map id>: the soil-strength
    service asks the map for the cells around the vehicle and starts its belief from them as the
    vehicle enters each (counted in its health, logged with the map's K)."""
    from map_helpers import item
    from soilocp.map.updater import MapUpdater

    db = tmp_path / "m.db"
    st = open_store(f"sqlite:{db}")
    MapUpdater(st).apply([item(estimate("mapper", i + 1, 123.0, 0.1, xy=((x + 2.5, y + 2.5),), frame="field"))
                          for i, (x, y) in enumerate((x, y) for x in range(-10, 100, 5) for y in (-10, -5, 0, 5))])
    st.close()
    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store", f"sqlite:{db}"])
        with client(ep) as s:
            assert _map_alive(s, "m"), procs.tail("map")
            status: list[dict] = []
            sub = s.declare_subscriber(keys.status("rover1", "soil-strength"),
                                       lambda x: status.append(json.loads(x.payload.to_bytes())))
            run = procs.spawn("rover", ["run", "--synthetic", "mixed", "--vehicle-id", "rover1", "--duration", "18",
                                        "--listen", endpoint(free_port()), "--plain", "--log-dir", str(tmp_path / "run")],
                              env={"SOILOCP_START_POSE": "field:0,0,0", "SOILOCP_ROUTER_CONNECT": ep,
                                   "SOILOCP_MAP_PRIOR": "m"})
            run.wait(240)
            sub.undeclare()
        assert run.returncode == 0, procs.tail("rover", 40)
        (log,) = list((tmp_path / "run").rglob("soil-strength*.log"))
        events = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
        asked = [e for e in events if e.get("event") == "map_prior_cells"]
        used = [e for e in events if e.get("event") == "map_prior_used"]
        assert asked and asked[0]["cells"] >= 20 and asked[0]["frame"] == "field", log.read_text()[-2000:]
        # at 1 m/s over ~18 s: the front axle enters the 5 m cells at x = 5, 10, 15 m (the map's answer
        # may come after the first), once each, not at every wobble over the border y = 0
        assert len(used) >= 2, log.read_text()[-2000:]
        assert all(e["K"] == pytest.approx(123.0, rel=1e-6) and e["cell"].startswith("field/5/") for e in used)
        assert len({e["cell"].rsplit("/", 2)[1] for e in used}) == len(used)  # one entry per column
        details = [h["detail"] for h in status if "map_prior_entered" in h.get("detail", {})]
        assert details and max(d["map_prior_entered"] for d in details) >= 1, status[-1:] if status else "no status"
        assert max(d["map_prior_queries"] for d in details) >= 1
    finally:
        procs.close()
