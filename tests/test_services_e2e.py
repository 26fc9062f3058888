"""End-to-end tests of the services: real processes, a real Zenoh router on an ephemeral
loopback port, explicit endpoints, multicast scouting off; every process is reaped."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from soilocp.schemas.export import export_schemas
from soilocp.schemas.messages import OcpReply, Rejection, ServiceHealth
from soilocp.schemas.pipeline import OcpEstimate

from zenoh_helpers import (PIPELINE, Procs, alive_services, client, endpoint, free_port, get_payloads,
                            start_pipeline, wait_alive, wait_count, wait_for, write_log)

pytestmark = pytest.mark.timeout(240)  # generous: other suites may load the machine


@pytest.fixture(scope="module")
def router(tmp_path_factory):
    """One router for the module; each test runs its own services under its own vehicle id."""
    ep = endpoint(free_port())
    procs = Procs(tmp_path_factory.mktemp("router"))
    try:
        procs.spawn("router", ["router", "--listen", ep])
        yield ep
    finally:
        codes = procs.close()
        assert codes["router"] == 0, procs.log_text("router")


@pytest.fixture
def procs(tmp_path):
    p = Procs(tmp_path / "logs")
    try:
        yield p
    finally:
        p.close()


class Collector:
    """Subscriber callback storing payloads (thread-safe append)."""

    def __init__(self):
        self.items: list[bytes] = []
        self.lock = threading.Lock()

    def __call__(self, sample):
        with self.lock:
            self.items.append(sample.payload.to_bytes())

    def __len__(self):
        return len(self.items)

    def models(self, cls):
        with self.lock:
            return [cls.model_validate_json(b) for b in self.items]


def _healths(session, vid: str) -> list[str]:
    """Every service's health of a vehicle, for failure messages."""
    return [p.decode()[:400] for p in get_payloads(session, f"soilocp/{vid}/status/*")]


def _offline_estimates(log: Path, out: Path) -> list[dict]:
    """``soilocp estimate`` on the same log: the reference the live stream must equal."""
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "estimate", str(log), "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return [json.loads(line) for line in out.read_text().splitlines() if line.strip()]


def _assert_same_records(live: list[OcpEstimate], offline: list[dict]) -> None:
    assert [e.seq for e in live] == [d["seq"] for d in offline]
    for e, d in zip(live, offline):
        ld = json.loads(e.model_dump_json())
        assert set(ld) == set(d), (set(ld) ^ set(d))
        for k, v in d.items():
            lv = ld[k]
            if isinstance(v, float) and isinstance(lv, float):
                assert math.isclose(lv, v, rel_tol=1e-12, abs_tol=1e-12), (e.seq, k, lv, v)
            elif isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
                assert lv == pytest.approx(v, rel=1e-12, abs=1e-12), (e.seq, k)
            else:
                assert lv == v, (e.seq, k, lv, v)


# --- the plain Zenoh client: no project imports --------------------------------------------------
PLAIN_CLIENT = textwrap.dedent("""
    import json, sys, zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    out = {}
    with zenoh.open(conf) as s:
        for sel in sys.argv[2:]:
            out[sel] = [json.loads(r.ok.payload.to_bytes()) for r in s.get(sel, timeout=5.0) if r.ok is not None]
    print(json.dumps(out))
""")


