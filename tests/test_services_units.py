"""Unit tests of the services' pure parts (no processes): keys, config, gateway checks, the
observer's join, the OCP store, the schema export."""

from __future__ import annotations

import json
import math

import pytest

from soilocp.schemas import keys
from soilocp.services.stages.graph import ALL_SERVICES
from soilocp.schemas.export import MESSAGE_MODELS, export_schemas
from soilocp.schemas.messages import OcpReply, Rejection
from soilocp.schemas.pipeline import NormalForces, OcpEstimate
from soilocp.schemas.sensor import SensorSample
from soilocp.services.stages.gateway import RawSampleChecker
from soilocp.services.stages.observer import SeqJoiner
from soilocp.services.stages.ocp import OcpStore, parse_parameters
from soilocp.services.runtime.config import ConfigError, load_service_config
from soilocp.services.runtime.worker import Counters


def _sample(seq: int, stamp: float, vid: str = "rover1", **kw) -> dict:
    d = dict(vehicle_id=vid, seq=seq, stamp=stamp, specific_force=[0.5, 0.0, 9.8], roll=0.0, pitch=-0.05,
             yaw_rate=0.0, wheel_speed=[5.0, 5.0, 5.0, 5.0], wheel_torque=[3.0, 3.0, 3.0, 3.0], ground_speed=0.45)
    d.update(kw)
    return d


# --- keys ----------------------------------------------------------------------------------------
def test_keys_are_built_from_validated_ids_only():
    assert keys.raw("rover_1-A") == "soilocp/rover_1-A/sensors/raw"
    assert keys.ocp("r") == "soilocp/r/ocp"
    assert keys.rejected("r") == "soilocp/r/rejected"
    assert keys.alive("r", "soil-strength") == "soilocp/r/alive/soil-strength"
    assert keys.status("r", "ocp") == "soilocp/r/status/ocp"
    for bad in ["", "a/b", "*", "**", "a*", "@x", "$*", "a?b", "a b", "a#", "x" * 65, None, 7]:
        with pytest.raises(ValueError, match="vehicle_id"):
            keys.raw(bad)
    with pytest.raises(ValueError, match="service"):
        keys.alive("r", "gate/way")
    assert keys.split_key("soilocp/r1/alive/gateway") == ("r1", "alive/gateway")
    assert keys.service_of_alive_key("soilocp/r1/alive/ocp") == ("r1", "ocp")
    with pytest.raises(ValueError):
        keys.service_of_alive_key("soilocp/r1/status/ocp")
    with pytest.raises(ValueError):
        keys.split_key("other/r1/ocp")


# --- configuration ------------------------------------------------------------------------------
def test_config_layers_file_env_cli(tmp_path):
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"vehicle_id": "filecar", "connect": ["tcp/10.0.0.1:7447"], "stale_timeout_s": 2.0,
                             "services": {"ocp": {"history_size": 50}}, "router": {"listen": ["tcp/0.0.0.0:7447"]}}))
    cfg = load_service_config("ocp", config_path=str(f), env={})
    assert (cfg.vehicle_ids, cfg.connect, cfg.stale_timeout_s, cfg.history_size) == (
        ["filecar"], ["tcp/10.0.0.1:7447"], 2.0, 50)
    assert load_service_config("gateway", config_path=str(f), env={}).history_size == 1000  # other section
    env = {"SOILOCP_CONFIG": str(f), "SOILOCP_VEHICLE_ID": "a,b", "SOILOCP_CONNECT": "tcp/h:1,tcp/h:2",
           "SOILOCP_MODE": "peer", "SOILOCP_LISTEN": "tcp/127.0.0.1:0", "SOILOCP_LOG_LEVEL": "DEBUG",
           "SOILOCP_STALE_TIMEOUT": "0.25"}
    cfg = load_service_config("ocp", env=env)
    assert (cfg.vehicle_ids, cfg.connect, cfg.mode, cfg.listen, cfg.log_level, cfg.stale_timeout_s) == (
        ["a", "b"], ["tcp/h:1", "tcp/h:2"], "peer", ["tcp/127.0.0.1:0"], "debug", 0.25)
    cfg = load_service_config("ocp", env=env, overrides={"vehicle_ids": ("cli",), "stale_timeout_s": 3.0})
    assert (cfg.vehicle_ids, cfg.stale_timeout_s) == (["cli"], 3.0)


