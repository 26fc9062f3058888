"""Kill -9 under ``soilocp run --restart``: the supervisor restarts what died and the OCP stream resumes.

A real ``soilocp run --synthetic mixed --restart`` (router, five services, the synthetic vehicle, each an
OS process) on an ephemeral loopback port; the test's own client session records every OCP with its
arrival time.  Each pipeline service in turn (the short form), or every process including the router
every 10 s for 5 minutes (the long form, ``slow``), is killed with SIGKILL; the supervisor starts it
again.  For each kill: the OCP stream must resume within 2 s of the restarted process being up (its
"running" log event: session open, inputs subscribed, token declared), and a service that held the
soil-strength belief must not serve an ``ok`` from the lost belief: its first records after the restart
are not ``ok``.  Recovery times are printed (the report quotes them).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import zenoh

from soilocp.services.runtime.settings import zenoh_config
from soilocp.services.stages.graph import PIPELINE_SERVICES
from zenoh_helpers import endpoint, free_port, wait_alive, wait_for

RESUME_WITHIN_S = 2.0


def _children(ppid: int) -> dict[str, int]:
    """``{process name: pid}`` of the ``soilocp run`` children (``router``, ``gateway``..., ``vehicle``),
    from /proc (their command lines: ``python -m soilocp.cli router|service NAME ...``)."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            if int(stat[stat.rindex(")") + 2:].split()[1]) != ppid:
                continue
            argv = (d / "cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError):
            continue
        args = [a.decode(errors="replace") for a in argv if a]
        if "soilocp.cli" not in args:
            continue
        rest = args[args.index("soilocp.cli") + 1:]
        name = rest[1] if rest[:1] == ["service"] and len(rest) > 1 else rest[0] if rest else "?"
        out[name] = int(d.name)
    return out


def _running_at(log: Path, pid: int, timeout: float) -> float | None:
    """Wall time of the "running" event logged by process ``pid`` in ``log`` (None if not within ``timeout``)."""
    def find():
        try:
            lines = log.read_text(errors="replace").splitlines()
        except OSError:
            return None
        mine = False
        for line in lines:
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if rec.get("event") == "starting":
                mine = rec.get("pid") == pid
            elif rec.get("event") == "running" and (mine or rec.get("pid") == pid):  # the router logs its pid here
                return rec["ts"]
        return None

    return wait_for(find, timeout, interval=0.05)


def _kill_and_measure(run: subprocess.Popen, log_dir: Path, victims: list[str], interval_s: float, vid: str,
                      ocps: list, lock: threading.Lock) -> list[dict]:
    results = []
    for name in victims:
        time.sleep(interval_s)
        before = _children(run.pid)
        pid = before.get(name)
        assert pid is not None, (name, before)
        with lock:
            n_before = len(ocps)
        t_kill = time.time()
        os.kill(pid, signal.SIGKILL)
        new = wait_for(lambda: (p := _children(run.pid).get(name)) not in (None, pid) and p, 30)
        assert new, f"{name} was not restarted"
        t_up = _running_at(log_dir / f"{name}.log", new, 60)
        assert t_up is not None, f"{name} (pid {new}) never logged running"

        def resumed():
            with lock:
                return next((o for o in ocps[n_before:] if o[0] > max(t_up, t_kill)), None)

        first = wait_for(resumed, 30)
        assert first is not None, f"OCPs did not resume after {name} was restarted"
        with lock:
            after = [o for o in ocps[n_before:] if o[0] >= first[0]][:20]
        results.append({"victim": name, "kill_to_up_s": t_up - t_kill, "up_to_ocp_s": first[0] - t_up,
                        "kill_to_ocp_s": first[0] - t_kill, "first_statuses": [o[2] for o in after[:5]]})
    return results


def _run_kills(tmp_path, victims: list[str], interval_s: float, duration_s: float) -> list[dict]:
    vid = "kill1"
    ep = endpoint(free_port())
    log_dir = tmp_path / "logs"
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    run = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--synthetic", "mixed", "--duration",
                            str(duration_s), "--restart", "--plain", "--listen", ep, "--vehicle-id", vid,
                            "--log-dir", str(log_dir)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           env=env, start_new_session=True)
    ocps: list[tuple[float, int, str]] = []  # (arrival wall time, seq, status)
    lock = threading.Lock()

    def _ocp(sample) -> None:
        t = time.time()
        d = json.loads(sample.payload.to_bytes())
        with lock:
            ocps.append((t, d["seq"], d["status"]))

    try:
        # a client that reconnects fast (as the services do) when the router is the one killed
        with zenoh.open(zenoh_config("client", [ep], [], connect_timeout_ms=60_000)) as s:
            s.declare_subscriber(f"soilocp/{vid}/ocp", _ocp)
            assert wait_alive(s, vid, timeout=90)
            assert wait_for(lambda: len(ocps) > 50, 60), "no OCPs before the first kill"
            results = _kill_and_measure(run, log_dir, victims, interval_s, vid, ocps, lock)
        run.send_signal(signal.SIGTERM)
        out, _ = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait(10)
    text = out.decode(errors="replace")
    for r in results:
        print(f"\nkill -9 {r['victim']}: restarted and running {r['kill_to_up_s']:.2f} s after the kill, "
              f"first OCP {r['up_to_ocp_s']:.3f} s after that ({r['kill_to_ocp_s']:.2f} s after the kill); "
              f"first statuses {r['first_statuses']}")
    for name in victims:
        assert f"soilocp run: {name} exited" in text, text[-3000:]
    seqs = [q for _t, q, _s in ocps]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), "OCPs out of order or repeated"
    return results


