"""ROS 2 bags in: a simulated drive written with rosbags (both storages, three rates, shuffled
joint order, Unix stamps) imports and estimates as accurately as its JSON log; hostile bags get
errors that name the topic, the field and the reason, and the good data around a bad stretch is kept."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from soilocp.cli.main import main
from soilocp.estimation.estimate import estimate_lines
from soilocp.analysis.evaluation import evaluate_records
from soilocp.ingest import load_map
from soilocp.ingest.bag_writer import UNIX_BASE, write_bag
from soilocp.ingest.rosbag_import import BagImportError, import_bag
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.sim.simulator import simulate

MAP = """\
vehicle_id: rover1
rate_hz: 100
imu: {topic: /imu/data}
joint_states: {topic: /joint_states, wheels: [rear_left_wheel, front_left_wheel, front_right_wheel, rear_right_wheel], effort_scale: 1.0}
ground_speed: {topic: /odom}
"""


@pytest.fixture(scope="module")
def drive():
    pairs = list(simulate("sand", duration=12.0, seed=3))
    return [s for s, _ in pairs], [t.model_dump() for _, t in pairs]


@pytest.fixture
def map_file(tmp_path) -> Path:
    p = tmp_path / "map.yaml"
    p.write_text(MAP)
    return p


def _read(path) -> list[dict]:
    return [json.loads(x) for x in Path(path).read_text().splitlines() if x.strip()]


def _k_stats(truth, samples_lines):
    est = list(estimate_lines(samples_lines, PipelineConfig()))
    seg = evaluate_records(truth, est)[0]
    # K over the last 4 s: one sample's K carries that sample's noise, which the three rates resample
    late = [r["soil_strength"] for r in est if r["soil_strength"] is not None and r["stamp"] >= est[-1]["stamp"] - 4.0]
    return seg.k_median_rel, float(np.median(late)), est


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_estimates_as_well_as_the_json_log(tmp_path, drive, map_file, storage):
    samples, truth = drive
    bag = write_bag(samples, tmp_path / "bag", storage=storage, joint_every=2, odom_every=5)  # 100 / 50 / 20 Hz
    out = tmp_path / "s.jsonl"
    res = CliRunner().invoke(main, ["import", str(bag), "--map", str(map_file), "--out", str(out)])
    assert res.exit_code == 0, res.output
    imported = _read(out)
    assert imported[0]["stamp"] == pytest.approx(UNIX_BASE, abs=1e-6)  # header stamps kept, Unix time
    assert [r["seq"] for r in imported[: len(samples)]] == list(range(len(samples)))  # no tick skipped
    # held values: joints at 50 Hz -> odd ticks repeat the even tick's wheel speeds
    assert imported[3]["wheel_speed"] == imported[2]["wheel_speed"]
    # shuffled joint order in the bag, product order in the log
    assert imported[400]["wheel_speed"] == pytest.approx(list(samples[400].wheel_speed))
    json_med, json_k, _ = _k_stats(truth, [s.model_dump_json() for s in samples])
    bag_med, bag_k, _ = _k_stats(truth, out.read_text().splitlines())
    assert json_med is not None and bag_med is not None
    assert abs(bag_med - json_med) <= 0.01, (bag_med, json_med)
    assert abs(bag_k - json_k) <= 0.01 * json_k, (bag_k, json_k)
    assert bag_med <= 0.10  # and both meet the accuracy target


def test_bare_mcap_file_and_twist_stamped(tmp_path, drive, map_file):
    samples, _ = drive
    bag = write_bag(samples[:300], tmp_path / "bag", storage="mcap",
                    types={"/odom": "geometry_msgs/msg/TwistStamped"})
    (mcap_file,) = bag.glob("*.mcap")
    prov, issues = import_bag(mcap_file, load_map(map_file), tmp_path / "s.jsonl")
    assert prov.samples >= 300 and not issues
    rec = _read(tmp_path / "s.jsonl")[100]
    assert rec["ground_speed"] == pytest.approx(samples[100].ground_speed)


def test_estimate_bag_with_map_writes_mcap(tmp_path, drive, map_file):
    samples, _ = drive
    bag = write_bag(samples[:400], tmp_path / "bag", storage="sqlite3")
    res = CliRunner().invoke(main, ["estimate", str(bag), "--map", str(map_file), "--out", str(tmp_path / "E.mcap")])
    assert res.exit_code == 0, res.output
    from mcap.reader import make_reader

    with open(tmp_path / "E.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert "/soilocp/rover1/soil_strength" in topics


def test_skid_steer_side_joints_share_speed_and_split_effort(tmp_path, drive):
    samples, _ = drive
    bag = write_bag(samples[:50], tmp_path / "bag", joint_names=("left", "x1", "right", "x2"))
    m = tmp_path / "m.yaml"
    m.write_text(MAP.replace("[rear_left_wheel, front_left_wheel, front_right_wheel, rear_right_wheel]",
                             "[left, left, right, right]").replace("effort_scale: 1.0", "effort_scale: 2.0"))
    prov, _ = import_bag(bag, load_map(m), tmp_path / "s.jsonl")
    assert prov.drive == "per_side"
    r, s = _read(tmp_path / "s.jsonl")[40], samples[40]
    assert r["wheel_speed"] == pytest.approx([s.wheel_speed[0]] * 2 + [s.wheel_speed[2]] * 2)
    # effort x scale / 2 wheels per side
    assert r["wheel_torque"] == pytest.approx([s.wheel_torque[0]] * 2 + [s.wheel_torque[2]] * 2)


# --- hostile bags --------------------------------------------------------------------------------
def test_missing_topic(tmp_path, drive, map_file):
    bag = write_bag(drive[0][:50], tmp_path / "bag")
    m = tmp_path / "m.yaml"
    m.write_text(MAP.replace("/odom", "/gnss/odom"))
    with pytest.raises(BagImportError, match=r"/gnss/odom: topic not in the bag \(map key ground_speed.topic\).*/odom"):
        import_bag(bag, load_map(m), tmp_path / "s.jsonl")


def test_wrong_message_type(tmp_path, drive, map_file):
    bag = write_bag(drive[0][:50], tmp_path / "bag", types={"/odom": "sensor_msgs/msg/Imu"},
                    mutate=lambda t, i, m: None if t == "/odom" else m)
    with pytest.raises(BagImportError, match=r"/odom: message type sensor_msgs/msg/Imu cannot feed ground_speed.*"
                                             r"nav_msgs/msg/Odometry or geometry_msgs/msg/TwistStamped"):
        import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")


def test_joint_name_not_in_bag(tmp_path, drive, map_file):
    bag = write_bag(drive[0][:50], tmp_path / "bag", joint_names=("wheel_rl", "wheel_fl", "wheel_fr", "wheel_rr"))
    with pytest.raises(BagImportError, match=r"/joint_states: name: joint 'rear_left_wheel' "
                                             r"\(map key joint_states.wheels\[0\]\) is not in the bag.*wheel_fl"):
        import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")


def _nan_imu(t, i, m):
    if t == "/imu/data" and 200 <= i < 250:
        m.linear_acceleration.x = math.nan
    return m


def test_nan_values_dropped_with_reason_and_good_data_kept(tmp_path, drive, map_file):
    samples = drive[0][:600]
    bag = write_bag(samples, tmp_path / "bag", mutate=_nan_imu)
    prov, issues = import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    assert any(line.startswith("/imu/data: linear_acceleration.x: NaN value (50 messages dropped") for line in issues), issues
    seqs = {r["seq"] for r in _read(tmp_path / "s.jsonl")}
    # held up to 0.05 s = 5 ticks, then stale: ticks 205..249 skipped, the rest kept
    assert set(range(0, 205)) <= seqs and set(range(250, 600)) <= seqs
    assert not seqs & set(range(205, 250))
    assert prov.skipped == {"stale imu (/imu/data) (older than 0.05 s)": 45}
    with pytest.raises(BagImportError, match=r"/imu/data: linear_acceleration.x: NaN value .*--strict"):
        import_bag(bag, load_map(map_file), tmp_path / "s2.jsonl", strict=True)


def test_stamps_going_backwards_dropped_with_reason(tmp_path, drive, map_file):
    samples = drive[0][:600]

    def back(t, i, m):
        if t == "/joint_states" and 300 <= i < 320:
            m.header.stamp.sec -= 1  # a stretch one second in the past
        return m

    bag = write_bag(samples, tmp_path / "bag", mutate=back)
    prov, issues = import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    assert issues == ["/joint_states: header.stamp: goes backwards (earlier than the previous message) "
                      "(10 messages dropped, first at stamp 1700000002.000, by 0.980 s)"]
    seqs = {r["seq"] for r in _read(tmp_path / "s.jsonl")}
    assert set(range(0, 309)) <= seqs and set(range(320, 600)) <= seqs  # last good 298, held 0.1 s; next good 320
    assert prov.skipped == {"stale joint_states (/joint_states) (older than 0.1 s)": 11}


def test_stale_ground_speed_skips_ticks_and_counts(tmp_path, drive, map_file):
    samples = drive[0][:600]
    bag = write_bag(samples, tmp_path / "bag", mutate=lambda t, i, m: None if t == "/odom" and 200 <= i < 300 else m)
    prov, issues = import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    assert not issues
    # odom every 5 ticks; last before the gap at 195, next at 300; held 0.25 s -> 221..299 stale
    assert prov.skipped == {"stale ground_speed (/odom) (older than 0.25 s)": 79}
    got = _read(tmp_path / "s.jsonl")
    assert all(np.isfinite(r["ground_speed"]) for r in got)


def test_cli_error_names_topic_and_exits_nonzero(tmp_path, drive):
    bag = write_bag(drive[0][:30], tmp_path / "bag")
    m = tmp_path / "m.yaml"
    m.write_text(MAP.replace("topic: /imu/data", "topic: /imu"))
    res = CliRunner().invoke(main, ["import", str(bag), "--map", str(m), "--out", str(tmp_path / "s.jsonl")])
    assert res.exit_code != 0 and "/imu: topic not in the bag (map key imu.topic)" in res.output


def test_bad_map_file_names_the_key(tmp_path):
    m = tmp_path / "m.yaml"
    m.write_text(MAP.replace("rate_hz: 100", "rate_hz: -5"))
    with pytest.raises(ValueError, match=r"rate_hz: Input should be greater than 0"):
        load_map(m)


def test_imu_without_orientation_uses_gyro_and_accelerometer(tmp_path, map_file):
    samples = [s for s, _ in simulate("sandy-slope", duration=8.0, seed=1)]

    def no_orientation(t, i, m):
        if t == "/imu/data":
            m.orientation_covariance[0] = -1.0  # REP-145: this IMU gives no orientation
        return m

    bag = write_bag(samples, tmp_path / "bag", mutate=no_orientation)
    prov, _ = import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    assert prov.attitude.startswith("gyro+accelerometer")
    got = _read(tmp_path / "s.jsonl")
    true_pitch = np.array([s.pitch for s in samples[400:800]])
    est_pitch = np.array([r["pitch"] for r in got[400:800]])
    assert abs(np.median(est_pitch - true_pitch)) < 0.02  # rad: the slope's pitch, not zero


def test_documented_map_is_the_shipped_ros2_map():
    root = Path(__file__).resolve().parents[1]
    page = (root / "docs" / "import.md").read_text()  # "Your robot's data" on the docs site
    section = page.split("## The map file", 1)[1].split("\n## ", 1)[0]
    block = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    assert block == (root / "docs" / "maps" / "ros2-robot.yaml").read_text()
    assert load_map(root / "docs" / "maps" / "ros2-robot.yaml").joint_states.wheels[0] == "rear_left_wheel"


def test_not_a_bag_and_an_all_bad_topic(tmp_path, drive, map_file):
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagImportError, match=r"not a readable ROS 2 bag"):
        import_bag(tmp_path / "empty", load_map(map_file), tmp_path / "s.jsonl")
    bag = write_bag(drive[0][:50], tmp_path / "bag", mutate=lambda t, i, m: (
        setattr(m.twist.twist.linear, "x", math.nan) or m) if t == "/odom" else m)
    with pytest.raises(BagImportError, match=r"/odom: no usable message \(map key ground_speed.topic\)"):
        import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")


def test_unstamped_driver_error_suggests_receive_clock(tmp_path, drive, map_file):
    def unstamped(t, i, m):
        if t == "/joint_states":
            m.header.stamp.sec, m.header.stamp.nanosec = 0, 0
        return m

    bag = write_bag(drive[0][:100], tmp_path / "bag", mutate=unstamped)
    with pytest.raises(BagImportError, match=r"/joint_states: no usable message.*/joint_states: header.stamp: zero or "
                                             r"negative: the driver does not stamp.*clock: receive"):
        import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    m = tmp_path / "m.yaml"
    m.write_text(map_file.read_text() + "clock: receive\n")
    prov, issues = import_bag(bag, load_map(m), tmp_path / "s.jsonl")
    assert not issues and prov.samples >= 100
    assert _read(tmp_path / "s.jsonl")[0]["stamp"] == pytest.approx(UNIX_BASE + 0.002)  # log time = stamp + 2 ms


def test_one_stamp_far_ahead_loses_only_itself(tmp_path, drive, map_file):
    def ahead(t, i, m):
        if t == "/odom" and i == 100:
            m.header.stamp.sec += 86_400  # a clock glitch: one message a day in the future
        return m

    bag = write_bag(drive[0][:400], tmp_path / "bag", mutate=ahead)
    prov, issues = import_bag(bag, load_map(map_file), tmp_path / "s.jsonl")
    assert issues == ["/odom: header.stamp: jumps ahead (later than the messages after it) "
                      "(1 message dropped, first at stamp 1700086401.000, by 86399.950 s)"]
    assert prov.skipped == {} and prov.samples >= 400  # the held value bridges the one lost message
