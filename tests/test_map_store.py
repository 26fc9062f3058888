"""The fleet soil map's library: cells, fusion (inverse variance in ln K, ageing, latest estimate
per vehicle), refusals that never touch a cell, and the two stores (SQLite file; PostgreSQL +
PostGIS on a real server) giving the same cells whatever the order of arrival."""

from __future__ import annotations

import json
import math
import random

import pytest

from map_helpers import estimate, item
from soilocp.schemas.map import WGS84
from soilocp.map.cells import CellConfig, CellIndex, cell_polygon
from soilocp.map.fusion import BAND_Z, FusionConfig, fuse
from soilocp.map.store import SqliteStore, StoreError, open_store
from soilocp.map.updater import MapUpdater

NOW = 1_800_000_100.0


def _sqlite(tmp_path, name="m.db", **kw):
    return open_store(f"sqlite:{tmp_path / name}", CellConfig(**kw.get("cells", {})), FusionConfig(**kw.get("fusion", {})))


def test_square_and_h3_cells():
    ix = CellIndex(CellConfig(cell_size=5.0, h3_resolution=12))
    c = ix.local("field", 12.4, -0.1)
    assert (c.cell, c.cx, c.cy) == ("field/5/2/-1", 12.5, -2.5)
    assert cell_polygon(c.cell, c.frame)[:3] == [(10.0, -5.0), (15.0, -5.0), (15.0, 0.0)]
    g = ix.geo(46.5, 6.6)
    import h3

    assert g.cell == h3.latlng_to_cell(46.5, 6.6, 12) and g.frame == WGS84
    assert abs(g.cy - 46.5) < 1e-3 and abs(g.cx - 6.6) < 1e-3  # centre in (lon, lat)
    ring = cell_polygon(g.cell, WGS84)
    assert len(ring) == 7 and ring[0] == ring[-1]


def test_fusion_is_inverse_variance_in_ln_k_with_ageing():
    lk, var = fuse([math.log(50), math.log(80)], [0.01, 0.04], [NOW, NOW], NOW, 0.0)
    w1, w2 = 100.0, 25.0
    assert lk == pytest.approx((w1 * math.log(50) + w2 * math.log(80)) / (w1 + w2))
    assert var == pytest.approx(1 / (w1 + w2))
    # a row one day old has its variance grown by 24 h x rate: the fresh one dominates more
    lk_aged, var_aged = fuse([math.log(50), math.log(80)], [0.01, 0.04], [NOW - 86400, NOW], NOW, 0.02)
    assert var_aged == pytest.approx(1 / (1 / (0.01 + 0.48) + 25.0))
    assert abs(lk_aged - math.log(80)) < abs(lk - math.log(80))


def test_cells_fuse_vehicles_and_keep_each_vehicles_latest(tmp_path):
    st = _sqlite(tmp_path)
    up = MapUpdater(st)
    # rover1's running posterior in one cell: only its newest estimate counts (not 3x the information)
    res = up.apply([item(estimate("rover1", s, k, 0.2)) for s, k in ((1, 40.0), (2, 45.0), (3, 50.0))])
    assert res.applied == {"rover1": (3, 3)} and res.cells == ["f/5/0/0"] and not res.refused
    res = up.apply([item(estimate("rover2", 7, 60.0, 0.1))])
    (c,) = st.query_box("f", (0, 0, 5, 5), NOW)[0]
    t = 1_800_000_000.0  # when the map received them: fused then, and the fused variance aged to NOW
    lk, var = fuse([math.log(50.0), math.log(60.0)], [0.04, 0.01], [t, t], t, 0.0)
    var += FusionConfig().ageing_rate * (NOW - t) / 3600.0
    assert c.K == pytest.approx(math.exp(lk)) and c.log_k_std == pytest.approx(math.sqrt(var))
    assert c.K_lo == pytest.approx(math.exp(lk - BAND_Z * math.sqrt(var)))
    assert c.count == 4 and c.vehicles == ["rover1", "rover2"] and c.last_seen == 1_800_000_000.0
    # a patch in another cell opens it; an estimate on two wheels in two cells updates both
    up.apply([item(estimate("rover1", 9, 70.0, 0.1, xy=((4.0, 1.0), (6.0, 1.0))))])
    got = {c.cell: c for c in st.all_cells(NOW)}
    assert set(got) == {"f/5/0/0", "f/5/1/0"} and got["f/5/1/0"].K == pytest.approx(70.0)


