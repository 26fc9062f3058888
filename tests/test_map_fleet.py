"""A simulated fleet of three vehicles crosses a mixed field; the map's cells match the field's
truth, and two live map services (one on SQLite, one on PostgreSQL + PostGIS) that hear the same
fleet over Zenoh hold the same cells (docs/map.md)."""

from __future__ import annotations

import json
import threading
import time

import pytest

from soilocp.schemas import keys
from soilocp.schemas.map import MapCellUpdate
from soilocp.analysis.fleet_map import fleet_drives, map_items, mixed_field, score_cells
from soilocp.map.fusion import FusionConfig
from soilocp.map.store import open_store
from soilocp.map.updater import MapUpdater
from zenoh_helpers import Procs, client, endpoint, free_port, wait_count, wait_for

T0 = 1_800_000_000.0

pytestmark = pytest.mark.e2e  # three 40 s drives through the estimator: ~1 min on a quiet 2-core machine


@pytest.fixture(scope="module")
def drives():
    return fleet_drives(40.0, seed=0, jobs=2)


def test_fleet_map_matches_the_field(drives, tmp_path):
    st = open_store(f"sqlite:{tmp_path / 'fleet.db'}")
    up = MapUpdater(st)
    items = map_items(drives, T0)
    for i in range(0, len(items), 1000):
        up.apply(items[i:i + 1000])
    cells = st.all_cells(T0 + 60.0)
    score = score_cells(cells, mixed_field())
    print(f"fleet map: {score.cells} cells, median |K error| {score.median_error:.3f}, 95 % band coverage "
          f"{score.coverage:.2f}; worst {score.worst}")
    # every vehicle mapped its row of 5 m cells across two regions (8 cells each; two crossings shared)
    assert score.cells >= 20
    assert {v for c in cells for v in c.vehicles} == {"alpha", "bravo", "charlie"}
    assert any(len(c.vehicles) == 2 for c in cells)
    assert score.median_error <= 0.10
    assert score.coverage >= 0.90
    # the regions are told apart: each cell's K is nearest its own region's K among the four soils
    soils = {50.0, 80.0, 200.0, 300.0}
    for c in cells:
        k_true = mixed_field().soil_at(*c.center)[1]
        assert min(soils, key=lambda k: abs(c.K / k - 1)) == k_true, c


def _publish_fleet(ep: str, drives, every: int = 1) -> int:
    """Publish each vehicle's soil estimates on its own key, the vehicles interleaved in time."""
    import zenoh

    with client(ep) as s:
        # reliable and blocking, as the soil-strength service publishes (soilocp.services.runtime.service)
        pubs = {d.vehicle_id: s.declare_publisher(keys.soil(d.vehicle_id),
                                                  congestion_control=zenoh.CongestionControl.BLOCK) for d in drives}
        n = 0
        for key, payload, _t in map_items(drives, T0)[::every]:
            vid = keys.split_key(key)[0]
            pubs[vid].put(payload)
            n += 1
        time.sleep(1.0)  # let the last batches leave before the session closes
        for p in pubs.values():
            p.undeclare()
    return n


