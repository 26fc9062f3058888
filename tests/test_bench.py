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

from services.bench import json_safe, verdict
from services.bench_live import proc_cpu_seconds, proc_rss_mib
from services.bench_stages import STAGES, summarize

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
    assert proc_cpu_seconds(2**22 + 12345) is None  # no such pid


@pytest.mark.timeout(900)
def test_quick_bench_report_is_well_formed(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, "-m", "services.bench", "--quick", "--json", str(out)],
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
