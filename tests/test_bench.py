"""``soilocp bench --quick`` produces a well-formed report (keys present, numbers finite): real
processes, a real router on an ephemeral loopback port.  No assertion on the timings themselves
(the machine is shared); the helpers are checked on known inputs."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import pytest

from soilocp.services.bench.run import json_safe, verdict
from soilocp.services.bench.live import proc_cpu_seconds, proc_pss_mib, proc_rss_mib
from soilocp.services.bench.stages import STAGES, summarize

PIPELINE_PROCS = {"standard": {"router", "gateway", "normal-force", "observer", "soil-strength", "ocp"},
                  "batched": {"router", "gateway", "batch"}}


def _finite(x, what):
    assert isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x), (what, x)


def test_summarize_known_values():
    st = summarize(list(range(1, 101)))
    assert st["n"] == 100 and st["p50"] == pytest.approx(50.5) and st["max"] == 100
    assert st["p99"] == pytest.approx(99.01)
    assert math.isnan(summarize([])["p50"])
    assert json_safe({"a": [float("nan"), 1.0], "b": float("inf")}) == {"a": [None, 1.0], "b": None}


def test_proc_readers_see_this_process():
    t0 = proc_cpu_seconds(os.getpid())
    x = 0
    end = time.process_time() + 0.2
    while time.process_time() < end:  # burn 0.2 s of CPU
        x += 1
    assert proc_cpu_seconds(os.getpid()) - t0 >= 0.1
    assert proc_rss_mib(os.getpid()) > 10.0
    pss = proc_pss_mib(os.getpid())
    assert pss is None or 0.0 < pss <= proc_rss_mib(os.getpid()) + 1.0  # shared pages count a share
    assert proc_cpu_seconds(2**22 + 12345) is None  # no such pid


@pytest.mark.timeout(900)
def test_quick_bench_report_is_well_formed(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, "-m", "soilocp.services.bench.run", "--quick", "--json", str(out)],
                       capture_output=True, text=True, timeout=880, cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "sample -> OCP latency" in r.stdout and "targets:" in r.stdout
    rep = json.loads(out.read_text())
    assert rep["quick"] is True
    m = rep["machine"]
    assert m["nproc"] >= 1 and m["cpu_model"] and len(m["load_start"]) == 3 and len(m["load_end"]) == 3
    for name in (*STAGES, "total"):
        st = rep["stages"][name]
        assert st["n"] > 100
        for k in ("p50", "p99", "max"):
            _finite(st[k], (name, k))
    _finite(rep["replay"]["samples_per_s"], "replay")
    _finite(rep["replay"]["x_real_time"], "replay x")
    pipes = {row["pipeline"] for row in rep["latency"]}
    assert "standard" in pipes
    for row in rep["latency"]:
        assert row["rate_hz"] in (100.0, 1000.0)
        res, base = row["result"], row["baseline"]
        assert res["sent"] > 0 and 0 <= res["drops"] <= res["sent"] and res["rejections"] >= 0
        if res["received"]:
            for k in ("p50", "p90", "p99", "max"):
                _finite(res[k], (row["pipeline"], row["rate_hz"], k))
        _finite(base["p50"], "ping p50")
        assert base["lost"] == 0 or base["lost"] < base["sent"]
        assert PIPELINE_PROCS[row["pipeline"]] <= set(row["processes"])
    assert set(rep["scale"]) == pipes
    for pipe, sc in rep["scale"].items():
        assert sc["steps"] and sc["steps"][0]["vehicles"] == 1
        assert 0 <= sc["max_vehicles"] <= max(s["vehicles"] for s in sc["steps"])
        assert 0 <= sc["max_vehicles"] <= sc["max_vehicles_no_drop"]
        for step in sc["steps"]:
            if "result" not in step:
                continue
            for name in PIPELINE_PROCS[pipe]:
                p = step["processes"][name]
                _finite(p["cpu_percent"], (pipe, name, "cpu"))
                _finite(p["rss_mib"], (pipe, name, "rss"))
    cl = rep["control_loop"]  # sample -> slip set-point through pipeline + controller service
    assert "error" not in cl, cl
    assert cl["sent"] > 0 and 0 <= cl["drops"] < cl["sent"] and cl["n"] > 0
    for k in ("p50", "p99", "max"):
        _finite(cl[k], ("control_loop", k))
    assert "5. control loop" in r.stdout
    assert set(verdict(rep)) == set(rep["verdict"])
    assert all(isinstance(v, bool) for v in rep["verdict"].values())


def _report(total_cpu, replay_x, p99, rss_gateway, vehicles):
    return {"machine": {"nproc": 2}, "stages": {"total": {"p50": 2 * total_cpu, "cpu_p50": total_cpu}},
            "replay": {"x_real_time": replay_x, "x_real_time_cpu": replay_x},
            "latency": [{"pipeline": "standard", "rate_hz": 100.0, "result": {"p50": 1.0, "p99": p99, "drops": 0},
                         "baseline": {"p50": 0.5},
                         "processes": {"router": {"rss_mib": 50.0}, "gateway": {"rss_mib": rss_gateway},
                                       "bench": {"rss_mib": 999.0}, "echo": {"rss_mib": 999.0}}}],
            "scale": {"batched": {"max_vehicles": vehicles, "max_vehicles_no_drop": vehicles}}}


def test_compare_ratios_and_gains_on_known_reports():
    from soilocp.services.bench.compare import compare, pipeline_rss_mib

    base, now = _report(400.0, 20.0, 8.0, 150.0, 10), _report(100.0, 50.0, 2.0, 50.0, None)
    assert pipeline_rss_mib(base["latency"][0]["processes"]) == 200.0  # bench and echo are not the pipeline
    rows = {r["figure"]: r for r in compare(base, now)}
    cpu = rows["stage total CPU median, us"]
    assert (cpu["base"], cpu["now"], cpu["ratio"], cpu["gain"]) == (400.0, 100.0, 0.25, 4.0)
    rp = rows["offline replay, x real time (wall)"]
    assert rp["ratio"] == 2.5 and rp["gain"] == 2.5  # higher is better: gain = ratio
    assert rows["latency standard 100 Hz p99, ms"]["gain"] == 4.0
    assert rows["RSS standard router + services, MiB"]["now"] == 100.0
    gone = rows["scale batched: vehicles x 100 Hz passing"]
    assert gone["base"] == 10 and gone["now"] is None and gone["ratio"] is None and gone["gain"] is None


def test_compare_cli_renders_saved_reports_and_rejects_a_bad_baseline(tmp_path):
    base, now, bad = tmp_path / "base.json", tmp_path / "now.json", tmp_path / "bad.json"
    b, n = _report(400.0, 20.0, 8.0, 150.0, 10), _report(100.0, 50.0, 2.0, 50.0, 20)
    for r in (b, n):
        r.update(quick=True, command="soilocp bench", latency=r["latency"], elapsed_s=1.0, verdict={"x": True})
        r["machine"].update(cpu_model="cpu", load_start=[0, 0, 0], python="3", zenoh="1")
        r["stages"]["total"].update(p99=1.0, cpu_p99=1.0, n=3)
        r["latency"][0]["result"].update(p90=1.0, max=1.0, sent=1, rejections=0)
        r["latency"][0]["baseline"]["p99"] = 1.0
        r["scale"] = {}
    base.write_text(json.dumps(b))
    now.write_text(json.dumps(n))
    bad.write_text(json.dumps({"not": "a report"}))
    cmd = [sys.executable, "-m", "soilocp.services.bench.run", "--report", str(now), "--compare"]
    r = subprocess.run(cmd + [str(base)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "before / after" in r.stdout and "stage total CPU median, us" in r.stdout and "4.00" in r.stdout
    r = subprocess.run(cmd + [str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "is not a bench report" in r.stderr


@pytest.mark.parametrize("argv", [["service", "observer"], ["router"]])
def test_process_commands_load_no_heavy_module(argv):
    """The deployed processes (resident memory): ``soilocp service NAME`` / ``soilocp router``
    register only the services area's commands, and the stage services, with every stage built,
    load no scipy / rich / matplotlib / filterpy (the cli with any other command still registers every area)."""
    code = ("import sys; import soilocp.cli.entry as entry; group = entry.command_group(sys.argv[1:]); "
            "import soilocp.services.stages.registry; from soilocp.services.stages.graph import PIPELINE; "
            "from soilocp.estimation.pipeline import PipelineConfig; "
            "[row.stage(PipelineConfig()) for row in PIPELINE if row.stage is not None]; "
            "heavy = sorted(m for m in ('scipy', 'rich', 'matplotlib', 'filterpy') if m in sys.modules); "
            "print(heavy, sorted(group.commands))")
    r = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    heavy, commands = r.stdout.strip().split("] [")
    assert heavy == "[", r.stdout
    assert "'router'" in commands and "'estimate'" not in commands
    assert ("'service'" in commands) == (argv[0] == "service")  # the router's group holds the router only
    r = subprocess.run([sys.executable, "-c", code, "estimate"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "'estimate'" in r.stdout and "'bench'" in r.stdout, r.stdout + r.stderr


@pytest.mark.timeout(200)
def test_soak_short_form_carries_every_sample_and_reports_memory(tmp_path):
    """``soilocp bench --soak 20``: the report has every figure of the soak; nothing dropped, no
    observer reset but the start's, no process error.  Timing figures are reported, not asserted."""
    out = tmp_path / "soak.json"
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "bench", "--soak", "20", "--json", str(out)],
                       capture_output=True, text=True, timeout=170)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    rep = json.loads(out.read_text())
    assert rep["kind"] == "soak" and rep["sent"] == 2000
    assert rep["drops"] == 0, rep["drops"]
    assert set(rep["rss"]) == {"router", "gateway", "normal-force", "observer", "soil-strength", "ocp"}
    assert all(v["growth_mib"] is not None for v in rep["rss"].values())
    assert rep["observer_resets"] == {"start": 1}, rep["observer_resets"]
    assert all(h["errors"] == 0 and h["dropped"] == 0 for h in rep["health"].values()), rep["health"]
    assert rep["latency"]["first_tenth_n"] > 0 and rep["latency"]["last_tenth_n"] > 0
    assert "soak targets:" in r.stdout and "resident memory per process" in r.stdout
