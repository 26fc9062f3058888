"""The batched observer + soil + OCP (soilocp.batch) against the single-vehicle pipeline
(filterpy observer, grid Bayes estimator, OcpStage) on real simulated drives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.batch import BatchInputs, BatchPipeline, ocp_batch
from soilocp.ocp import ocp_from_soil_strength
from soilocp.pipeline import PipelineConfig, VehiclePipeline
from soilocp.simulator import simulate

TOL = 1e-9


def _drive(scenario: str, duration: float, seed: int, vid: str):
    return [s for s, _t in simulate(scenario, duration=duration, seed=seed, vehicle_id=vid)]


@pytest.fixture(scope="module")
def drives():
    a = _drive("mixed", 6.0, 1, "a")
    b = _drive("sandy-slope", 4.0, 2, "b")
    # c: the same terrain as b with a wheel-speed spike (gated rows) and a 1 s gap (reset)
    c = [s.model_copy(update={"vehicle_id": "c"}) for s in _drive("sand", 5.0, 3, "c")]
    spike = c[250]
    c[250] = spike.model_copy(update={"wheel_speed": (spike.wheel_speed[0] + 40.0, *spike.wheel_speed[1:])})
    c = c[:300] + c[380:]
    return {"a": a, "b": b, "c": c}


def _close(x, y, what):
    if x is None or y is None:
        assert x is None and y is None, what
        return
    assert math.isclose(x, y, rel_tol=TOL, abs_tol=TOL), (what, x, y)


def _quad(x, y, what):
    assert np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=TOL, atol=TOL), (what, x, y)


def test_batched_equals_single_vehicle_pipeline(drives):
    cfg = PipelineConfig()
    names = list(drives)
    singles = {n: VehiclePipeline(cfg) for n in names}
    batch = BatchPipeline(cfg, len(names))
    n_steps = max(len(v) for v in drives.values())
    checked = rejected = resets = 0
    statuses = set()
    for k in range(n_steps):
        # vehicles step together when they have a sample: any subset, in any order
        present = [i for i, n in enumerate(names) if k < len(drives[n])][::-1 if k % 2 else 1]
        samples = [drives[names[i]][k] for i in present]
        ref = [singles[names[i]].process_all(s) for i, s in zip(present, samples)]
        out = batch.step(np.array(present), BatchPipeline.inputs_from_samples(samples, [r[0].normal_force for r in ref]))
        for j, (nf, ob, so, oc) in enumerate(ref):
            o = out.observer
            for name in ("mu", "mu_var", "resistance", "gross", "gross_var", "wheel_speed"):
                _quad(getattr(o, name)[j], getattr(ob, name), (k, name))
            _close(float(o.ground_speed[j]), ob.ground_speed, (k, "ground_speed"))
            _close(float(o.yaw_rate[j]), ob.yaw_rate, (k, "yaw_rate"))
            assert int(o.rejected[j]) == ob.rejected_measurements and bool(o.reset[j]) == ob.reset, k
            _quad(out.slip[j], so.slip, (k, "slip"))
            st = out.soil[j]
            assert st.used == so.informative and st.status == so.status and st.reason == so.reason, (k, st, so)
            assert st.soil_class == so.soil_class, k
            for name in ("soil_strength", "soil_strength_std", "log_k_std", "soil_class_confidence", "last_update_stamp"):
                _close(getattr(st, name), getattr(so, name), (k, name))
            f = out.ocp_fields(j)
            for name in ("mu_T", "S_T", "S_E", "te_at_S_E", "soil_strength"):
                _close(f[name], getattr(oc, name), (k, name))
            assert f["status"] == oc.status
            checked += 1
            rejected += ob.rejected_measurements
            resets += ob.reset
            statuses.add(oc.status)
    assert checked == sum(len(v) for v in drives.values())
    # the drives exercised gating, re-initialisation after a gap and real estimates
    assert rejected > 0 and resets >= 4 and ({"ok", "uncertain"} & statuses)


def test_ocp_batch_equals_scalar_path():
    ks = np.geomspace(5.0, 5000.0, 57)
    o = ocp_batch(ks, PipelineConfig().constants)
    for i, k in enumerate(ks):
        ref = ocp_from_soil_strength(float(k))
        for name in ("mu_T", "S_T", "S_E"):
            assert math.isclose(o[name][i], getattr(ref, name), rel_tol=1e-12, abs_tol=1e-15)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="n_vehicles"):
        BatchPipeline(None, 0)
    bp = BatchPipeline(None, 2)
    inp = BatchInputs(*(np.zeros(2) for _ in range(4)), np.zeros((2, 4)), np.zeros((2, 4)), np.zeros(2),
                      np.full((2, 4), 100.0))
    with pytest.raises(ValueError, match="only once"):
        bp.step(np.array([1, 1]), inp)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        bp.step(np.array([0, 2]), inp)
    bad = BatchInputs(*(np.zeros(2) for _ in range(4)), np.zeros((2, 3)), np.zeros((2, 4)), np.zeros(2),
                      np.full((2, 4), 100.0))
    with pytest.raises(ValueError, match="wheel_speed"):
        bp.step(np.array([0, 1]), bad)
    with pytest.raises(ValueError, match="soil_strength"):
        ocp_batch(np.array([10.0, -1.0]), PipelineConfig().constants)


@pytest.mark.timeout(300)
def test_batch_service_stream_equals_offline_estimate():
    """gateway + the batched normal-force/observer/soil/OCP service (services.batch_services), real processes
    behind a real router: two vehicles' live OCP streams equal ``estimate_lines`` offline."""
    import json
    import threading
    import time

    import zenoh

    from schemas import keys
    from services.bench_live import Rig, open_client
    from soilocp.estimate import estimate_lines

    vids = ["bx1", "bx2"]
    logs = {v: [s.model_dump_json() for s, _t in simulate(sc, duration=3.0, seed=i, vehicle_id=v)]
            for i, (v, sc) in enumerate(zip(vids, ("sandy-slope", "mixed")))}
    offline = {v: list(estimate_lines(lines, PipelineConfig())) for v, lines in logs.items()}
    got: dict[str, list[dict]] = {v: [] for v in vids}
    lock = threading.Lock()

    def on_ocp(sample):
        vid = str(sample.key_expr).split("/")[1]
        with lock:
            got[vid].append(json.loads(sample.payload.to_bytes()))

    rig = Rig.batched(vids)
    try:
        rig.start()
        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 120.0)
            sub = session.declare_subscriber(keys.any_vehicle_ocp(), on_ocp)
            pubs = {v: session.declare_publisher(keys.raw(v), congestion_control=zenoh.CongestionControl.BLOCK)
                    for v in vids}
            time.sleep(0.3)
            for k in range(max(len(x) for x in logs.values())):
                for v in vids:
                    if k < len(logs[v]):
                        pubs[v].put(logs[v][k])
                time.sleep(0.002)  # ~5x real time: the batch service steps both vehicles together
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and any(len(got[v]) < len(offline[v]) for v in vids):
                time.sleep(0.1)
            sub.undeclare()
        assert not rig.dead(), rig.dead()
    finally:
        rig.stop()
    for v in vids:
        live = sorted(got[v], key=lambda r: r["seq"])
        assert [r["seq"] for r in live] == [r["seq"] for r in offline[v]], v
        for a, b in zip(live, offline[v]):
            assert a["status"] == b["status"] and a["soil_class"] == b["soil_class"], (v, a["seq"])
            for name in ("soil_strength", "soil_strength_std", "mu_T", "S_T", "S_E", "te_at_S_E",
                         "soil_class_confidence"):
                _close(a[name], b[name], (v, a["seq"], name))
            _quad(a["mu"], b["mu"], (v, a["seq"], "mu"))
            _quad(a["slip"], b["slip"], (v, a["seq"], "slip"))