def test_only_usable_estimates_update_cells(tmp_path):
    st = _sqlite(tmp_path)
    up = MapUpdater(st)
    res = up.apply([item(estimate("r", 1, 50.0, 0.1, status=s)) for s in
                    ("not_observable", "holding", "model_mismatch", "stale")]
                   + [item(estimate("r", 2, None, None, status="no_estimate")), item(estimate("r", 3, 50.0, xy=None))])
    assert st.all_cells(NOW) == [] and not res.refused
    assert dict(res.skipped) == {"status_not_observable": 1, "status_holding": 1, "status_model_mismatch": 1,
                                 "status_stale": 1, "status_no_estimate": 1, "no_place": 1}
    up.apply([item(estimate("r", 4, 50.0, 1.5, status="uncertain"))])  # uncertain, with its wide band
    (c,) = st.all_cells(NOW)
    assert c.log_k_std == pytest.approx(1.5, rel=1e-3)  # aged by 100 s
    assert c.K_hi / c.K_lo == pytest.approx(math.exp(2 * BAND_Z * c.log_k_std))


def _bad_payloads():
    good = json.loads(estimate("rover1", 50, 50.0).model_dump_json())

    def mod(**kw):
        d = json.loads(json.dumps(good))
        for k, v in kw.items():
            if v is KeyError:
                d.pop(k)
            else:
                d[k] = v
        return json.dumps(d).encode()

    where2 = dict(good["where"], xy=[[1.0, 1.0], [2.0, 2.0]])
    return [
        (b"\xff\xfe", "malformed_json"), (b"{not json", "malformed_json"), (b"[1,2]", "schema"),
        (mod(soil_strength=KeyError), "schema"), (mod(extra=1), "schema"),
        (mod(soil_strength=float("nan")), "non_finite"), (mod(log_k_std=float("inf")), "non_finite"),
        (mod(soil_strength=-5.0), "out_of_range"), (mod(soil_strength=1e9), "out_of_range"),
        (mod(log_k_std=0.0), "out_of_range"),
        (mod(soil_strength=None), "inconsistent"), (mod(where=where2), "inconsistent"),
        (mod(where=dict(good["where"], wheels=[7])), "out_of_range"),
        (mod(where=dict(good["where"], xy=[[3e7, 0.0]])), "out_of_range"),
        (mod(where={"wheels": [1], "latlon": [[95.0, 0.0]]}), "out_of_range"),
        (mod(vehicle_id="rover2"), "vehicle_mismatch"),
    ]


def test_bad_updates_are_refused_with_a_reason_and_never_touch_a_cell(tmp_path):
    st = _sqlite(tmp_path)
    up = MapUpdater(st)
    up.apply([item(estimate("rover1", 1, 80.0, 0.1))])
    before = st.obs_rows(), st.all_cells(NOW), st.ledger()
    bad = _bad_payloads()
    res = up.apply([item(p, "rover1") for p, _code in bad] + [("soilocp/rover1/ocp", b"{}", 0.0)])
    assert [r.code for r in res.refused] == [c for _p, c in bad] + ["bad_key"]
    for r in res.refused:
        assert r.message and r.vehicle_id in ("rover1", None)
    assert res.refused[7].field == "soil_strength" and "-5.0" in res.refused[7].message
    assert (st.obs_rows(), st.all_cells(NOW), st.ledger()) == before
    # an honest but uninformative band (ln K 1-sigma > 5) is skipped with its reason, not refused
    res = up.apply([item(estimate("rover1", 3, 80.0, 50.0))])
    assert res.refused == [] and res.skipped == {"band_too_wide": 1}
    assert (st.obs_rows(), st.all_cells(NOW), st.ledger()) == before
    # good estimates in the same batch as bad ones still land
    res = up.apply([item(bad[0][0], "rover1"), item(estimate("rover1", 2, 90.0, 0.1))])
    assert [r.code for r in res.refused] == ["malformed_json"] and st.all_cells(NOW)[0].K == pytest.approx(90.0)