def _check(instance, schema, root, path="$"):
    """Validate ``instance`` against the JSON Schema subset pydantic emits (``jsonschema`` is not
    installed here): $ref, anyOf, type, const, enum, properties/required/additionalProperties,
    prefixItems/items/minItems/maxItems, minimum/maximum/exclusive*, pattern."""
    import re

    if "$ref" in schema:
        name = schema["$ref"].split("/")[-1]
        return _check(instance, root["$defs"][name], root, path)
    if "anyOf" in schema:
        errs = []
        for sub in schema["anyOf"]:
            try:
                _check(instance, sub, root, path)
                return
            except AssertionError as exc:
                errs.append(str(exc))
        raise AssertionError(f"{path}: matches no anyOf branch: {errs}")
    t = schema.get("type")
    types = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}
    if t == "integer":
        assert isinstance(instance, int) and not isinstance(instance, bool), f"{path}: not an integer: {instance!r}"
    elif t == "number":
        assert isinstance(instance, (int, float)) and not isinstance(instance, bool), f"{path}: not a number"
    elif t is not None:
        assert isinstance(instance, types[t]), f"{path}: expected {t}, got {type(instance).__name__}"
    if "const" in schema:
        assert instance == schema["const"], f"{path}: {instance!r} != const {schema['const']!r}"
    if "enum" in schema:
        assert instance in schema["enum"], f"{path}: {instance!r} not in {schema['enum']}"
    if "minimum" in schema:
        assert instance >= schema["minimum"], path
    if "maximum" in schema:
        assert instance <= schema["maximum"], path
    if "exclusiveMinimum" in schema:
        assert instance > schema["exclusiveMinimum"], path
    if "pattern" in schema:
        assert re.search(schema["pattern"], instance), f"{path}: {instance!r} !~ {schema['pattern']}"
    if isinstance(instance, dict):
        props = schema.get("properties", {})
        for req in schema.get("required", []):
            assert req in instance, f"{path}: required key {req!r} missing"
        if schema.get("additionalProperties") is False:
            extra = set(instance) - set(props)
            assert not extra, f"{path}: unexpected keys {extra}"
        for k, v in instance.items():
            if k in props:
                _check(v, props[k], root, f"{path}.{k}")
            elif isinstance(schema.get("additionalProperties"), dict):
                _check(v, schema["additionalProperties"], root, f"{path}.{k}")
    if isinstance(instance, list):
        if "minItems" in schema:
            assert len(instance) >= schema["minItems"], path
        if "maxItems" in schema:
            assert len(instance) <= schema["maxItems"], path
        prefix = schema.get("prefixItems", [])
        for i, v in enumerate(instance):
            sub = prefix[i] if i < len(prefix) else schema.get("items")
            if isinstance(sub, dict):
                _check(v, sub, root, f"{path}[{i}]")


