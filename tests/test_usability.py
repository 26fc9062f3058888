"""What a user sees: no silent failure, reason codes with next steps, records that say whether they are
confirmed, the torque constant on any log, settings typos with the closest key.  Real processes
(``.venv/bin/soilocp``) for the commands."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pydantic import ValidationError

from soilocp.schemas.pipeline import REASON_CODES, OcpEstimate
from soilocp.services.supervisor.log_watch import LogWatch
from soilocp.services.supervisor.table import drop_lines
from soilocp.estimation.next_steps import NEXT_STEPS, status_rows
from soilocp.model.settings_errors import describe_validation_error
from soilocp.model.vehicle import VehicleParams

SOILOCP = shutil.which("soilocp", path=str(Path(sys.executable).parent)) or "soilocp"


def soilocp(*args, timeout=120, cwd=None):
    return subprocess.run([SOILOCP, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd)


@pytest.fixture(scope="module")
def sand(tmp_path_factory):
    d = tmp_path_factory.mktemp("sand")
    r = soilocp("simulate", "--scenario", "sand", "--duration", "12", "--out", d / "s.jsonl", "--truth", d / "t.jsonl")
    assert r.returncode == 0, r.stderr
    return d


def _records(path):
    return [json.loads(x) for x in Path(path).read_text().splitlines()]


def test_estimate_on_an_empty_log_fails_with_the_cause(tmp_path):
    (tmp_path / "empty.jsonl").write_text("\n\n")
    r = soilocp("estimate", tmp_path / "empty.jsonl", "--out", tmp_path / "e.jsonl")
    assert r.returncode == 1 and "holds no sensor sample" in r.stderr and "Traceback" not in r.stderr


def test_estimate_where_every_sample_is_rejected_fails_with_the_codes(tmp_path):
    (tmp_path / "bad.jsonl").write_text('{"a": 1}\nnot json\n')
    r = soilocp("estimate", tmp_path / "bad.jsonl", "--out", tmp_path / "e.jsonl")
    assert r.returncode == 1, r.stderr
    assert "every sample" in r.stderr and "schema 1" in r.stderr and "malformed_json 1" in r.stderr


def test_plot_on_an_empty_file_is_a_clear_error(tmp_path):
    (tmp_path / "e.jsonl").write_text("")
    r = soilocp("plot", "--estimates", tmp_path / "e.jsonl", "--out", tmp_path / "p")
    assert r.returncode == 2 and "holds no record" in r.stderr and "Traceback" not in r.stderr


def test_vehicle_file_typo_names_the_closest_key_without_usage_banner(tmp_path, sand):
    (tmp_path / "v.json").write_text(json.dumps({"mass": 70, "wheel_radiuss": 0.2}))
    r = soilocp("estimate", sand / "s.jsonl", "--vehicle", tmp_path / "v.json", "--out", tmp_path / "e.jsonl")
    assert r.returncode == 2
    assert "did you mean 'wheel_radius'?" in r.stderr and "valid keys: a, b, c, d" in r.stderr
    assert "Usage:" not in r.stderr and "errors.pydantic.dev" not in r.stderr


def test_settings_error_lists_the_keys_of_the_nested_level():
    with pytest.raises(ValidationError) as exc:
        VehicleParams.model_validate({"mass": -1, "whel_inertia": 0.1})
    text = describe_validation_error(exc.value, "vehicle file 'v.json'", VehicleParams)
    assert text.startswith("vehicle file 'v.json': 2 problems")
    assert "mass: Input should be greater than 0 (got -1)" in text
    assert "whel_inertia: unknown key (value 0.1); did you mean 'wheel_inertia'?" in text
    from soilocp.estimation.config import PipelineConfig

    with pytest.raises(ValidationError) as exc:
        PipelineConfig.model_validate({"soil": {"zzz": 1}})
    text = describe_validation_error(exc.value, "config", PipelineConfig)
    assert "soil.zzz: unknown key" in text and "did you mean" not in text and "valid keys of soil:" in text


def test_records_carry_reason_codes_and_confirmed_and_the_table_next_steps(tmp_path, sand):
    r = soilocp("estimate", sand / "s.jsonl", "--out", tmp_path / "e.jsonl")
    assert r.returncode == 0, r.stderr
    recs = _records(tmp_path / "e.jsonl")
    assert {x["status"] for x in recs} >= {"ok", "no_estimate"}
    for x in recs:
        assert x["reason_code"] in REASON_CODES
        assert x["confirmed"] is (x["status"] == "ok")
        assert (x["reason_code"] == "none") is (x["status"] == "ok"), x
    assert "records per status and reason" in r.stderr and "not_yet" in r.stderr and "traction test" in r.stderr
    assert "{'" not in r.stderr  # no Python dict in what a user reads
    assert "WARNING" not in r.stderr  # the simulated rover is the built-in one


def test_confirmed_cannot_contradict_the_status():
    q = (0.0,) * 4
    kw = dict(vehicle_id="v", seq=0, stamp=0.0, soil_strength=40.0, soil_strength_std=30.0, soil_class="sand",
              mu_T=0.3, S_T=0.2, S_E=0.1, mu=q, slip=q)
    assert OcpEstimate(status="uncertain", reason_code="wide", **kw).confirmed is False
    assert OcpEstimate(status="ok", **kw).confirmed is True
    with pytest.raises(ValidationError, match="contradicts status 'uncertain'"):
        OcpEstimate(status="uncertain", confirmed=True, **kw)
    with pytest.raises(ValidationError):
        OcpEstimate(status="ok", reason_code="made_up", **kw)


def test_confirmed_null_is_filled_in_and_anything_but_the_status_bool_refused():
    # confirmed is checked by a field validator and a model validator after the fields (no model validator
    # before them, which would turn every record's JSON into Python objects first): the same rule
    q = (0.0,) * 4
    kw = dict(vehicle_id="v", seq=0, stamp=0.0, soil_strength=40.0, soil_strength_std=30.0, soil_class="sand",
              mu_T=0.3, S_T=0.2, S_E=0.1, mu=q, slip=q)
    for status, ok in (("ok", True), ("uncertain", False)):
        extra = {} if ok else {"reason_code": "wide"}
        absent, null = OcpEstimate(status=status, **extra, **kw), OcpEstimate(status=status, confirmed=None, **extra, **kw)
        given = OcpEstimate.model_validate_json(absent.model_dump_json())
        assert absent.confirmed is null.confirmed is given.confirmed is ok
        assert "confirmed" in absent.model_fields_set and absent.model_dump_json() == given.model_dump_json()
        for bad in (not ok, 1, 0, "true", "false", 1.0):
            with pytest.raises(ValidationError, match="contradicts status"):
                OcpEstimate.model_validate_json(absent.model_dump_json().replace(
                    f'"confirmed":{str(ok).lower()}', f'"confirmed":{json.dumps(bad)}'))


def test_every_reason_code_has_a_next_step_and_the_table_sorts_by_count():
    assert set(NEXT_STEPS) == set(REASON_CODES)
    rows = status_rows({("ok", "none"): 3, ("no_estimate", "not_yet"): 5})
    assert [r[:3] for r in rows] == [("no_estimate", "not_yet", 5), ("ok", "none", 3)]


def test_torque_constant_applies_to_any_log(tmp_path, sand):
    halved = tmp_path / "halved.jsonl"
    with open(halved, "w") as fh:
        for rec in _records(sand / "s.jsonl"):
            rec["wheel_torque"] = [t / 2 for t in rec["wheel_torque"]]  # a power of 2: exact both ways
            fh.write(json.dumps(rec) + "\n")
    assert soilocp("estimate", sand / "s.jsonl", "--out", tmp_path / "ref.jsonl").returncode == 0
    plain = soilocp("estimate", halved, "--out", tmp_path / "plain.jsonl")
    (tmp_path / "k.json").write_text(json.dumps({"status": "ok", "reason": "", "k": 2.0, "k_std": 0.01}))
    fixed = soilocp("estimate", halved, "--torque-constant", tmp_path / "k.json", "--out", tmp_path / "fixed.jsonl")
    assert fixed.returncode == 0, fixed.stderr
    ref, got = _records(tmp_path / "ref.jsonl"), _records(tmp_path / "fixed.jsonl")
    assert got == ref
    assert _records(tmp_path / "plain.jsonl") != ref
    (tmp_path / "nd.json").write_text(json.dumps({"status": "not_determined", "reason": "barely accelerated", "k": None}))
    bad = soilocp("estimate", halved, "--torque-constant", tmp_path / "nd.json", "--out", tmp_path / "x.jsonl")
    assert bad.returncode == 2 and "did not determine k" in bad.stderr and "barely accelerated" in bad.stderr


def test_estimate_warns_when_the_data_do_not_look_like_the_built_in_rover(tmp_path, sand):
    bigger = tmp_path / "bigger.jsonl"  # the same drive on wheels twice the radius: half the wheel speeds
    with open(bigger, "w") as fh:
        for rec in _records(sand / "s.jsonl"):
            rec["wheel_speed"] = [w / 2 for w in rec["wheel_speed"]]
            fh.write(json.dumps(rec) + "\n")
    r = soilocp("estimate", bigger, "--out", tmp_path / "e.jsonl")
    assert r.returncode == 0 and "no vehicle file given" in r.stderr and re.search(r"wheel radius is about 0\.(29|3)", r.stderr)
    (tmp_path / "v.json").write_text(json.dumps({"wheel_radius": 0.3}))
    r = soilocp("estimate", bigger, "--vehicle", tmp_path / "v.json", "--out", tmp_path / "e.jsonl")
    assert r.returncode == 0 and "WARNING" not in r.stderr


def test_run_replay_refuses_a_vehicle_id_the_log_does_not_have(tmp_path, sand):
    t0 = time.monotonic()
    r = soilocp("run", "--replay", sand / "s.jsonl", "--vehicle-id", "other", "--plain", timeout=60)
    assert r.returncode == 2 and time.monotonic() - t0 < 30
    assert "'rover1'" in r.stderr and "--vehicle-id rover1" in r.stderr and "vehicle_mismatch" in r.stderr


def test_run_with_a_missing_ros2_router_fails_at_once_with_the_services_words(tmp_path):
    from zenoh_helpers import endpoint, free_port

    t0 = time.monotonic()
    r = soilocp("run", "--synthetic", "sand", "--ros2", "--listen", endpoint(free_port()), "--ros2-connect",
                endpoint(free_port()), "--plain", "--log-dir", tmp_path / "logs", timeout=120)
    took = time.monotonic() - t0
    assert r.returncode == 1, r.stdout
    assert "ros2-out cannot start: waiting_for_ros2_router" in r.stdout and "rmw_zenohd" in r.stdout
    assert took < 45, f"took {took:.0f} s"  # the liveliness wait would have taken 90 s


def test_log_watch_reports_errors_and_external_waits_but_not_its_own_router(tmp_path):
    log = tmp_path / "svc.log"
    log.write_text(json.dumps({"level": "warning", "event": "waiting_for_router", "error": "x"}) + "\n")
    watch = LogWatch(tmp_path, ["svc"])
    assert watch.poll() is None
    with open(log, "a") as fh:
        fh.write("plain text\n" + json.dumps({"level": "error", "event": "boom", "error": "disk full"}) + "\n")
    problem = watch.poll()
    assert problem is not None and str(problem) == "svc cannot start: boom: disk full"
    assert watch.poll() is None  # read once


def test_drop_lines_say_why_and_what_to_do_at_speed_zero():
    class H:
        dropped, received, detail = 958, 4000, {"unjoined": 958}

    lines = drop_lines({"observer": H()}, 0.0)
    assert "observer dropped 958 of 4000 inputs: 958 their normal forces arrived too late" in lines[0]
    assert "--speed 1" in lines[1]
    assert drop_lines({"observer": H()}, 1.0)[1:] == []


def test_run_replay_uses_the_logs_vehicle_id_and_ends_with_the_reason_table(tmp_path, sand):
    from zenoh_helpers import endpoint, free_port

    short = tmp_path / "short.jsonl"  # 3 s of the drive, under an id that is not run's default
    with open(short, "w") as fh:
        for rec in _records(sand / "s.jsonl")[:300]:
            fh.write(json.dumps({**rec, "vehicle_id": "logbot"}) + "\n")
    r = soilocp("run", "--replay", short, "--speed", "1", "--plain", "--listen", endpoint(free_port()), timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "vehicle logbot" in r.stdout and "vehicle_mismatch" not in r.stdout
    assert "OCP records per status and reason" in r.stdout and "next step" in r.stdout
    n = int(r.stdout.split("OCP records received: ")[1].split(";")[0])
    assert n > 0


def test_the_codes_page_lists_every_reason_code_and_the_no_estimate_page_links_it():
    docs = Path(__file__).resolve().parents[1] / "docs"
    page = (docs / "reference" / "codes.md").read_text()
    listed = {line.split("`")[1] for line in page.split("## Reason codes")[1].splitlines() if line.startswith("| `")}
    assert listed == set(REASON_CODES)
    assert "(reference/codes.md)" in (docs / "from-no-estimate-to-ok.md").read_text()


def test_a_torque_constant_lifts_only_the_unknown_current_scale_from_the_provenance():
    from soilocp.commands.io import _with_torque_constant
    from soilocp.estimation.config import PipelineConfig
    from soilocp.ingest.align import Provenance

    scale = "wheel torque is a motor current with an unknown scale (no current_to_torque in the map)"
    prov = Provenance("x", wheel_torque="current_unknown_scale", identifiable=False, reasons=[scale])
    assert _with_torque_constant(prov, PipelineConfig()) is prov
    lifted = _with_torque_constant(prov, PipelineConfig(torque_constant=2.5))
    assert lifted.identifiable and lifted.reasons == [] and lifted.withhold_reason() is None
    both = Provenance("x", ground_speed="absent", wheel_torque="current_unknown_scale", identifiable=False,
                      reasons=["no independent ground speed in the source (slip, eq. 1, needs it)", scale])
    still = _with_torque_constant(both, PipelineConfig(torque_constant=2.5))
    assert not still.identifiable and still.reasons == both.reasons[:1]