def test_two_live_map_services_converge(drives, tmp_path):
    from pg_helpers import APT_HINT, PgServer, pg_bindir

    if pg_bindir() is None:
        pytest.skip(f"PostgreSQL + PostGIS not installed: CI installs them with `{APT_HINT}`")
    pg = PgServer(free_port()).start()
    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    try:
        pg_url = pg.new_database("fleet")
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map-a", ["service", "map", "--map-id", "a", "--connect", ep, "--store", f"sqlite:{tmp_path / 'a.db'}"])
        procs.spawn("map-b", ["service", "map", "--map-id", "b", "--connect", ep, "--store", pg_url])
        with client(ep) as s:
            acks = {"a": {}, "b": {}}
            lock = threading.Lock()

            def on_cells(sample):
                m = MapCellUpdate.model_validate_json(sample.payload.to_bytes())
                with lock:
                    for v, (_seq, total) in m.applied.items():
                        acks[m.map_id][v] = max(acks[m.map_id].get(v, 0), total)

            subs = [s.declare_subscriber(keys.map_key(m, "cells"), on_cells) for m in "ab"]
            assert wait_for(lambda: all(list(s.liveliness().get(keys.map_key(m, "alive"), timeout=1)) for m in "ab"), 60)
            n = _publish_fleet(ep, drives)
            # what the library map makes of the same estimates: the number each service must acknowledge
            ref = MapUpdater(open_store(f"sqlite:{tmp_path / 'ref.db'}"))
            ref.apply(map_items(drives, T0))
            want = ref.store.ledger()
            for m in "ab":
                assert wait_count(lambda m=m: sum(acks[m].values()), sum(n for _s, n in want.values()),
                                  stall_s=30, overall_s=120), (acks, want, procs.tail(f"map-{m}"))
            for sub in subs:
                sub.undeclare()
            # ask both over Zenoh for the whole field
            from soilocp.services.map.client import query_map

            now_cells = {}
            for m in "ab":
                rep = query_map([ep], m, "field", (-10, -10, 50, 50), session=s)
                now_cells[m] = rep.cells
            status = {m: json.loads(r.ok.payload.to_bytes()) for m in "ab"
                      for r in s.get(keys.map_key(m, "status"), timeout=3) if r.ok is not None}
        a, b = now_cells["a"], now_cells["b"]
        a, b = sorted(a, key=lambda c: c.cell), sorted(b, key=lambda c: c.cell)
        assert [c.cell for c in a] == [c.cell for c in b] == [c.cell for c in ref.store.all_cells(T0)]
        for ca, cb in zip(a, b):
            # same estimates per (cell, vehicle); only the ageing clocks differ (each service's receive
            # times and the two queries' times): on a loaded 2-core machine by up to a few seconds, which
            # moves the variance by q per second of difference and nothing else
            assert (ca.count, ca.vehicles) == (cb.count, cb.vehicles)
            assert ca.K == pytest.approx(cb.K, rel=1e-6)
            assert abs(ca.log_k_std ** 2 - cb.log_k_std ** 2) <= FusionConfig().ageing_rate / 3600.0 * 5.0
        sa = open_store(f"sqlite:{tmp_path / 'a.db'}")
        sb = open_store(pg_url)
        rows_a, rows_b = sa.obs_rows(), sb.obs_rows()
        assert [r[:6] for r in rows_a] == [r[:6] for r in rows_b] == [r[:6] for r in ref.store.obs_rows()]
        assert [r[6] for r in rows_a] == [r[6] for r in rows_b]
        sa.close(), sb.close()
        assert score_cells(a, mixed_field()).median_error <= 0.10
        for m in "ab":
            assert status[m]["received"] == n and status[m]["dropped"] == 0 and status[m]["rejected"] == {}
    finally:
        procs.close()
        pg.stop()


@pytest.mark.parametrize("vid", ["bravo2", "charlie2"])
def test_a_vehicle_that_trusts_the_map_converges_at_once_after_a_terrain_change(drives, tmp_path, vid):
    """Second pass over bravo's row (gravel -> firm) and charlie's column (grass -> firm: the rear
    axle still on grass when the front enters the firm cell), the same samples through two
    estimators: one starts its belief from the map on entering each mapped cell, one does not."""
    from soilocp.analysis.fleet_map import SECOND_PASSES, second_pass

    st = open_store(f"sqlite:{tmp_path / 'fleet.db'}")
    up = MapUpdater(st)
    up.apply(map_items(drives, T0))
    start, length, seed = SECOND_PASSES[vid]
    r = second_pass(st.all_cells(T0 + 60.0), vid, start, length, seed=seed)
    print(f"second pass {vid}: K within 10 % of {r.k_new:g} for 1 s after {r.with_map_s:.2f} s with the map, "
          f"{r.without_map_s:.2f} s without ({r.priors_given} cells entered)")
    assert r.k_new == 300.0 and r.priors_given >= 4
    assert r.without_map_s >= 3 * r.with_map_s and r.without_map_s > 0.1
