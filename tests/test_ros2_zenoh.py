"""ROS 2 without ROS, over Zenoh: soilocp against zenoh-ros2-sdk, an rmw_zenoh implementation from
PyPI that this project did not write (no ROS install).

(a) The SDK publishes /imu/data, /joint_states and /odom of a simulated drive (the messages of a
    bag written by soilocp.ingest.bag_writer); a live ``soilocp run --ros2-in MAP --ros2`` fed
    only by them gives the same OCP records as ``soilocp import`` of that bag followed by
    ``soilocp estimate``.  Tolerance: 1e-12 relative, as for the live chain against the offline
    one (tests/test_services_e2e.py): the live reader converts and aligns with the import's own
    functions, the float64 values cross CDR unchanged, so any difference is a bug, not noise.
(b) SDK subscribers (which decode the CDR with rosbags) receive our /soilocp/<vid>/estimate and
    /diagnostics; the SDK's graph discovery sees our node, subscriptions and publishers; the raw
    samples carry rmw_zenoh's attachment.

Real Zenoh sessions in separate processes, explicit endpoints, multicast scouting off, ephemeral
ports.  The robot's router (rmw_zenohd on a robot) is a plain Zenoh router, ``soilocp router``.
"""

from __future__ import annotations

import json
import struct
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from soilocp.ingest import load_map
from soilocp.ingest.bag_writer import write_bag
from soilocp.ingest.live import LiveAligner
from soilocp.ingest.rosbag_import import import_bag
from soilocp.sim.simulator import simulate
from zenoh_helpers import Procs, client, endpoint, free_port, wait_for

VID = "rover1"
DRIVE_S = 8.0
MAP = f"""\
vehicle_id: {VID}
rate_hz: 100
imu: {{topic: /imu/data}}
joint_states: {{topic: /joint_states, wheels: [rear_left_wheel, front_left_wheel, front_right_wheel, rear_right_wheel]}}
ground_speed: {{topic: /odom}}
"""
REPO = Path(__file__).resolve().parents[1]
SDK_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState", "nav_msgs/msg/Odometry",
             "diagnostic_msgs/msg/DiagnosticArray")


def _write_msg_dir(d: Path) -> Path:
    """.msg files for the SDK (it would otherwise git-clone them): the standard types as rosbags
    knows them, and our SoilEstimate.msg as shipped."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    sep = "=" * 80 + "\n"
    for t in SDK_TYPES:
        text, _ = ts.generate_msgdef(t, ros_version=2)
        parts = text.split(sep)
        for name, body in [(t, parts[0])] + [(p.split("\n", 1)[0][len("MSG: "):], p.split("\n", 1)[1]) for p in parts[1:]]:
            pkg, *_, short = name.split("/")
            f = d / pkg / "msg" / f"{short}.msg"
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(body)
    f = d / "soilocp_msgs" / "msg" / "SoilEstimate.msg"
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text((REPO / "services/ros2/soilocp_msgs/msg/SoilEstimate.msg").read_text())
    return d


def _cli(*args, timeout=180):
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", *args], capture_output=True, text=True, timeout=timeout,
                       cwd=REPO)
    assert r.returncode == 0, r.stderr + r.stdout
    return r


def _read(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("ros2")
    samples = [s for s, _ in simulate("sand", duration=DRIVE_S, seed=3, vehicle_id=VID)]
    bag = write_bag(samples, d / "bag")  # /imu/data 100 Hz, /joint_states 50 Hz (shuffled joints), /odom 20 Hz
    (d / "map.yaml").write_text(MAP)
    return d, bag, samples


@pytest.mark.parametrize("variant", ["odometry", "twist_stamped+imu_without_orientation"])
def test_live_aligner_gives_the_bag_imports_samples(drive, tmp_path, variant):
    """The bag's messages, one at a time in log order, give the import's samples byte for byte
    (also with TwistStamped ground speed and the attitude from gyro + accelerometer)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    d, bag, samples = drive
    tmap = load_map(d / "map.yaml")
    if variant != "odometry":
        bag = write_bag(samples, tmp_path / "bag", types={"/odom": "geometry_msgs/msg/TwistStamped"})
        (tmp_path / "map.yaml").write_text(MAP.replace("imu: {topic: /imu/data}",
                                                       "imu: {topic: /imu/data, attitude: estimate}"))
        tmap = load_map(tmp_path / "map.yaml")
    import_bag(bag, tmap, tmp_path / "imp.jsonl", progress=False)
    al = LiveAligner(tmap)
    out = []
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        for i, (c, t, raw) in enumerate(r.messages()):
            msg = r.deserialize(raw, c.msgtype)
            if i == 300:  # a message stamped before its topic's previous one: dropped with the import's reason
                old = r.deserialize(raw, c.msgtype)
                old.header.stamp.sec -= 1
                al.add(al.role_of(c.topic), old, c.msgtype, t)
            al.add(al.role_of(c.topic), msg, c.msgtype, t)
            out += al.ready()
    assert out, "nothing released before the end of the drive"
    out += al.flush()
    assert [s.model_dump_json() for s in out] == (tmp_path / "imp.jsonl").read_text().splitlines()
    [(what, n)] = al.dropped().items()
    assert n == 1 and "goes backwards" in what