@pytest.mark.parametrize("env, needle", [
    ({"SOILOCP_VEHICLE_ID": "a/b"}, "vehicle_ids"),
    ({"SOILOCP_MODE": "router"}, "mode"),
    ({"SOILOCP_STALE_TIMEOUT": "-1"}, "stale_timeout_s"),
    ({"SOILOCP_STALE_TIMEOUT": "x"}, "SOILOCP_STALE_TIMEOUT"),
    ({"SOILOCP_CONNECT": "127.0.0.1:7447"}, "endpoint"),
    ({"SOILOCP_CONFIG": "/nonexistent.json"}, "/nonexistent.json"),
])
def test_config_errors_are_one_line_and_name_the_setting(env, needle):
    with pytest.raises(ConfigError) as ei:
        load_service_config("ocp", env=env)
    assert needle in str(ei.value) and "\n" not in str(ei.value)


def test_config_file_with_unknown_key_is_fatal(tmp_path):
    f = tmp_path / "c.json"
    f.write_text('{"stale_timeout": 1}')
    with pytest.raises(ConfigError, match="stale_timeout"):
        load_service_config("ocp", config_path=str(f), env={})
    f.write_text("[1]")
    with pytest.raises(ConfigError, match="object"):
        load_service_config("ocp", config_path=str(f), env={})


def test_deploy_single_machine_config_is_valid():
    from pathlib import Path

    from soilocp.services.router import router_settings

    path = Path(__file__).resolve().parents[1] / "deploy" / "single-machine.json"
    for name in ALL_SERVICES:
        cfg = load_service_config(name, config_path=str(path), env={})
        assert cfg.vehicle_ids == ["rover1"] and cfg.connect == ["tcp/127.0.0.1:7447"]
    assert router_settings(str(path), (), (), env={})["listen"] == ["tcp/127.0.0.1:7447"]


# --- gateway checks ------------------------------------------------------------------------------
def test_gateway_checker_accepts_good_and_rejects_each_bad_kind():
    chk = RawSampleChecker("rover1", max_payload_bytes=6000)
    ok = chk.check(json.dumps(_sample(0, 0.0)).encode())
    assert isinstance(ok, SensorSample) and ok.seq == 0
    good1 = json.dumps(_sample(1, 0.01))
    cases = [
        (b'{"seq": 1,', "malformed_json", None),
        (good1.replace('"roll": 0.0', '"roll": NaN').encode(), "non_finite", "roll"),
        (good1.replace('"ground_speed": 0.45', '"ground_speed": 1e400').encode(), "non_finite", "ground_speed"),
        (json.dumps(_sample(1, 0.01, pitch=3.0)).encode(), "out_of_range", "pitch"),
        (json.dumps(_sample(1, 0.01, roll="flat")).encode(), "schema", "roll"),
        (json.dumps(_sample(1, 0.01, vehicle_id="rover2")).encode(), "vehicle_mismatch", "vehicle_id"),
        (json.dumps(_sample(0, 0.01)).encode(), "duplicate_seq", "seq"),
        (b"x" * 7000, "too_large", "payload"),
        (b'{"seq": ' + b"9" * 4400 + b"}", "malformed_json", "payload"),  # beyond Python's int parsing limit
        (b"[" * 2000 + b"]" * 2000, "malformed_json", "payload"),  # nested past the recursion limit
    ]
    for payload, code, field in cases:
        res = chk.check(payload)
        assert isinstance(res, Rejection), (code, res)
        assert res.code == code and res.vehicle_id == "rover1" and res.field == field, (code, res)
    # nothing rejected changed the ordering state: seq 1 is still welcome, an equal stamp is not "backwards"
    assert isinstance(chk.check(json.dumps(_sample(1, 0.0)).encode()), SensorSample)
    res = chk.check(json.dumps(_sample(5, 0.0)).encode(), key="soilocp/*/sensors/raw")
    assert isinstance(res, Rejection) and res.code == "bad_key" and res.seq == 5
    chk2 = RawSampleChecker("rover1")
    assert isinstance(chk2.check(json.dumps(_sample(10, 1.0)).encode()), SensorSample)
    res = chk2.check(json.dumps(_sample(11, 0.5)).encode())
    assert res.code == "stamp_backwards" and res.seq == 11 and res.stamp == 0.5
    res = chk2.check(json.dumps(_sample(3, 2.0)).encode())
    assert res.code == "old_seq" and "10" in res.message
    res = chk2.check(("é" * 2000).encode() + b"\xff")
    assert res.code == "malformed_json" and len(res.payload) <= 512 and res.payload_size == 4001
    with pytest.raises(ValueError, match="vehicle_id"):
        RawSampleChecker("a/b")