def test_live_ocp_stream_equals_offline_estimate_and_plain_client_gets_valid_json(router, procs, tmp_path):
    vid = "clean1"
    log = tmp_path / "drive.jsonl"
    lines = write_log(log, vid, duration=12.0)
    start_pipeline(procs, router, vid)
    offline = _offline_estimates(log, tmp_path / "estimates.jsonl")  # while the services start
    assert len(offline) == len(lines) == 1200
    assert any(d["soil_strength"] is not None for d in offline)
    got = Collector()
    with client(router) as s:
        sub = s.declare_subscriber(f"soilocp/{vid}/ocp", got)
        assert wait_alive(s, vid), alive_services(s, vid)
        v = procs.spawn("vehicle", ["service", "vehicle", "--vehicle-id", vid, "--connect", router,
                                    "--replay", str(log), "--speed", "4"])
        assert v.wait(60) == 0, procs.log_text("vehicle")
        assert wait_count(lambda: len(got), len(offline)), (len(got), len(offline), _healths(s, vid))
        time.sleep(0.3)  # nothing more may arrive
        sub.undeclare()
        live = got.models(OcpEstimate)
        _assert_same_records(live, offline)

        # health: every stage saw every sample, dropped none, failed none
        for name in PIPELINE:
            [payload] = get_payloads(s, f"soilocp/{vid}/status/{name}")
            h = ServiceHealth.model_validate_json(payload)
            assert (h.published, h.dropped, h.errors, h.last_seq) == (1200, 0, 0, 1199), (name, h)
        # a wildcard get reaches every service of the vehicle (replies on their concrete keys)
        services = {ServiceHealth.model_validate_json(p).service for p in get_payloads(s, f"soilocp/{vid}/status/*")}
        assert services == set(PIPELINE)

    # a plain eclipse-zenoh client, no project imports, in its own process
    schema_dir = tmp_path / "schemas"
    export_schemas(schema_dir)
    script = tmp_path / "plain_client.py"
    script.write_text(PLAIN_CLIENT)
    sels = [f"soilocp/{vid}/ocp", f"soilocp/{vid}/ocp?last=5", f"soilocp/{vid}/ocp?since=11.5"]
    r = subprocess.run([sys.executable, "-I", str(script), router, *sels], capture_output=True, text=True,
                       timeout=60, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    replies = json.loads(r.stdout)
    schema = json.loads((schema_dir / "OcpReply.schema.json").read_text())
    for sel in sels:
        assert len(replies[sel]) == 1, (sel, replies)
        _check(replies[sel][0], schema, schema)
    latest = replies[sels[0]][0]
    assert latest["vehicle_id"] == vid and latest["stale"] is True  # the drive is over
    assert latest["latest"]["seq"] == 1199 and latest["latest"]["status"] == "stale" and latest["age_s"] > 0.5
    assert latest["history"] is None
    assert [e["seq"] for e in replies[sels[1]][0]["history"]] == [1195, 1196, 1197, 1198, 1199]
    assert [e["seq"] for e in replies[sels[2]][0]["history"]] == list(range(1150, 1200))
    assert replies[sels[1]][0]["history"][-1]["mu_T"] == offline[-1]["mu_T"]
    # the same schema rejects a broken reply: the hand validator can fail
    broken = dict(latest, stale="no")
    with pytest.raises(AssertionError):
        _check(broken, schema, schema)


def _hostile_payloads(good: list[dict], vid: str, at: int) -> list[tuple[str, bytes, str]]:
    """(key suffix or '' for the raw key, payload, expected code) inserted after good sample ``at``."""
    prev, nxt = good[at], good[at + 1]

    def js(d):
        return json.dumps(d).encode()

    def mod(**kw):
        d = dict(nxt)
        d.update(kw)
        return d

    no_pitch = {k: v for k, v in nxt.items() if k != "pitch"}
    return [
        ("", b"{not json", "malformed_json"),
        ("", b"\xff\xfe\x00garbage", "malformed_json"),
        ("", b"", "malformed_json"),
        ("", b"[1, 2, 3]", "malformed_json"),
        ("", b"[" * 2000 + b"]" * 2000, "malformed_json"),  # nesting beyond the parser's depth, within 4 KiB
        ("", b"[" * 30000 + b"]" * 30000, "too_large"),  # refused before parsing (max_payload_bytes)
        ("", js(mod(seq=0)).replace(b'"seq": 0', b'"seq": ' + b"9" * 5000), "too_large"),
        ("", js(mod()).replace(b'"ground_speed": ', b'"ground_speed": NaN, "x": '), "non_finite"),
        ("", js(mod(roll=0.0)).replace(b'"roll": 0.0', b'"roll": 1e999'), "non_finite"),
        ("", js(mod(wheel_torque=[1e9, 0.0, 0.0, 0.0])), "out_of_range"),
        ("", js(mod(stamp=-1.0)), "out_of_range"),
        ("", js(mod(seq=str(nxt["seq"]))), "schema"),
        ("", js(mod(seq=True)), "schema"),
        ("", js(no_pitch), "schema"),
        ("", js(mod(extra_field=1)), "schema"),
        ("", js(mod(wheel_speed=["fast", 1, 2, 3])), "schema"),
        ("", js(mod(stamp=prev["stamp"] - 0.05)), "stamp_backwards"),
        ("", js(prev), "duplicate_seq"),
        ("", js(good[at - 10]), "old_seq"),
        ("", js(mod(vehicle_id="rover1")), "vehicle_mismatch"),
        ("", js(mod(vehicle_id=f"{vid}/ocp")), "schema"),
        ("", js(mod(vehicle_id="*")), "schema"),
        ("", js(mod(vehicle_id="@/x")), "schema"),
        ("", b" " * 70000, "too_large"),
        ("wildcard", js(mod()), "bad_key"),
    ]


def test_hostile_samples_rejected_with_reasons_and_good_ocps_unchanged(router, procs, tmp_path):
    vid = "hostile1"
    log = tmp_path / "drive.jsonl"
    lines = write_log(log, vid, duration=8.0)
    start_pipeline(procs, router, vid)
    offline = _offline_estimates(log, tmp_path / "estimates.jsonl")
    good = [json.loads(x) for x in lines]
    plan: list[tuple[str, bytes, str]] = []
    inject_at = {100, 350, 600}
    for i, line in enumerate(lines):
        plan.append(("", line.encode(), "ok"))
        if i in inject_at:
            plan += _hostile_payloads(good, vid, i)
    expected_codes = [c for _k, _p, c in plan if c != "ok"]
    ocps, rejs = Collector(), Collector()
    raw = f"soilocp/{vid}/sensors/raw"
    with client(router) as s:
        s1 = s.declare_subscriber(f"soilocp/{vid}/ocp", ocps)
        s2 = s.declare_subscriber(f"soilocp/{vid}/rejected", rejs)
        # a put on another vehicle's key and on a deeper key must never reach this vehicle
        s.put(f"soilocp/{vid}x/sensors/raw", lines[0].encode())
        assert wait_alive(s, vid), alive_services(s, vid)
        import zenoh

        pub = s.declare_publisher(raw, congestion_control=zenoh.CongestionControl.BLOCK)
        for n, (k, payload, _code) in enumerate(plan):
            if k == "wildcard":
                s.put("soilocp/*/sensors/raw", payload)  # key-injection through a wildcard key
            else:
                pub.put(payload)
            if n % 4 == 0:
                time.sleep(0.004)  # ~1000 samples/s: faster than real time, within the queues
        assert wait_count(lambda: len(ocps), len(offline)), (len(ocps), _healths(s, vid))
        assert wait_for(lambda: len(rejs) >= len(expected_codes), 10), (len(rejs), len(expected_codes))
        time.sleep(0.3)
        s1.undeclare()
        s2.undeclare()
        rejections = rejs.models(Rejection)
        assert [r.code for r in rejections] == expected_codes
        for r in rejections:
            assert r.vehicle_id == vid and r.message and r.payload_size >= 0
            assert len(r.payload) <= 512
        by_code: dict[str, Rejection] = {}
        for r in rejections:  # the first of each code: the group injected after good sample 100
            by_code.setdefault(r.code, r)
        assert by_code["non_finite"].field == "ground_speed" and "nan" in by_code["non_finite"].message
        assert by_code["out_of_range"].field == "wheel_torque.0" and "1000000000" in by_code["out_of_range"].message
        assert by_code["vehicle_mismatch"].seq == good[101]["seq"] and "'rover1'" in by_code["vehicle_mismatch"].message
        assert by_code["duplicate_seq"].seq == good[100]["seq"]
        assert by_code["stamp_backwards"].seq == good[101]["seq"] and by_code["old_seq"].seq == good[90]["seq"]
        assert by_code["bad_key"].key == "soilocp/*/sensors/raw"
        _assert_same_records(ocps.models(OcpEstimate), offline)
        [payload] = get_payloads(s, f"soilocp/{vid}/status/gateway")
        h = ServiceHealth.model_validate_json(payload)
        assert (h.rejected, h.published, h.errors, h.dropped) == (len(expected_codes), len(lines), 0, 0)
        assert h.detail["rejected_schema"] == expected_codes.count("schema")
        assert h.detail["rejected_too_large"] == expected_codes.count("too_large")
    assert all(procs.alive().values()), procs.alive()


def test_kill9_of_a_service_and_restart_resumes_ocps_and_flags_stale(router, procs, tmp_path):
    vid = "restart1"
    log = tmp_path / "drive.jsonl"
    write_log(log, vid, duration=40.0, scenario="mixed")  # long enough for a slow restart under load
    start_pipeline(procs, router, vid, extra=["--stale-timeout", "0.5"])
    ocps, status = Collector(), Collector()
    with client(router) as s:
        s.declare_subscriber(f"soilocp/{vid}/ocp", ocps)
        s.declare_subscriber(f"soilocp/{vid}/status/ocp", status)
        assert wait_alive(s, vid), alive_services(s, vid)
        procs.spawn("vehicle", ["service", "vehicle", "--vehicle-id", vid, "--connect", router,
                                "--replay", str(log), "--speed", "1"])
        assert wait_for(lambda: len(ocps) >= 150, 30)
        victim = procs.procs["observer"]
        victim.send_signal(signal.SIGKILL)
        victim.wait(10)
        n_status = len(status)

        def stale_reported():
            return any(h.stale and h.state == "stale" for h in status.models(ServiceHealth)[n_status:])

        assert wait_for(stale_reported, 10), "the OCP publisher did not publish a stale status"
        seq_at_kill = ocps.models(OcpEstimate)[-1].seq  # after the stages downstream drained what was in flight
        [rep] = get_payloads(s, f"soilocp/{vid}/ocp")
        rep = OcpReply.model_validate_json(rep)
        assert rep.stale and rep.latest.status == "stale" and rep.age_s > 0.5

        procs.spawn("observer", ["service", "observer", "--vehicle-id", vid, "--connect", router])
        n_before = len(ocps)
        assert wait_for(lambda: len(ocps) >= n_before + 100, 90), "OCPs did not resume after the restart"

        def fresh():
            [p] = get_payloads(s, f"soilocp/{vid}/ocp")
            return not OcpReply.model_validate_json(p).stale

        assert wait_for(fresh, 5)
        seqs = [e.seq for e in ocps.models(OcpEstimate)]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)  # in order, no duplicates
        resumed = [q for q in seqs if q > seq_at_kill]
        assert resumed and resumed[0] > seq_at_kill + 20  # the gap is visible, not papered over
        assert any(not h.stale for h in status.models(ServiceHealth)[n_status:]) or fresh()
    alive = procs.alive()
    assert all(alive[n] for n in PIPELINE), alive
    assert alive.get("vehicle") is not False or procs.procs["vehicle"].returncode == 0
    for name in ("gateway", "normal-force", "soil-strength", "ocp"):
        assert "processing_error" not in procs.log_text(name), name


