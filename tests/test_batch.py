"""One kernel, two callers: the batched chain (soilocp.estimation.batch, N vehicles) against the single-vehicle
pipeline (the same kernels with N = 1) in every output field, and the observer kernel against the
filterpy reference, step by step, on real simulated drives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.estimation.batch import BatchPipeline
from soilocp.model.ocp import ocp_arrays, ocp_from_soil_strength
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
from soilocp.estimation.soil_strength import SoilBank
from soilocp.estimation.torque_scale import TorqueScaleConfig
from soilocp.sim.simulator import simulate
from soilocp.sim.variants import get_variant

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
    # d: a ground speed 50 ms late at 10 Hz (the observer measures and leads it), a 0.3 s dropout of
    # it, a 1 s gap (reset) and a repeated stamp
    d = [s.model_copy(update={"vehicle_id": "d"}) for s, _t in get_variant("ground-speed-lag").simulate(4, duration=10.0)]
    d = [s.model_copy(update={"ground_speed": None}) if 500 <= i < 530 else s for i, s in enumerate(d)]
    d = d[:700] + [d[700]] + d[700:760] + d[860:]
    return {"a": a, "b": b, "c": c, "d": d}


def _close(x, y, what):
    if x is None or y is None:
        assert x is None and y is None, what
        return
    assert math.isclose(x, y, rel_tol=TOL, abs_tol=TOL), (what, x, y)


def _quad(x, y, what):
    assert np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=TOL, atol=TOL), (what, x, y)


def _same_record(a: dict, b: dict, what) -> None:
    """Every field of two OCP records: floats to TOL, everything else (statuses, reasons, classes,
    flags, None-ness) exactly."""
    assert a.keys() == b.keys(), what
    for name in a:
        x, y = a[name], b[name]
        if isinstance(x, float) or isinstance(y, float):
            _close(x, y, (what, name))
        elif isinstance(x, (tuple, list)) and x and isinstance(x[0], float):
            _quad(x, y, (what, name))
        else:  # a JSON record (live) has lists where a model_dump (offline) has tuples
            as_list = (lambda v: list(v) if isinstance(v, tuple) else v)
            assert as_list(x) == as_list(y), (what, name, x, y)


@pytest.mark.parametrize("scale", ["default", "off", "modelled_resistance"])
def test_batched_equals_single_vehicle_pipeline_in_every_field(drives, scale):
    """The chain's one core call (BatchPipeline) against the stages' calls, with the torque scale as configured,
    off (the chain without a scale) and with eq. 4's resistance fed the records' K."""
    cfg = PipelineConfig(torque_scale={"default": TorqueScaleConfig(), "off": TorqueScaleConfig(enabled=False),
                                       "modelled_resistance": TorqueScaleConfig(model_resistance=True)}[scale])
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
        out = batch.step(np.array(present), samples, [r[0].normal_force for r in ref])
        for j, (nf, ob, so, oc) in enumerate(ref):
            _same_record(out[j].model_dump(), oc.model_dump(), k)
            checked += 1
            rejected += ob.rejected_measurements
            resets += ob.reset
            statuses.add(oc.status)
    assert checked == sum(len(v) for v in drives.values())
    # the drives exercised gating, re-initialisation after a gap and real estimates
    assert rejected > 0 and resets >= 4 and ({"ok", "uncertain"} & statuses)


@pytest.mark.parametrize("structure", ["slip", "shared", "none"])
def test_observer_kernel_equals_filterpy_reference_step_by_step(drives, structure):
    """The kernel's own predict / gated update (N = 1) against filterpy's KalmanFilter on the same model."""
    from soilocp.estimation.observer import ObserverConfig
    from soilocp.estimation.observer_bank import ObserverBank
    from reference_observer import TractionObserver
    from soilocp.estimation.pipeline import NormalForceStage, observer_inputs

    cfg = PipelineConfig(observer=ObserverConfig(structure=structure))
    nfs = NormalForceStage(cfg)
    for name, drive in drives.items():
        bank = ObserverBank(cfg.vehicle, cfg.observer, 1)
        ref = TractionObserver(cfg.vehicle, cfg.observer)
        for k, s in enumerate(drive):
            fz = nfs.step(s).normal_force
            o = bank.step(np.zeros(1, dtype=int), observer_inputs([s], [fz]))
            r = ref.step(s.stamp, s.specific_force[0], s.yaw_rate, s.pitch, s.wheel_speed, s.wheel_torque,
                         s.ground_speed, fz)
            for field in ("mu", "mu_var", "resistance", "gross", "gross_var", "wheel_speed"):
                _quad(getattr(o, field)[0], getattr(r, field), (name, k, field))
            _close(float(o.ground_speed[0]), r.ground_speed, (name, k, "ground_speed"))
            assert int(o.rejected[0]) == r.rejected and bool(o.reset[0]) == r.reset, (name, k)
        if name == "d":  # the latency path ran, in both, to the same value
            assert o.ground_speed_latency[0] > 0.03
            assert o.ground_speed_latency[0] == pytest.approx(r.ground_speed_latency, abs=1e-12)


def test_ocp_arrays_equal_the_single_k_path_and_te_is_defined_alike():
    ks = np.concatenate([np.geomspace(5.0, 5000.0, 57), np.linspace(640.0, 690.0, 26)])
    o = ocp_arrays(ks, PipelineConfig().constants)
    for i, k in enumerate(ks):
        ref = ocp_from_soil_strength(float(k))
        for name in ("mu_T", "S_T", "S_E"):
            assert math.isclose(o[name][i], getattr(ref, name), rel_tol=1e-12, abs_tol=1e-15)
        # te at S_E exists exactly where S_E is a driving slip (the old paths disagreed for K 651-677)
        assert math.isnan(o["te_at_S_E"][i]) == (not 0 < ref.S_E < 1), k


def test_bad_arguments_are_named(drives):
    with pytest.raises(ValueError, match="n_vehicles"):
        BatchPipeline(None, 0)
    bp = BatchPipeline(None, 2)
    two = drives["a"][:2]
    fz = [(100.0,) * 4] * 2
    with pytest.raises(ValueError, match="only once"):
        bp.step(np.array([1, 1]), two, fz)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        bp.step(np.array([0, 2]), two, fz)
    with pytest.raises(ValueError, match="normal_force"):
        bp.step(np.array([0, 1]), two, [(100.0,) * 3] * 2)
    with pytest.raises(ValueError, match="soil_strength"):
        ocp_arrays(np.array([10.0, -1.0]), PipelineConfig().constants)


@pytest.mark.timeout(300)
def test_batch_service_stream_equals_offline_estimate():
    """gateway + the batched normal-force/observer/soil/OCP service (soilocp.services.stages.batch), real processes
    behind a real router: two vehicles' live OCP streams equal ``estimate_lines`` offline."""
    import json
    import threading
    import time

    import zenoh

    from soilocp.schemas import keys
    from soilocp.services.bench.live import Rig, open_client
    from soilocp.estimation.estimate import estimate_lines

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
            _same_record(a, b, (v, a["seq"]))