# --- observer join -------------------------------------------------------------------------------
class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _nf(seq: int) -> NormalForces:
    return NormalForces(vehicle_id="rover1", seq=seq, stamp=seq * 0.01, normal_force=(10.0, 10.0, 10.0, 10.0))


def test_seq_joiner_keeps_order_and_drops_lost_samples_after_timeout():
    out, c, clock = [], Counters(), _Clock()
    j = SeqJoiner(lambda s, f: out.append((s.seq, f.seq)), c, capacity=5, timeout_s=0.2, clock=clock)
    for q in range(3):
        j.add_sample(SensorSample.model_validate(_sample(q, q * 0.01)))
    j.add_forces(_nf(1))  # forces of 0 are late: 1 waits
    assert out == []
    j.add_forces(_nf(0))
    assert out == [(0, 0), (1, 1)]
    # forces of 2 lost; 3's arrive: 2 is given up only after the timeout
    j.add_sample(SensorSample.model_validate(_sample(3, 0.03)))
    j.add_forces(_nf(3))
    assert out[-1] == (1, 1) and c.dropped == 0
    clock.t = 0.5
    j.add_forces(_nf(4))  # no sample 4 yet; triggers the drain
    assert out[-1] == (3, 3) and c.dropped == 1 and c.detail["unjoined"] == 1
    # a sample older than what was emitted (gateway restarted) is refused, not fed to the observer
    j.add_sample(SensorSample.model_validate(_sample(2, 0.02)))
    assert c.detail["out_of_order"] == 1 and out[-1] == (3, 3)
    # the buffer is bounded
    for q in range(5, 12):
        j.add_sample(SensorSample.model_validate(_sample(q, q * 0.01)))
    assert j.pending() <= 5 and c.detail["unjoined"] >= 3


# --- OCP store -----------------------------------------------------------------------------------
def _est(seq: int) -> OcpEstimate:
    return OcpEstimate(vehicle_id="rover1", seq=seq, stamp=seq * 0.1, soil_strength=50.0, soil_strength_std=5.0,
                       mu_T=0.38, S_T=0.26, S_E=0.12, status="ok", mu=(0.1,) * 4, slip=(0.2,) * 4)