@pytest.mark.timeout(240)
def test_kill9_of_each_service_under_the_supervisor_resumes_ocps(tmp_path):
    results = _run_kills(tmp_path, list(PIPELINE_SERVICES), interval_s=4.0, duration_s=60.0)
    for r in results:
        assert r["up_to_ocp_s"] <= RESUME_WITHIN_S, r
        if r["victim"] == "soil-strength":  # its belief was lost: no ok until it has converged again
            assert r["first_statuses"][0] != "ok", r
    print(f"kill -9: max up -> OCP {max(r['up_to_ocp_s'] for r in results):.3f} s, max kill -> OCP "
          f"{max(r['kill_to_ocp_s'] for r in results):.2f} s")


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_kill9_of_every_process_every_10s_for_5_minutes(tmp_path):
    victims = [*PIPELINE_SERVICES, "router"] * 5  # 30 kills, 10 s apart
    results = _run_kills(tmp_path, victims, interval_s=10.0, duration_s=340.0)
    for r in results:
        assert r["up_to_ocp_s"] <= RESUME_WITHIN_S, r
        if r["victim"] == "soil-strength":
            assert r["first_statuses"][0] != "ok", r
    print(f"kill -9: {len(results)} kills, max up -> OCP {max(r['up_to_ocp_s'] for r in results):.3f} s")


def test_every_deployment_restarts_what_dies():
    """Who restarts what (docs/services.md, "Who restarts what"): the systemd units restart the router
    and every service (not on a configuration error, exit 2); in the compose files every long-running
    container restarts (the one-shot certificate maker does not)."""
    import yaml

    root = Path(__file__).resolve().parents[1]
    for unit in ("soilocp@.service", "soilocp-router.service"):
        lines = (root / "deploy" / "systemd" / unit).read_text().splitlines()
        assert "Restart=always" in lines and "RestartPreventExitStatus=2" in lines, unit
    for compose in ("docker-compose.yml", "docker-compose.plain.yml"):
        services = yaml.safe_load((root / compose).read_text())["services"]
        assert services
        for name, svc in services.items():
            want = "no" if name == "certs" else "unless-stopped"
            assert svc.get("restart") == want, (compose, name, svc.get("restart"))
