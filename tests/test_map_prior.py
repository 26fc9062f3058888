"""The fleet map back to the vehicles (docs/map.md §4): the prior the single-vehicle stage takes is
the batched pipeline's too (one step, soilocp.map.prior.start_from_map), and the wheels still on
the ground the front axle left do not inform the belief the map just started."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.schemas.map import MapCell
from soilocp.analysis.fleet_map import mixed_field
from soilocp.estimation.batch import BatchPipeline
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
from soilocp.map.prior import MapPrior
from soilocp.sim.field import StartPose, straight_drive
from soilocp.sim.simulator import simulate


def _true_cells(size: float = 5.0) -> list[MapCell]:
    """The mixed field's 5 m cells at their true K, with a band of +-10 % (1-sigma)."""
    fld, out = mixed_field(), []
    for ix in range(8):
        for iy in range(8):
            cx, cy = (ix + 0.5) * size, (iy + 0.5) * size
            k = fld.soil_at(cx, cy)[1]
            out.append(MapCell(cell=f"field/{size:g}/{ix}/{iy}", frame="field", center=(cx, cy), K=k, log_k_std=0.1,
                               K_lo=k * math.exp(-0.196), K_hi=k * math.exp(0.196), count=100, last_seen=0.0,
                               vehicles=["a"]))
    return out


def test_the_batched_pipeline_takes_the_same_map_prior_as_the_single_one():
    """Charlie's column, grass 200 -> firm 300 at y = 20: vehicle 0 of a batch with a MapPrior equals
    VehiclePipeline(prior=MapPrior) sample by sample, vehicle 1 (no prior) equals the pipeline
    without; the prior is taken on entering each mapped cell, and the rear wheels are kept out of
    the belief while they are still on the grass cell."""
    start = StartPose(frame="field", x=27.5, y=13.0, heading=math.pi / 2)
    samples = [s for s, _t in simulate(straight_drive(mixed_field(), start, 11.0, name="prior-batch"), seed=3,
                                       start=start, vehicle_id="v0")]
    cfg = PipelineConfig()
    cells = _true_cells()
    single_prior, batch_prior = MapPrior(cells, vehicle=cfg.vehicle), MapPrior(cells, vehicle=cfg.vehicle)
    with_map, without = VehiclePipeline(cfg, prior=single_prior), VehiclePipeline(cfg)
    batch = BatchPipeline(cfg, 2, priors=[batch_prior, None])
    k_single, k_batch, k_without, k_plain = [], [], [], []
    for s in samples:
        nf, _obs, soil, _ocp = with_map.process_all(s)
        k_single.append(soil.soil_strength)
        k_without.append(without.process_all(s)[2].soil_strength)
        other = s.model_copy(update={"vehicle_id": "v1"})
        out = batch.step(np.array([0, 1]), [s, other], [nf.normal_force, nf.normal_force])
        k_batch.append(out[0].soil_strength)
        k_plain.append(out[1].soil_strength)
    assert single_prior.entered == batch_prior.entered >= 3  # 2/3 -> 2/4 -> 2/5, ... each cell entered once
    assert single_prior.withheld == batch_prior.withheld > 0
    for name, a, b in (("with the map", k_single, k_batch), ("without", k_without, k_plain)):
        assert [x is None for x in a] == [x is None for x in b], name
        got = np.array([x for x in a if x is not None]), np.array([x for x in b if x is not None])
        assert np.allclose(*got, rtol=1e-9), name
    # on the firm cell the map's belief holds 300 from the front axle's entry on; without it, it does not yet
    i = next(j for j, s in enumerate(samples) if s.position.y + cfg.vehicle.b >= 20.0)
    assert all(abs(k / 300.0 - 1) <= 0.10 for k in k_single[i:i + 50] if k is not None)
    assert any(k is None or abs(k / 300.0 - 1) > 0.10 for k in k_without[i:i + 50])


def test_live_batched_service_starts_from_the_map(tmp_path):
    """The batched service (soilocp.services.stages.batch) with SOILOCP_MAP_PRIOR, real processes: a map
    service holds cells along the drive at K = 123 (no soil of the drive has it); the batched
    service asks it for the cells around the vehicle and starts the belief from them as the vehicle
    enters each, as the soil-strength service does (tests/test_map_service.py)."""
    import json
    import time

    import zenoh

    from map_helpers import estimate, item
    from soilocp.schemas import keys
    from soilocp.map.store import open_store
    from soilocp.map.updater import MapUpdater
    from zenoh_helpers import Procs, client, endpoint, free_port, wait_for

    db = tmp_path / "m.db"
    st = open_store(f"sqlite:{db}")
    MapUpdater(st).apply([item(estimate("mapper", i + 1, 123.0, 0.1, xy=((x + 2.5, y + 2.5),), frame="field"))
                          for i, (x, y) in enumerate((x, y) for x in range(-10, 100, 5) for y in (-10, -5, 0, 5))])
    st.close()
    start = StartPose(frame="field", x=0.0, y=0.0, heading=0.0)
    lines = [s.model_dump_json() for s, _t in simulate("mixed", duration=16.0, seed=0, vehicle_id="bx1", start=start)]
    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    env = {"SOILOCP_VEHICLE_ID": "bx1", "SOILOCP_CONNECT": ep}
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store", f"sqlite:{db}"])
        procs.spawn("gateway", ["service", "gateway"], env=env)
        procs.start("batch", [], module="soilocp.services.stages.batch", env={**env, "SOILOCP_MAP_PRIOR": "m"})
        with client(ep) as s:
            for name in ("map/m", "ocp"):
                key = keys.map_key("m", "alive") if name == "map/m" else keys.alive("bx1", "ocp")
                assert wait_for(lambda: list(s.liveliness().get(key, timeout=1)), 90), procs.tail("batch")
            status: list[dict] = []
            sub = s.declare_subscriber(keys.status("bx1", "ocp"), lambda x: status.append(json.loads(x.payload.to_bytes())))
            pub = s.declare_publisher(keys.raw("bx1"), congestion_control=zenoh.CongestionControl.BLOCK)
            for line in lines:
                pub.put(line)
                time.sleep(0.004)  # ~2.5x real time
            assert wait_for(lambda: any(h.get("detail", {}).get("map_prior_entered", 0) >= 2 for h in status), 30), \
                (status[-1:], procs.tail("batch", 40))
            sub.undeclare()
        events = [json.loads(x) for x in procs.log_text("batch").splitlines() if x.startswith("{")]
        asked = [e for e in events if e.get("event") == "map_prior_cells"]
        used = [e for e in events if e.get("event") == "map_prior_used"]
        assert asked and asked[0]["cells"] >= 20 and asked[0]["frame"] == "field", procs.tail("batch", 40)
        assert len(used) >= 2 and all(e["K"] == pytest.approx(123.0, rel=1e-6) for e in used), procs.tail("batch", 40)
        assert not procs.dead(), procs.dead()
    finally:
        procs.close()