def test_ocp_store_latest_history_and_staleness():
    clock = _Clock()
    st = OcpStore("rover1", capacity=5, stale_timeout_s=0.5, clock=clock)
    r = st.reply({})
    assert r.stale and r.latest is None and r.age_s is None
    for q in range(8):
        clock.t = q * 0.1
        st.add(_est(q))
    clock.t = 0.9
    r = st.reply({})
    assert not r.stale and r.latest.seq == 7 and r.latest.status == "ok" and math.isclose(r.age_s, 0.2)
    assert r.history is None
    assert [e.seq for e in st.reply({"last": "3"}).history] == [5, 6, 7]
    assert [e.seq for e in st.reply({"last": "99"}).history] == [3, 4, 5, 6, 7]  # bounded history
    assert [e.seq for e in st.reply({"since": "0.6"}).history] == [6, 7]
    assert [e.seq for e in st.reply({"since": "0.4", "last": "1"}).history] == [7]
    clock.t = 1.31
    r = st.reply({})
    assert r.stale and r.latest.status == "stale" and "no input" in r.latest.reason and r.age_s > 0.5
    OcpReply.model_validate_json(r.model_dump_json())
    for bad in ({"last": "0"}, {"last": "x"}, {"since": "nan"}, {"since": "soon"}, {"other": "1"}):
        with pytest.raises(ValueError):
            st.reply(bad)
    assert parse_parameters("last=3;since=1.5") == {"last": "3", "since": "1.5"}
    assert parse_parameters("") == {}


# --- schema export -------------------------------------------------------------------------------
def test_schema_export_writes_one_versioned_schema_per_message(tmp_path):
    paths = export_schemas(tmp_path)
    assert len(paths) == len(MESSAGE_MODELS) >= 8
    names = {p.name for p in paths}
    assert {"SensorSample.schema.json", "OcpEstimate.schema.json", "OcpReply.schema.json",
            "Rejection.schema.json", "ServiceHealth.schema.json"} <= names
    for p in paths:
        s = json.loads(p.read_text())
        assert s["$schema"].startswith("https://json-schema.org/") and s["$id"].startswith("soilocp.")
        if p.name == "SensorSample.schema.json":
            assert s["$id"] == "soilocp.sensor_sample/1" and "schema_version" not in s["properties"]
        else:
            assert s["properties"]["schema_version"]["const"] == 1 and s["$id"].endswith("/1")
    rej = json.loads((tmp_path / "Rejection.schema.json").read_text())
    assert "bad_key" in rej["properties"]["code"]["enum"] and "malformed_json" in rej["properties"]["code"]["enum"]


def test_schemas_export_command_and_service_help(tmp_path):
    from click.testing import CliRunner

    from soilocp.cli.main import main

    r = CliRunner().invoke(main, ["schemas", "export", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    assert len(r.output.splitlines()) == len(MESSAGE_MODELS)
    assert json.loads((tmp_path / "out" / "OcpEstimate.schema.json").read_text())["$id"] == "soilocp.ocp_estimate/1"
    r = CliRunner().invoke(main, ["service", "--help"])
    assert r.exit_code == 0 and "SOILOCP_CONFIG" in r.output
    r = CliRunner().invoke(main, ["run", "--synthetic", "sand", "--replay", __file__])
    assert r.exit_code == 2 and "exactly one" in r.output


def test_bounded_worker_keeps_order_drops_beyond_its_bound_and_survives_a_failing_item():
    import threading
    import time

    from soilocp.services.runtime.worker import BoundedWorker

    gate, seen, dropped, failed = threading.Event(), [], [], []

    def handle(item):
        gate.wait(5)
        if item == 2:
            raise RuntimeError("bad item")
        seen.append(item)

    w = BoundedWorker("t", handle, 4, dropped.append, lambda item, exc: failed.append((item, str(exc))))
    w.start()
    try:
        # the worker holds at most one item (blocked on the gate) and the queue 4: of 8, 3 or 4 are dropped
        accepted = [w.offer(i) for i in range(8)]
        assert w.depth() <= 4 and accepted.count(False) in (3, 4)
        gate.set()
        kept = [i for i, a in zip(range(8), accepted) if a]
        deadline = time.monotonic() + 5
        while len(seen) + len(failed) < len(kept) and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        w.stop()
    assert dropped == [i for i, a in zip(range(8), accepted) if not a] and kept == list(range(len(kept)))
    assert seen == [i for i in kept if i != 2] and failed == [(2, "bad item")]
