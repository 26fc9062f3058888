"""Live equals offline with every feedback of the chain on: one drive through the five live services
(real processes, a router and a map service on an ephemeral loopback port) and through ``soilocp
estimate`` with the same inputs, record by record.

The drive (simulated, 24 s at 100 Hz) carries a payload the vehicle file does not know (+25 % mass)
and swings its speed 0.5..1.5 m/s, so the torque scale leaves its prior and models the motion
resistance at the soil's K (``torque_scale.model_resistance``: K goes back from the soil-strength
service to the observer service's torque scale); it crosses a terrain change (sand K = 50 -> gravel
K = 80 at 12 m); and a fleet map holds cells along it, which the soil-strength service gets from the
map service (``SOILOCP_MAP_PRIOR``) and ``soilocp estimate --map-prior`` reads from the same store.

Agreement: every record's fields equal, numbers within a relative and absolute tolerance of
``REL_TOL`` / ``ABS_TOL`` (the live path carries the same numbers through JSON, whose floats round
trip exactly; the tolerance bounds the map cells' ageing between the two reads of the store, a random
walk of 0.02 per hour of ln K over the seconds between them), statuses and reason codes identical.
Live must neither drop nor reorder a record, nor step a sample before its K came back
(``soil_feed_late``); each is counted and named in the failure.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time

import pytest

from soilocp.schemas import keys
from soilocp.schemas.messages import ServiceHealth
from soilocp.schemas.pipeline import OcpEstimate

from zenoh_helpers import PIPELINE, Procs, client, endpoint, free_port, get_payloads, wait_alive, wait_count, wait_for

pytestmark = pytest.mark.timeout(300)

VID = "lv1"
REL_TOL = 1e-9
ABS_TOL = 1e-12
#: replay speed (x real time): the observer waits for each sample's K, a round trip per sample
SPEED = 2.0


def _drive(path) -> list[str]:
    """The drive of the module doc as a sensor log; returns its lines."""
    from soilocp.model.vehicle import DEFAULT_VEHICLE
    from soilocp.sim.controller import ControllerParams
    from soilocp.sim.field import StartPose
    from soilocp.sim.simulator import simulate

    true = DEFAULT_VEHICLE.model_copy(update={"mass": DEFAULT_VEHICLE.mass * 1.25})
    start = StartPose(frame="field", x=0.0, y=2.5, heading=0.0)  # in the middle of a row of 5 m cells
    lines = [s.model_dump_json() for s, _t in simulate("mixed", duration=24.0, seed=0, vehicle=true, start=start,
                                                       controller=ControllerParams(speed_swing=0.5), vehicle_id=VID)]
    path.write_text("\n".join(lines) + "\n")
    return lines


def _map_store(db) -> str:
    """A map store holding 5 m cells from x = 5 m on (the drive starts outside them, so the soil-strength
    service has its cells before the vehicle enters the first), each at the K of the soil under it."""
    from map_helpers import estimate, item
    from soilocp.map.store import open_store
    from soilocp.map.updater import MapUpdater

    url = f"sqlite:{db}"
    st = open_store(url)
    ests = []
    for ix in range(1, 12):
        for iy in (-1, 0, 1):
            cx, cy = (ix + 0.5) * 5.0, (iy + 0.5) * 5.0
            k = 50.0 if cx < 12.0 else 80.0
            ests.append(estimate("mapper", len(ests) + 1, k, 0.1, xy=((cx, cy),), frame="field"))
    MapUpdater(st).apply([item(e) for e in ests])
    st.close()
    return url


def _differences(live: list[dict], offline: list[dict]) -> tuple[dict[str, float], list[str]]:
    """The largest absolute difference of each numeric field over the records, and every other mismatch."""
    worst: dict[str, float] = {}
    bad: list[str] = []
    for a, b in zip(live, offline):
        if set(a) != set(b):
            bad.append(f"seq {b['seq']}: fields {set(a) ^ set(b)}")
            continue
        for name, want in b.items():
            got = a[name]
            pairs = list(zip(got, want)) if isinstance(want, list) and isinstance(got, list) and len(got) == len(want) \
                else [(got, want)]
            for g, w in pairs:
                if isinstance(w, float) and isinstance(g, float):
                    d = abs(g - w) if not (math.isnan(g) and math.isnan(w)) else 0.0
                    worst[name] = max(worst.get(name, 0.0), d)
                    if not math.isclose(g, w, rel_tol=REL_TOL, abs_tol=ABS_TOL):
                        bad.append(f"seq {b['seq']}: {name} live {g!r} offline {w!r}")
                elif g != w:
                    bad.append(f"seq {b['seq']}: {name} live {g!r} offline {w!r}")
    return worst, bad


def test_live_services_equal_offline_with_k_fed_back_a_map_prior_and_a_terrain_change(tmp_path):
    log = tmp_path / "drive.jsonl"
    lines = _drive(log)
    url = _map_store(tmp_path / "map.db")
    pc = tmp_path / "pipeline.json"
    pc.write_text(json.dumps({"torque_scale": {"model_resistance": True}}))

    # offline: soilocp estimate with the same settings and map
    out = tmp_path / "estimates.jsonl"
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "estimate", str(log), "--out", str(out), "--config", str(pc),
                        "--map-prior", url], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    offline = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
    assert len(offline) == len(lines) == 2400

    # the drive exercises what it is meant to: K fed back matters, the map is entered, the soil changes
    _check_the_drive_exercises_the_feedback(lines, pc, url)

    procs = Procs(tmp_path / "logs")
    ep = endpoint(free_port())
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store", url])
        common = ["--vehicle-id", VID, "--connect", ep, "--pipeline-config", str(pc)]
        for name in PIPELINE:
            env = {"SOILOCP_MAP_PRIOR": json.dumps({"map_id": "m", "radius_m": 500})} if name == "soil-strength" else None
            procs.spawn(name, ["service", name, *common], env=env)
        got: list[bytes] = []
        lock = threading.Lock()

        def on_ocp(sample) -> None:
            with lock:
                got.append(sample.payload.to_bytes())

        with client(ep) as s:
            sub = s.declare_subscriber(keys.ocp(VID), on_ocp)
            assert wait_alive(s, VID), procs.tail("soil-strength")
            assert wait_for(lambda: list(s.liveliness().get(keys.map_key("m", "alive"), timeout=1)), 90), procs.tail("map")
            v = procs.spawn("vehicle", ["service", "vehicle", "--vehicle-id", VID, "--connect", ep, "--replay", str(log),
                                        "--speed", str(SPEED)])
            assert v.wait(120) == 0, procs.log_text("vehicle")
            arrived = wait_count(lambda: len(got), len(offline))
            time.sleep(0.5)  # nothing more may arrive
            sub.undeclare()
            health = {n: ServiceHealth.model_validate_json(get_payloads(s, keys.status(VID, n))[0]) for n in PIPELINE}
        with lock:
            live = [json.loads(OcpEstimate.model_validate_json(b).model_dump_json()) for b in got]
        died = {n: c for n, c in procs.dead().items() if n != "vehicle"}  # the replay ends by itself
        assert not died, died
    finally:
        procs.close()

    seqs = [d["seq"] for d in live]
    missing = sorted(set(range(len(offline))) - set(seqs))
    reordered = sum(1 for a, b in zip(seqs, seqs[1:]) if b <= a)
    obs = health["observer"].detail
    soil = health["soil-strength"].detail
    counts = (f"live {len(live)} of {len(offline)} records (arrived in time: {arrived}), missing {len(missing)} "
              f"{missing[:10]}, reordered {reordered}, dropped per service "
              f"{ {n: h.dropped for n, h in health.items()} }, observer soil_feed_late {obs.get('soil_feed_late')}, "
              f"soil_fed {obs.get('soil_fed')}, map_prior_entered {soil.get('map_prior_entered')}")
    assert not missing and not reordered and len(live) == len(offline), counts
    assert all(h.dropped == 0 and h.errors == 0 for h in health.values()), counts
    assert obs["soil_feed_late"] == 0 and obs["soil_fed"] == len(offline), counts
    assert soil["map_prior_entered"] >= 3 and soil["map_prior_failures"] == 0, counts

    worst, bad = _differences(live, offline)
    report = ", ".join(f"{k} {v:.3g}" for k, v in sorted(worst.items()) if v > 0) or "none"
    print(f"live vs offline: {len(live)} records, {counts}; max |difference| per field: {report}")
    assert not bad, (len(bad), bad[:10], counts)
    assert [d["status"] for d in live] == [d["status"] for d in offline]
    assert [d["reason_code"] for d in live] == [d["reason_code"] for d in offline]


def _check_the_drive_exercises_the_feedback(lines: list[str], pc, url: str) -> None:
    """In process, the offline chain on the drive: the torque scale leaves its prior; without K fed back the
    records differ (so the comparison would see a live path that does not feed it); the map prior is taken
    at >= 3 cells; K moves from the sand to the gravel."""
    from soilocp.estimation.config import load_pipeline_config
    from soilocp.estimation.pipeline import VehiclePipeline
    from soilocp.map.prior import MapPrior
    from soilocp.map.store import open_store
    from soilocp.schemas.sensor import SensorSample

    cfg = load_pipeline_config(str(pc))
    st = open_store(url)
    cells, cell_config = st.all_cells(time.time()), st.cell_config
    st.close()
    samples = [SensorSample.model_validate_json(x) for x in lines]
    runs = []
    for feed in (True, False):
        prior = MapPrior(cells, cell_config, vehicle=cfg.vehicle)
        pipe = VehiclePipeline(cfg, prior)
        if not feed:
            pipe.observer.feed = lambda _soil: None
        recs, scaled = [], 0
        for smp in samples:
            _nf, ob, _so, oc = pipe.process_all(smp)
            scaled += ob.torque_scale_std is not None
            recs.append(oc.model_dump())
        runs.append((recs, scaled, prior.entered))
    (fed, scaled, entered), (unfed, _, _) = runs
    assert scaled > 1000 and entered >= 3, (scaled, entered)
    assert sum(a != b for a, b in zip(fed, unfed)) > 1000
    ks = [r["soil_strength"] for r in fed]
    assert any(k is not None and abs(k / 50.0 - 1) < 0.15 for k in ks[:1200])
    assert any(k is not None and abs(k / 80.0 - 1) < 0.15 for k in ks[1800:])


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _feedback(capacity: int = 4):
    from types import SimpleNamespace

    from soilocp.services.runtime.worker import Counters
    from soilocp.services.stages.observer import SoilFeedback

    events: list[tuple[str, int]] = []
    clock = _Clock()
    c = Counters()
    fb = SoilFeedback(lambda s, _f: events.append(("step", s.seq)), lambda so: events.append(("feed", so.seq)), c,
                      capacity=capacity, timeout_s=0.5, clock=clock)
    pair = lambda n: (SimpleNamespace(seq=n), None)  # noqa: E731
    soil = lambda n: SimpleNamespace(seq=n)  # noqa: E731
    return fb, events, clock, c, pair, soil


def test_each_sample_waits_for_the_k_of_the_sample_before():
    """Sample n is stepped only after the soil estimate of sample n - 1 was fed, as offline."""
    fb, events, _clock, c, pair, soil = _feedback()
    fb.add_pair(*pair(0))
    fb.add_pair(*pair(1))
    fb.add_pair(*pair(2))
    assert events == [("step", 0)] and fb.pending() == 2
    fb.add_soil(soil(0))
    assert events == [("step", 0), ("feed", 0), ("step", 1)]
    fb.add_soil(soil(1))
    fb.add_soil(soil(2))
    assert events == [("step", 0), ("feed", 0), ("step", 1), ("feed", 1), ("step", 2), ("feed", 2)]
    assert c.detail == {"soil_feed_late": 0, "soil_fed": 3} and fb.pending() == 0


def test_a_soil_estimate_that_does_not_come_back_bounds_the_wait_and_is_counted():
    """Past the timeout the sample is stepped at the last K (counted late) and the next ones do not wait until
    a soil estimate comes again; an estimate older than the last fed is not fed; a full buffer steps the oldest."""
    fb, events, clock, c, pair, soil = _feedback()
    fb.add_pair(*pair(0))
    fb.add_pair(*pair(1))
    clock.t = 0.4
    assert not fb.due(clock.t)
    fb.drain()
    assert events == [("step", 0)]
    clock.t = 0.6
    assert fb.due(clock.t)
    fb.drain()  # the service's tick hands the worker this drain
    assert events == [("step", 0), ("step", 1)] and c.detail["soil_feed_late"] == 1
    fb.add_pair(*pair(2))  # not waiting now: stepped at once
    assert events[-1] == ("step", 2) and c.detail["soil_feed_late"] == 1
    fb.add_soil(soil(1))  # late, but newer than any fed: fed, and the samples wait again
    fb.add_soil(soil(0))  # older than the last fed: not fed
    assert events[-1] == ("feed", 1) and c.detail["soil_fed"] == 1
    fb.add_pair(*pair(3))
    assert events[-1] == ("feed", 1)  # waits for soil 2
    fb.add_soil(soil(2))
    assert events[-2:] == [("feed", 2), ("step", 3)]
    for n in range(4, 8):  # soil 3 never comes: the buffer holds 4 ...
        fb.add_pair(*pair(n))
    assert events[-1] == ("step", 3) and fb.pending() == 4
    fb.add_pair(*pair(8))  # ... the fifth steps them all, late once, and the samples stop waiting
    fb.add_pair(*pair(9))
    assert [e[1] for e in events if e[0] == "step"][-7:] == [3, 4, 5, 6, 7, 8, 9] and c.detail["soil_feed_late"] == 2