@pytest.fixture(scope="module")
def live_run(drive):
    d, bag, _samples = drive
    offline_log, offline_est = d / "imported.jsonl", d / "estimates.jsonl"
    ros_port, soil_port = free_port(), free_port()
    ros_ep, soil_ep = endpoint(ros_port), endpoint(soil_port)
    msg_dir = _write_msg_dir(d / "msg")
    procs = Procs(d / "logs")
    run = None
    try:
        procs.spawn("robot-router", ["router", "--listen", ros_ep])
        env = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
        run = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--ros2-in", str(d / "map.yaml"), "--ros2",
                                "--ros2-connect", ros_ep, "--ros2-domain", "0", "--listen", soil_ep, "--plain",
                                "--log-dir", str(d / "run-logs")],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO, env=env)
        # the reference, while the services start: soilocp import of the bag, then soilocp estimate
        _cli("import", str(bag), "--map", str(d / "map.yaml"), "--out", str(offline_log))
        _cli("estimate", str(offline_log), "--out", str(offline_est))
        offline = _read(offline_est)
        got: list[dict] = []
        with client(soil_ep) as s:
            sub = s.declare_subscriber(f"soilocp/{VID}/ocp", lambda smp: got.append(json.loads(smp.payload.to_bytes())))
            robot_env = dict(env, ZENOH_CONFIG_OVERRIDE="scouting/multicast/enabled=false")
            r = subprocess.run([sys.executable, str(REPO / "tests/ros2_robot.py"), str(bag), str(msg_dir),
                                str(ros_port), VID, str(len(offline)), "--speed", "2", "--timeout", "60"],
                               capture_output=True, text=True, timeout=150, cwd=REPO, env=robot_env)
            assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
            robot = json.loads(r.stdout.strip().splitlines()[-1])
            wait_for(lambda: len(got) >= len(offline), 10)
            sub.undeclare()
        run.send_signal(signal.SIGINT)
        out, _ = run.communicate(timeout=60)
        yield dict(offline=offline, live=got, robot=robot, run_rc=run.returncode, run_out=out,
                   imported=_read(offline_log), logs=d / "run-logs")
    finally:
        if run is not None and run.poll() is None:
            run.kill()
            run.wait(10)
        procs.close()


def _reader_report(robot) -> dict:
    """What each service counted (its health, relayed in /diagnostics), for a failure's message: on
    a starved machine the observer gives up joins (its "dropped"), which no ROS 2 code can mend."""
    for arr in reversed(robot.get("diagnostics", [])):
        if any(s["name"].endswith("/ros2-in") for s in arr):
            return {s["name"].rsplit("/", 1)[1]: {k: s["values"].get(k) for k in ("received", "published", "dropped")}
                    for s in arr if "values" in s}
    return {"published": robot.get("published"), "estimates": len(robot.get("estimates", []))}


def test_a_live_ros2_input_gives_the_bag_imports_estimates(live_run):
    offline, live = live_run["offline"], live_run["live"]
    assert live_run["run_rc"] == 130, live_run["run_out"][-3000:]  # stopped by the signal, nothing died
    assert len(offline) == len(live_run["imported"]) >= int(DRIVE_S * 100)  # every tick of the drive
    why = _reader_report(live_run["robot"])
    assert [r["seq"] for r in live] == [r["seq"] for r in offline], (len(live), len(offline), why)
    assert any(r["soil_strength"] is not None for r in offline)
    for lv, off in zip(live, offline):
        assert set(lv) == set(off)
        bad = [k for k in off if not _same(lv[k], off[k])]
        assert not bad, (off["seq"], {k: (lv[k], off[k]) for k in bad})