def test_service_waits_for_late_router_and_stops_cleanly_on_sigterm(procs):
    ep = endpoint(free_port())
    # one process may serve several vehicles: each id gets its own keys, token and state
    gw = procs.spawn("gateway", ["service", "gateway", "--vehicle-id", "late1", "--vehicle-id", "late2",
                                 "--connect", ep])
    time.sleep(2.0)
    assert gw.poll() is None, procs.log_text("gateway")  # still waiting, not crashed
    procs.spawn("router", ["router", "--listen", ep])
    with client(ep) as s:
        assert wait_alive(s, "late1", ["gateway"], timeout=30), procs.log_text("gateway")
        assert wait_alive(s, "late2", ["gateway"], timeout=5)
        rej = Collector()
        s.declare_subscriber("soilocp/*/rejected", rej)
        time.sleep(0.3)
        sample = dict(vehicle_id="late1", seq=0, stamp=0.0, specific_force=[0.0, 0.0, 9.81], roll=0.0, pitch=0.0,
                      yaw_rate=0.0, wheel_speed=[0.0] * 4, wheel_torque=[0.0] * 4, ground_speed=0.0)
        s.put("soilocp/late2/sensors/raw", json.dumps(sample).encode())
        assert wait_for(lambda: len(rej) == 1, 10)
        r = rej.models(Rejection)[0]
        assert (r.vehicle_id, r.code) == ("late2", "vehicle_mismatch")
    gw.send_signal(signal.SIGTERM)
    assert gw.wait(5) == 0
    log = procs.log_text("gateway")
    assert '"event": "waiting_for_router"' in log and '"event": "stopped"' in log
    for line in log.splitlines():  # structured logs: every line is a JSON object
        json.loads(line)
    r = procs.procs["router"]
    r.send_signal(signal.SIGINT)
    assert r.wait(5) == 0


