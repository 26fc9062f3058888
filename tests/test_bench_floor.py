"""``soilocp bench --floor``: the relay pipelines (services/bench/relay.py) carry every sample through the
real process graph and keys, and the report has its rows.  Real processes on an ephemeral loopback
port (the bench's Rig: explicit endpoints, no multicast scouting); no assertion on the timings."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from soilocp.services.bench.relay import LEVELS, RECORDED, RelayStep, record_templates, relay_class
from soilocp.services.bench.stages import simulate_drive
from soilocp.services.stages.graph import BY_NAME, PIPELINE_SERVICES
from soilocp.services.stages.registry import SPECIAL, stage_service
from soilocp.services.stages.stage_service import StageService

GRAPH_PROCS = {"standard": {"router", *PIPELINE_SERVICES}, "batched": {"router", "gateway", "batch"}}


@pytest.fixture(scope="module")
def templates():
    return record_templates(simulate_drive("bench", 2.0))


def test_recorded_outputs_are_real_messages(templates):
    assert set(templates) == set(RECORDED)
    for name, text in templates.items():
        BY_NAME[name].output_model.model_validate_json(text)  # a valid message of the row's output model


def test_relay_step_takes_vehicle_seq_and_stamp_from_its_input(templates):
    sample = simulate_drive("v7", 0.5)[-1]
    out = RelayStep(BY_NAME["ocp"].output_model.model_validate_json(templates["ocp"])).step(sample)
    assert (out.vehicle_id, out.seq, out.stamp) == ("v7", sample.seq, sample.stamp)
    assert len(out.model_dump_json()) == pytest.approx(len(templates["ocp"]), abs=20)


def test_relays_are_the_real_services_without_physics(templates):
    for level in LEVELS:
        for name in PIPELINE_SERVICES:
            cls = relay_class(name, level, templates)
            real = SPECIAL.get(name)  # the row's own class, or the generic one made for its spec
            assert issubclass(cls, real) if real else cls.__mro__[1].spec is BY_NAME[name]
            assert issubclass(cls, StageService) and cls.name == name  # same tokens, keys, health
            assert cls.spec.stage is None and cls.spec.output is BY_NAME[name].output
    assert relay_class("gateway", "messages", templates) is stage_service("gateway")
    with pytest.raises(ValueError, match="--templates"):
        relay_class("observer", "messages", None)
    with pytest.raises(ValueError, match="level"):
        relay_class("observer", "bytes", templates)


@pytest.mark.timeout(600)
def test_quick_floor_carries_every_sample(tmp_path):
    out = tmp_path / "floor.json"
    scratch = tmp_path / "tmp"  # the run's temporary files (the relays' recorded outputs): removed at its end
    scratch.mkdir()
    r = subprocess.run([sys.executable, "-m", "soilocp.services.bench.floor", "--quick", "--max-vehicles", "1",
                        "--variant", "messages", "--variant", "zenoh", "--json", str(out)],
                       capture_output=True, text=True, timeout=580, cwd=tmp_path,
                       env={**os.environ, "TMPDIR": str(scratch)})
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert not [p for p in scratch.iterdir() if p.name.startswith("soilocp-floor-")]
    assert "floor of the live rows, standard pipeline" in r.stdout and "batched pipeline" in r.stdout
    rep = json.loads(out.read_text())
    assert rep["kind"] == "floor" and rep["variants"] == ["bare", "messages", "zenoh"]  # bare: always, first
    assert {"raw sample", *RECORDED} <= set(rep["message_bytes"])
    rows = {(row["pipeline"], row["variant"], row["rate_hz"]): row for row in rep["latency"]}
    assert set(rows) == {(p, v, rate) for p in ("standard", "batched") for v in ("bare", "messages", "zenoh")
                         for rate in (100.0, 1000.0)}
    for (pipe, _v, _rate), row in rows.items():
        res = row["result"]
        # a sample later than the drain counts as a drop: timing, which the shared CI machine moves (no timing
        # assertions); every sample is accounted for, and the relays carried samples end to end
        assert res["sent"] > 0 and res["received"] > 0 and res["received"] + res["drops"] == res["sent"], row
        assert res["rejections"] == 0
        assert GRAPH_PROCS[pipe] <= set(row["processes"])
    for v, cl in rep["control_loop"].items():
        assert "error" not in cl, (v, cl)
        assert cl["sent"] > 0 and 0 <= cl["drops"] < cl["sent"], (v, cl)
    for pipe, by_variant in rep["scale"].items():
        for v, sc in by_variant.items():
            (step,) = sc["steps"]
            assert step["vehicles"] == 1 and 0 <= step["result"]["drops"] < step["result"]["sent"], (pipe, v, step)
            assert GRAPH_PROCS[pipe] <= set(step["processes"])
    assert set(rep["targets_met"]) == {f"{p}/{v}" for p in ("standard", "batched") for v in ("bare", "messages", "zenoh")}
    # every row as a ratio to the bare relay of the same run: 1 for bare itself, a figure for the others
    for pipe in ("standard", "batched"):
        assert rep["ratios"][pipe]["bare"]["100hz_p50"] == pytest.approx(1.0)
        assert rep["ratios"][pipe]["zenoh"]["1khz_cpu"] > 0 and rep["ratios"][pipe]["messages"]["100hz_p99"] > 0
    assert "over the bare zenoh-python relay of the same run" in r.stdout


def test_floor_refuses_compare_and_map():
    from click.testing import CliRunner

    from soilocp.services.bench.run import bench

    for extra in (["--compare", "base.json"], ["--map"]):
        r = CliRunner().invoke(bench, ["--floor", *extra])
        assert r.exit_code == 2 and "takes neither --compare nor --map" in r.output, r.output


def test_bare_relay_args_follow_the_graph(tmp_path):
    """Each bare relay subscribes its row's inputs, puts on its output key, holds its row's token."""
    from soilocp.services.bench.bare import splice_template
    from soilocp.services.bench.floor import bare_args

    t = tmp_path / "templates.json"
    obs = bare_args("observer", t)
    assert obs[:4] == ["--sub", "soilocp/{vid}/sensors/clean", "--sub", "soilocp/{vid}/normal_forces"]
    assert obs[obs.index("--forward") + 1] == "soilocp/{vid}/normal_forces"
    assert obs[obs.index("--pub") + 1] == "soilocp/{vid}/observer"
    assert obs[obs.index("--token") + 1] == "soilocp/{vid}/alive/observer"
    assert "--template" not in bare_args("gateway", t)  # forwards the sample's own bytes
    batch = bare_args("batch", t)
    assert [batch[i + 1] for i, a in enumerate(batch) if a == "--token"] == [
        f"soilocp/{{vid}}/alive/{n}" for n in ("normal-force", "observer", "soil-strength", "ocp")]
    out = splice_template(b'{"vehicle_id":"bench","seq":17,"x":1}')
    assert out(b"123456") == b'{"vehicle_id":"bench","seq":123456,"x":1}'
    with pytest.raises(ValueError):
        splice_template(b'{"x":1}')