def _fleet_items(seed=0, n=300):
    rng = random.Random(seed)
    out = []
    for v in ("a", "b", "c"):
        for s in range(n):
            out.append(item(estimate(v, s, rng.uniform(40, 300), rng.uniform(0.05, 0.5),
                                     xy=((rng.uniform(0, 30), rng.uniform(0, 30)),)), t=1_800_000_000.0 + s))
    return out


def test_order_of_arrival_and_duplicates_do_not_change_the_cells(tmp_path):
    items = _fleet_items()
    a = MapUpdater(_sqlite(tmp_path, "a.db"))
    a.apply(items)
    # another service: the vehicles' streams interleaved differently, in other batches, some twice
    per = {v: [it for it in items if f"/{v}/" in it[0]] for v in "abc"}
    rng = random.Random(1)
    mixed = []
    while any(per.values()):
        v = rng.choice([k for k, q in per.items() if q])
        mixed.append(per[v].pop(0))
    b = MapUpdater(_sqlite(tmp_path, "b.db"))
    for i in range(0, len(mixed), 37):
        b.apply(mixed[i:i + 37])
    b.apply(mixed[100:300])  # redelivered: changes nothing
    assert a.store.obs_rows()[:5] and a.store.all_cells(NOW) == b.store.all_cells(NOW)
    assert a.store.ledger() != b.store.ledger()  # the ledger counts what each received ...
    rows_a = [r[:6] for r in a.store.obs_rows()]
    assert rows_a == [r[:6] for r in b.store.obs_rows()]  # ... the cells do not


def test_a_store_refuses_another_grid(tmp_path):
    _sqlite(tmp_path, cells={"cell_size": 5.0}).close()
    with pytest.raises(StoreError, match="cell_size = 5"):
        _sqlite(tmp_path, cells={"cell_size": 2.0})
    with pytest.raises(StoreError, match="does not exist"):
        SqliteStore(str(tmp_path / "no" / "m.db"), CellConfig(), FusionConfig())


def test_h3_cells_from_latlon_and_box_query(tmp_path):
    st = _sqlite(tmp_path)
    up = MapUpdater(st)
    up.apply([item(estimate("g", 1, 120.0, 0.1, xy=None, latlon=((46.5, 6.6),))),
              item(estimate("g", 2, 60.0, 0.1, xy=None, latlon=((46.6, 6.7),)))])
    cells, cut = st.query_box(WGS84, (6.59, 46.49, 6.61, 46.51), NOW)
    assert len(cells) == 1 and cells[0].K == pytest.approx(120.0) and not cut
    assert len(st.query_box(WGS84, (6, 46, 7, 47), NOW)[0]) == 2
    assert st.query_box("f", (6, 46, 7, 47), NOW)[0] == []


@pytest.fixture(scope="module")
def pg():
    from pg_helpers import APT_HINT, PgServer, pg_bindir
    from zenoh_helpers import free_port

    if pg_bindir() is None:
        pytest.skip(f"PostgreSQL + PostGIS not installed: CI installs them with `{APT_HINT}`")
    srv = PgServer(free_port()).start()
    yield srv
    srv.stop()


def test_postgresql_postgis_store_gives_the_same_cells(tmp_path, pg):
    items = _fleet_items(seed=2, n=200)
    lite = MapUpdater(_sqlite(tmp_path))
    lite.apply(items)
    store = open_store(pg.new_database("same_cells"))
    post = MapUpdater(store)
    for i in range(0, len(items), 111):
        post.apply(items[i:i + 111])
    post.apply(items[:50])  # redelivered
    assert store.all_cells(NOW) == lite.store.all_cells(NOW)
    box = (5.0, 5.0, 20.0, 20.0)
    assert store.query_box("f", box, NOW) == lite.store.query_box("f", box, NOW)
    cur = store._conn().cursor()
    cur.execute("SELECT PostGIS_Version()")
    assert cur.fetchone()[0]
    store._conn().rollback()
    # a bad batch is refused without touching the database
    before = store.obs_rows()
    res = post.apply([item(p, "a") for p, _c in _bad_payloads()])
    assert len(res.refused) == len(_bad_payloads()) and store.obs_rows() == before
    store.close()