@pytest.mark.parametrize("args, env, needle", [
    (["--vehicle-id", "bad/id"], {}, "vehicle_id"),
    ([], {"SOILOCP_STALE_TIMEOUT": "soon"}, "SOILOCP_STALE_TIMEOUT"),
    (["--config", "/nonexistent/soilocp.json"], {}, "/nonexistent/soilocp.json"),
    (["--connect", "localhost"], {}, "endpoint"),
])
def test_fatal_config_error_exits_nonzero_with_one_line(args, env, needle):
    e = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    e.update(env)
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "service", "ocp", *args], capture_output=True,
                       text=True, timeout=60, env=e)
    assert r.returncode == 2
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and needle in lines[0] and "error" in lines[0], r.stderr


def test_soilocp_run_replay_without_tty_prints_lines_and_summary(tmp_path):
    log = tmp_path / "drive.jsonl"
    write_log(log, "rover1", duration=4.0)
    ep = endpoint(free_port())
    p = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--replay", str(log), "--speed", "2",
                          "--listen", ep, "--log-dir", str(tmp_path / "logs")],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = p.communicate(timeout=90)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 0, out
    assert "t=" in out and "services_alive=5/5" in out  # periodic plain lines
    assert "summary" in out and "OCP records received: 400" in out
    for name in ("router", *PIPELINE, "vehicle"):
        assert name in out
    assert "died" not in out and "killed" not in out
    logs = sorted(x.name for x in (tmp_path / "logs").iterdir())
    assert logs == sorted(f"{n}.log" for n in ("router", *PIPELINE, "vehicle"))