def test_b_sdk_subscriber_receives_and_decodes_our_topics(live_run):
    robot, offline = live_run["robot"], live_run["offline"]
    assert not robot["errors"], robot["errors"][:3]
    # the SDK's own graph discovery: our reader on the robot's topics, our writer on ours
    graph = dict((t, types) for t, types in robot["graph"])
    assert graph["/soilocp/rover1/estimate"] == ["soilocp_msgs/msg/SoilEstimate"]
    assert graph["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    assert ["soilocp_ros2_in", "sensor_msgs/msg/Imu"] in robot["subscribers"]["/imu/data"]
    assert ["soilocp_ros2_in", "nav_msgs/msg/Odometry"] in robot["subscribers"]["/odom"]
    [(node, typ, hash_, qos)] = robot["estimate_publishers"]
    assert (node, typ) == ("soilocp", "soilocp_msgs/msg/SoilEstimate") and hash_.startswith("RIHS01_")
    # every estimate, decoded from CDR by the SDK (rosbags), equals the offline record
    est = robot["estimates"]
    assert [e["seq"] for e in est] == [r["seq"] for r in offline]
    for e, off in zip(est, offline):
        assert e["vehicle_id"] == VID and e["frame_id"] == "base_link"
        assert math.isclose(e["stamp"], off["stamp"], abs_tol=1e-6)  # builtin_interfaces/Time: ns
        for k in ("status", "reason", "soil_class", "mu_determined"):
            assert e[k] == off[k], (off["seq"], k)
        for k in ("soil_strength", "soil_strength_std", "soil_class_confidence", "mu_T", "S_T", "S_E", "te_at_S_E",
                  "mu", "slip"):
            assert _same(e[k], off[k]), (off["seq"], k, e[k], off[k])
    # rmw_zenoh's attachment: 33 bytes, sequence 1, 2, 3... per publisher, a 16-byte GID, CDR encoding
    att = robot["attachments"]
    assert len(att) == len(est)
    assert {a["len"] for a in att} == {33} and {a["gid_len"] for a in att} == {16}
    assert [a["seq"] for a in att] == list(range(1, len(att) + 1))
    assert len({a["gid"] for a in att}) == 1 and abs(att[-1]["ts"] / 1e9 - time.time()) < 300
    assert {a["encoding"] for a in att} == {"application/cdr"}
    # diagnostics: the estimate and each service, with robot_localization's levels; during the
    # drive every service is running (OK), the estimate is OK or WARN (status: reason)
    names = [f"soilocp/{VID}/{svc}" for svc in ("gateway", "normal-force", "observer", "soil-strength", "ocp", "ros2-in")]
    arrays = [{s["name"]: s for s in arr} for arr in robot["diagnostics"]]
    driving = [a for a in arrays if all(n in a and a[n]["level"] == 0 for n in names)
               and a[f"soilocp/{VID}/estimate"]["level"] in (0, 1)]
    assert driving, [{n: (s["level"], s["message"]) for n, s in a.items()} for a in arrays]
    for a in driving:
        assert all(a[n]["message"] == "running" for n in names)
        e = a[f"soilocp/{VID}/estimate"]
        assert e["values"]["seq"].isdigit() and e["message"].split(":")[0] in ("ok", "uncertain", "holding",
                                                                             "no_estimate", "not_observable")
    # after the drive the OCP service says its input stopped: STALE, not OK
    for a in arrays:
        s = a[f"soilocp/{VID}/ocp"]
        assert s["level"] == (3 if s["values"]["state"] == "stale" else 0), s
    assert int(arrays[-1][f"soilocp/{VID}/ros2-in"]["values"]["dropped"]) == 0


# --- the reader's checks and the wire helpers, without sessions ------------------------------------
def _reader(drive):
    import io

    from soilocp.services.ros2.ros2_in import Ros2InService
    from soilocp.services.runtime.config import ServiceConfig
    from soilocp.services.runtime.log import JsonLog

    d, _bag, _samples = drive
    return Ros2InService(ServiceConfig(vehicle_ids=[VID]), JsonLog("ros2-in", "error", stream=io.StringIO()),
                         tmap=load_map(d / "map.yaml"), ros2_connect=["tcp/127.0.0.1:7447"])


def test_reader_drops_what_does_not_fit_with_its_reason(drive):
    from soilocp.services.ros2 import rmw_zenoh as rz

    svc = _reader(drive)
    ts = rz.typestore()
    T = ts.types
    imu = T["sensor_msgs/msg/Imu"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000, nanosec=0),
                                        frame_id="imu"),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
        angular_velocity=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.1), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81),
        linear_acceleration_covariance=np.zeros(9))
    cdr = bytes(ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
    att = rz.attachment(1, 5, bytes(16))
    key = rz.topic_key(0, "/imu/data", "sensor_msgs/msg/Imu")
    svc._decode(key, cdr, att, 1)  # good
    svc._decode(key.replace("Imu_", "Temperature_"), cdr, att, 2)  # another type on the topic
    svc._decode(key.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64, cdr, att, 3)  # another definition
    svc._decode(key.rsplit("/", 1)[0] + "/" + rz.NO_TYPE_HASH, cdr, att, 4)  # Humble: accepted
    svc._decode(key, cdr, None, 5)  # not from rmw_zenoh
    svc._decode(key, cdr, b"\x01\x02", 6)  # a broken attachment
    svc._decode(key, b"\x00\x01\x00\x00\x07", att, 7)  # truncated CDR
    reasons = svc.aligner.dropped()
    assert len(svc.aligner.readers["imu"].rows) == 2  # the good one and the Humble one
    assert any(k.startswith("/imu/data: type: sensor_msgs::msg::dds_::Temperature_ cannot feed imu") for k in reasons)
    assert any(k.startswith("/imu/data: type_hash: RIHS01_000") and "definition differs" in k for k in reasons)
    assert "/imu/data: attachment: missing (not an rmw_zenoh publisher)" in reasons
    assert any(k.startswith("/imu/data: attachment: not an rmw_zenoh attachment") for k in reasons)
    assert any(k.startswith("/imu/data: payload: CDR does not decode as sensor_msgs/msg/Imu: ") for k in reasons)
    assert sum(reasons.values()) == 5


def test_wire_helpers_follow_design_md():
    from soilocp.services.ros2 import rmw_zenoh as rz

    # design.md's own example: chatter, std_msgs/String, domain 0
    assert rz.topic_key(0, "/chatter", "std_msgs/msg/String") == (
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
    assert rz.split_topic_key("2/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_x") == (
        2, "/robot1/chatter", "std_msgs::msg::dds_::String_", "RIHS01_x")
    assert rz.ros_type_name("sensor_msgs::msg::dds_::Imu_") == "sensor_msgs/msg/Imu"
    assert rz.endpoint_token(2, "8b20", 0, 10, "MP", "/", "talker", "/chatter", "std_msgs/msg/String",
                             qos="::,7:,:,:,,") == (
        "@ros2_lv/2/8b20/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")
    raw = rz.attachment(7, 1_700_000_000_123_456_789, bytes(range(16)))
    assert raw == struct.pack("<qqB", 7, 1_700_000_000_123_456_789, 16) + bytes(range(16))
    assert rz.parse_attachment(raw) == (7, 1_700_000_000_123_456_789, bytes(range(16)))
    for bad in ("imu", "/imu/", "//imu", "/imu/1data", "/imu data"):
        with pytest.raises(ValueError, match="topic"):
            rz.check_topic(bad)


def test_run_refuses_the_robots_router_on_its_own_port(drive):
    d, _bag, _samples = drive
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "run", "--ros2-in", str(d / "map.yaml")],
                       capture_output=True, text=True, timeout=60, cwd=REPO)
    assert r.returncode == 2 and "give --listen another endpoint" in r.stderr, r.stderr