def _reply_equals_columns(store, frame, box, now, limit=100_000):
    from soilocp.schemas.map import MapCellColumns

    text, n, cut, aged_to = store.query_json(frame, box, now, limit)
    assert now - 1.0 < aged_to <= now  # the replies' ageing clock steps once a second
    got = MapCellColumns.model_validate_json(text)  # the reply's own schema
    want, want_cut = store.query_columns(frame, box, aged_to, limit)
    assert (n, cut) == (len(want["cell"]), want_cut)
    for name in ("cell", "cx", "cy", "count", "last_seen", "vehicles"):
        assert getattr(got, name) == want[name], name
    for name in ("K", "log_k_std", "K_lo", "K_hi"):
        assert getattr(got, name) == pytest.approx(want[name], rel=1e-12), name
    return n


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_box_replies_from_memory_follow_every_commit(tmp_path, backend, request):
    """query_json (the map service's replies, laid out in memory) equals the database's own box
    query after each commit: new cells, changed cells, ageing, limits, unknown frames."""
    store = (_sqlite(tmp_path) if backend == "sqlite"
             else open_store(request.getfixturevalue("pg").new_database("replies")))
    up = MapUpdater(store)
    items = _fleet_items(seed=5, n=240)
    box, limit_box = (0.0, 0.0, 40.0, 40.0), (5.0, 5.0, 20.0, 20.0)
    assert _reply_equals_columns(store, "f", box, NOW) == 0
    seen = []
    for i in range(0, len(items), 60):  # every batch adds cells and changes some already laid out
        up.apply(items[i:i + 60])
        seen.append(_reply_equals_columns(store, "f", box, NOW + i))
        _reply_equals_columns(store, "f", limit_box, NOW + 3600 * i)
    assert seen[-1] > seen[0] > 0
    assert _reply_equals_columns(store, "f", box, NOW, limit=3) == 3
    assert store.query_json("f", box, NOW, limit=3)[2]
    assert _reply_equals_columns(store, "elsewhere", box, NOW) == 0
    # another connection (a second reader, a restarted service) lays out the same cells
    other = open_store(store.url)
    assert other.query_json("f", box, NOW + 1)[0] == store.query_json("f", box, NOW + 1)[0]
    other.close()
    store.close()


def test_map_prior_enters_new_ground_once_not_each_wobble_over_a_border():
    """MapPrior along a cell border (y = 0, the front axle wandering ±5 cm): the belief starts from
    the map on entering ground it has not just left, not at every crossing of the border."""
    from types import SimpleNamespace

    from soilocp.schemas.map import MapCell
    from soilocp.map.prior import MapPrior

    def cell(ix, iy, k):
        return MapCell(cell=f"f/5/{ix}/{iy}", frame="f", center=(5 * ix + 2.5, 5 * iy + 2.5), K=k, log_k_std=0.1,
                       K_lo=k * 0.8, K_hi=k * 1.2, count=3, last_seen=NOW, vehicles=["a"])

    cells = [cell(ix, iy, 50.0 + 10 * ix + iy) for ix in range(4) for iy in (-1, 0)]
    prior = MapPrior(cells, CellConfig(cell_size=5.0))
    got = []
    for i in range(1500):  # 15 m at 1 cm a step, y flipping sign every 7 steps
        x, y = 0.01 * i, 0.05 if (i // 7) % 2 else -0.05
        start = prior(SimpleNamespace(position=SimpleNamespace(frame="f", x=x - prior.ahead, y=y, heading=0.0), geo=None))
        if start is not None:
            got.append((round(x, 2), round(math.exp(start[0]), 6)))
    # once for each of the two cells at the border in each 5 m column: 6 restarts, not ~200
    assert sorted(k for _x, k in got) == [49.0, 50.0, 59.0, 60.0, 69.0, 70.0]
    assert [x for x, _k in got][::2] == [0.0, 5.0, 10.0] and prior.entered == 6

    def at(x, y):
        return prior(SimpleNamespace(position=SimpleNamespace(frame="f", x=x - prior.ahead, y=y, heading=0.0), geo=None))

    # on into the next column: new ground; back into the cell just left 3 m from where it was
    # left (a turn, not a wobble): new ground again, from the map
    assert at(15.5, 0.05) is not None and prior.current == "f/5/3/0"
    assert at(12.0, 0.05) is not None and prior.current == "f/5/2/0" and prior.entered == 8