def test_router_restart_services_rejoin_and_ocps_resume(procs, tmp_path):
    vid = "rejoin1"
    ep = endpoint(free_port())
    log = tmp_path / "drive.jsonl"
    write_log(log, vid, duration=40.0, scenario="sand")
    procs.spawn("router", ["router", "--listen", ep])
    start_pipeline(procs, ep, vid)
    ocps = Collector()
    with client(ep) as s:
        assert wait_alive(s, vid), alive_services(s, vid)
    procs.spawn("vehicle", ["service", "vehicle", "--vehicle-id", vid, "--connect", ep, "--replay", str(log)])
    # the test's own client is on a peer-less router that is about to die: use fresh ones
    with client(ep) as s:
        s.declare_subscriber(f"soilocp/{vid}/ocp", ocps)
        assert wait_for(lambda: len(ocps) >= 100, 30)
    seq_at_kill = ocps.models(OcpEstimate)[-1].seq
    router = procs.procs["router"]
    router.send_signal(signal.SIGKILL)
    router.wait(10)
    time.sleep(0.5)
    procs.spawn("router", ["router", "--listen", ep])
    after = Collector()
    with client(ep) as s:
        s.declare_subscriber(f"soilocp/{vid}/ocp", after)
        assert wait_for(lambda: len(after) >= 100, 90), "OCPs did not resume after the router restart"
        assert wait_alive(s, vid, timeout=10)
    seqs = [e.seq for e in after.models(OcpEstimate)]
    assert seqs[0] > seq_at_kill and seqs == sorted(seqs)
    assert all(procs.procs[n].poll() is None for n in PIPELINE)