def test_reader_names_the_robots_topics_when_a_mapped_one_stays_silent(drive, tmp_path):
    """The robot publishes /imu, the map says /imu/data: the reader's log lists what the graph has."""
    from soilocp.services.ros2 import rmw_zenoh as rz

    d, _bag, _samples = drive
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        with client(ep) as s:
            tok = s.liveliness().declare_token(rz.endpoint_token(0, str(s.zid()), 0, 1, "MP", "/", "imu_driver", "/imu",
                                                                 "sensor_msgs/msg/Imu"))
            procs.spawn("ros2-in", ["service", "ros2-in", "--vehicle-id", VID, "--connect", ep, "--ros2-connect", ep,
                                    "--ros2-map", str(d / "map.yaml"), "--wait-timeout", "0"])
            line = wait_for(lambda: next((x for x in procs.log_text("ros2-in").splitlines()
                                          if "ros2_topics_silent" in x), None), 40)
            tok.undeclare()
        assert line, procs.log_text("ros2-in")[-2000:]
        rec = json.loads(line)
        assert rec["silent"] == ["/imu/data", "/joint_states", "/odom"]
        assert rec["published_in_graph"] == {"/imu": ["sensor_msgs/msg/Imu"]}
    finally:
        procs.close()


def test_live_aligner_stays_bounded_while_a_stream_never_starts(drive):
    """/odom never arrives: nothing is written (no clock yet) and the IMU buffer stays ~max_age + lag long."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    d, bag, _samples = drive
    al = LiveAligner(load_map(d / "map.yaml"))
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        for c, t, raw in r.messages():
            if c.topic != "/odom":
                al.add(al.role_of(c.topic), r.deserialize(raw, c.msgtype), c.msgtype, t)
                assert al.ready() == []
    assert al.flush() == []
    imu = al._buf["imu"]
    assert (imu.stamps[-1] - imu.stamps[0]) / 1e9 <= 0.05 + 0.5 and len(imu.stamps) <= 56