def test_a_chain_step_that_raises_after_the_observer_leaves_one_clock_the_core_s(drives):
    """ChainCore.step can raise after the scale and the observer stepped (the soil update refusing a sample):
    the observer's clock is the core's alone, so the next step spans one interval: its output equals that of
    an observer that stepped the same samples without the refusal."""
    from soilocp.estimation.pipeline import observer_inputs

    s = next(iter(drives.values()))[:3]
    fz = [np.full(4, 150.0)] * 3
    refused, plain = BatchPipeline(PipelineConfig(), 2), BatchPipeline(PipelineConfig(), 2)
    for bank in (refused, plain):
        bank.step_all(np.array([0]), s[:1], fz[:1])

    def stepped_then_refused(*args):
        refused.observer._core.step(*args)  # the observer moves on, then something after it raises
        raise ValueError("refused after the observer")

    with pytest.raises(ValueError, match="after the observer"):
        refused.observer.run(stepped_then_refused, np.array([0]), observer_inputs(s[1:2], fz[1:2]))
    plain.observer.step(np.array([0]), observer_inputs(s[1:2], fz[1:2]))
    assert refused.observer.last_stamp[0] == s[1].stamp and np.isnan(refused.observer.last_stamp[1])
    a = refused.observer.step(np.array([0]), observer_inputs(s[2:3], fz[2:3]))
    b = plain.observer.step(np.array([0]), observer_inputs(s[2:3], fz[2:3]))
    for name, x in a._asdict().items():
        assert np.array_equal(x, getattr(b, name), equal_nan=True), name


def test_the_chain_refuses_stages_of_different_banks_and_a_soil_bank_without_records():
    from soilocp import _core

    cfg = PipelineConfig()
    two, three = BatchPipeline(cfg, 2), BatchPipeline(cfg, 3)
    with pytest.raises(ValueError, match="soil holds 3 vehicles, the observer 2"):
        _core.ChainCore(two.observer._core, two.gate.core, three.soil.core, two.scale._core)
    bare = SoilBank(cfg.constants, cfg.soil, 2)
    bare.core = bare.grid.bank(2)  # the core's bank before its records' settings
    with pytest.raises(ValueError, match="set_status"):
        _core.ChainCore(two.observer._core, two.gate.core, bare.core)