def _pids_from_logs(log_dir: Path) -> dict[str, int]:
    """pid of each process of a ``soilocp run``, from the first JSON log line that names it."""
    out = {}
    for f in log_dir.glob("*.log"):
        for line in f.read_text(errors="replace").splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and "pid" in rec:
                out[f.stem] = rec["pid"]
                break
    return out


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


class _RunProc:
    """``soilocp run`` in its own process group with its stdout read by a thread."""

    def __init__(self, args, tmp_path):
        self.log_dir = tmp_path / "runlogs"
        self.p = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", *args, "--log-dir", str(self.log_dir)],
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        self.t = threading.Thread(target=lambda: self.lines.extend(iter(self.p.stdout.readline, "")), daemon=True)
        self.t.start()

    def text(self) -> str:
        return "".join(self.lines)

    def close(self):
        if self.p.poll() is None:
            os.killpg(self.p.pid, signal.SIGKILL)
            self.p.wait()
        for pid in _pids_from_logs(self.log_dir).values():  # never leave a child behind
            if _pid_alive(pid):
                os.kill(pid, signal.SIGKILL)


def test_soilocp_run_ctrl_c_stops_every_process(tmp_path):
    ep = endpoint(free_port())
    run = _RunProc(["--synthetic", "sand", "--duration", "60", "--listen", ep], tmp_path / "a")
    try:
        def flowing():
            last = [x for x in run.text().splitlines() if x.startswith("t=")][-1:]
            return last and "samples/s=0.0" not in last[0] and "services_alive=5/5" in last[0]

        assert wait_for(flowing, 90), run.text()
        assert wait_for(lambda: len(_pids_from_logs(run.log_dir)) == 7, 10), _pids_from_logs(run.log_dir)
        pids = _pids_from_logs(run.log_dir)
        os.killpg(run.p.pid, signal.SIGINT)  # what Ctrl-C on the terminal does
        assert run.p.wait(15) == 130, run.text()
        run.t.join(5)
        assert "interrupted" in run.text() and "summary" in run.text()
        assert not [n for n, pid in pids.items() if _pid_alive(pid)]
    finally:
        run.close()


def test_soilocp_run_fails_when_a_service_dies(tmp_path):
    ep = endpoint(free_port())
    run = _RunProc(["--synthetic", "sand", "--duration", "60", "--listen", ep], tmp_path / "b")
    try:
        assert wait_for(lambda: "services_alive=5/5" in run.text(), 90), run.text()
        assert wait_for(lambda: len(_pids_from_logs(run.log_dir)) == 7, 10)
        pids = _pids_from_logs(run.log_dir)
        os.kill(pids["soil-strength"], signal.SIGKILL)
        assert run.p.wait(15) == 1, run.text()
        run.t.join(5)
        assert "FAILED" in run.text() and "soil-strength died" in run.text()
        assert not [n for n, pid in pids.items() if _pid_alive(pid)]
    finally:
        run.close()


def test_children_of_a_killed_soilocp_run_stop_themselves(tmp_path):
    ep = endpoint(free_port())
    run = _RunProc(["--synthetic", "sand", "--duration", "60", "--listen", ep], tmp_path)
    try:
        assert wait_for(lambda: "services_alive=5/5" in run.text(), 90), run.text()
        assert wait_for(lambda: len(_pids_from_logs(run.log_dir)) == 7, 10)
        pids = _pids_from_logs(run.log_dir)
        os.kill(run.p.pid, signal.SIGKILL)  # no chance to clean up: the children must notice
        run.p.wait(5)
        assert wait_for(lambda: not [n for n, pid in pids.items() if _pid_alive(pid)], 10), \
            [n for n, pid in pids.items() if _pid_alive(pid)]
        assert '"event": "parent_gone"' in (run.log_dir / "ocp.log").read_text()
    finally:
        run.close()
