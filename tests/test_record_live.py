"""``soilocp record``: a real router, real recorder processes, OCP records and sensor samples
published by a client session; the recorder's MCAP files (rotated, bounded) hold exactly what was
published, on the five channels of the live Foxglove server."""

from __future__ import annotations

import json
import signal

import pytest
from mcap.reader import make_reader

from soilocp.schemas import keys
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.export.channels import topics
from soilocp.sim.simulator import simulate

from zenoh_helpers import Procs, client, endpoint, free_port, wait_for

pytestmark = pytest.mark.timeout(240)


def _ocp(vid: str, seq: int) -> bytes:
    k = 50.0 + seq * 0.01
    return OcpEstimate(vehicle_id=vid, seq=seq, stamp=1_700_000_000 + seq / 100, soil_strength=k, soil_strength_std=2.0,
                       soil_class="sand", soil_class_confidence=0.9, mu_T=0.38, S_T=0.26, S_E=0.12, status="ok",
                       mu=(0.1, 0.2, 0.2, 0.1), slip=(0.05, 0.3, 0.3, 0.05)).model_dump_json().encode()


def _messages(files, topic_suffix="soil_strength", log_time=False):
    out = []
    for p in files:
        with open(p, "rb") as f:
            for _s, ch, m in make_reader(f).iter_messages():
                if ch.topic.endswith(topic_suffix):
                    out.append((ch.topic, json.loads(m.data)) + ((m.log_time,) if log_time else ()))
    return out


def _topics(files) -> set[str]:
    out = set()
    for p in files:
        with open(p, "rb") as f:
            out |= {c.topic for c in make_reader(f).get_summary().channels.values()}
    return out


def test_record_fleet_and_one_vehicle_with_rotation(tmp_path):
    # the sensor samples of a simulated drive per vehicle, published on its raw key
    samples = {v: [s for s, _ in simulate("sand", duration=3.0, seed=i, vehicle_id=v)]
               for i, v in enumerate(("rover1", "rover2"))}
    assert all(len(x) == 300 for x in samples.values())
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("rec_fleet", ["record", "--out", str(tmp_path / "fleet.mcap"), "--connect", ep])
        procs.spawn("rec_one", ["record", "--out", str(tmp_path / "one.mcap"), "--connect", ep, "--vehicle-id", "rover2",
                                "--max-mb", "0.02", "--max-files", "50"])
        for name in ("rec_fleet", "rec_one"):
            assert wait_for(lambda n=name: '"event": "recording"' in procs.log_text(n), 60), procs.log_text(name)
        with client(ep) as s:
            import zenoh

            # BLOCK: a burst of puts on a loaded machine must not be dropped by congestion control
            block = zenoh.CongestionControl.BLOCK
            pubs = {v: s.declare_publisher(keys.ocp(v), congestion_control=block) for v in ("rover1", "rover2")}
            raw = {v: s.declare_publisher(keys.raw(v), congestion_control=block) for v in ("rover1", "rover2")}
            for v, p in list(pubs.items()) + list(raw.items()):  # both recorders' subscriptions have reached this session
                assert wait_for(lambda p=p: p.matching_status.matching, 30), v
            for seq in range(300):
                for v in pubs:
                    raw[v].put(samples[v][seq].model_dump_json())
                    pubs[v].put(_ocp(v, seq))
            s.put(keys.ocp("rover1"), b'{"not": "an ocp record"}', congestion_control=block)
            # a valid sample on another vehicle's key: not that vehicle's data, not written
            s.put(keys.raw("rover1"), samples["rover2"][0].model_dump_json(), congestion_control=block)
            for p in list(pubs.values()) + list(raw.values()):
                p.undeclare()
        # stop once every record has reached the recorder (puts are asynchronous)
        assert wait_for(lambda: '"written": 600, "sensors": 600, "invalid": 2' in procs.log_text("rec_fleet"), 60), \
            procs.log_text("rec_fleet")
        assert wait_for(lambda: '"written": 300, "sensors": 300' in procs.log_text("rec_one"), 60), procs.log_text("rec_one")
        for name in ("rec_fleet", "rec_one"):
            procs.procs[name].send_signal(signal.SIGTERM)
        for name in ("rec_fleet", "rec_one"):
            assert procs.procs[name].wait(30) == 0, procs.log_text(name)
    finally:
        procs.close()
    fleet_files = sorted(tmp_path.glob("fleet_*.mcap"))
    assert len(fleet_files) == 1  # 64 MB default: no rotation
    assert _topics(fleet_files) == set(topics("rover1")) | set(topics("rover2"))  # 5 channels per vehicle
    got = _messages(fleet_files)
    by_vid = {v: [m["seq"] for t, m in got if t == f"/soilocp/{v}/soil_strength"] for v in ("rover1", "rover2")}
    assert by_vid == {"rover1": list(range(300)), "rover2": list(range(300))}
    # the sensor messages are the published samples: every value, and the sample's stamp as log time
    sens = _messages(fleet_files, "sensors", log_time=True)
    for v in ("rover1", "rover2"):
        mine = [(m, t) for topic, m, t in sens if topic == f"/soilocp/{v}/sensors"]
        assert [m for m, _ in mine] == [json.loads(x.model_dump_json()) for x in samples[v]]
        assert [t for _, t in mine] == [round(x.stamp * 1e9) for x in samples[v]]
    assert '"invalid": 2' in procs.log_text("rec_fleet")
    one = sorted(tmp_path.glob("one_*.mcap"))
    assert len(one) > 1  # rotated at ~20 kB
    assert _topics(one) == set(topics("rover2"))
    got = _messages(one)
    assert {t for t, _ in got} == {"/soilocp/rover2/soil_strength"}
    assert [m["seq"] for _, m in got] == list(range(300))
    assert got[-1][1]["K"] == pytest.approx(52.99) and got[-1][1]["K_minus_std"] == pytest.approx(50.99)
    assert [m for _, m in _messages(one, "sensors")] == [json.loads(x.model_dump_json()) for x in samples["rover2"]]


def test_soilocp_run_replays_a_bag_with_its_map(tmp_path):
    import os
    import subprocess
    import sys

    from soilocp.ingest.bag_writer import write_bag
    from soilocp.sim.simulator import simulate

    bag = write_bag([s for s, _ in simulate("sand", duration=4.0, seed=2, vehicle_id="bagrover")], tmp_path / "bag")
    m = tmp_path / "map.yaml"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    m.write_text(open(os.path.join(root, "docs", "maps", "ros2-robot.yaml")).read().replace("rover1", "bagrover"))
    ep = endpoint(free_port())
    p = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--replay", str(bag), "--map", str(m), "--speed", "2",
                          "--listen", ep, "--log-dir", str(tmp_path / "logs")],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 0, out
    n = sum(1 for _ in open(tmp_path / "logs" / "imported-sensors.jsonl"))
    assert n >= 400 and "vehicle bagrover" in out  # the map's vehicle_id is the run's
    assert f"OCP records received: {n}" in out, out
