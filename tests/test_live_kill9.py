"""Kill -9 under ``soilocp run --restart``: the supervisor restarts what died and the OCP stream resumes.

A real ``soilocp run --synthetic mixed --restart --map-store sqlite:...`` (router, the fleet soil map
service, five services, the synthetic vehicle with a start pose so that its soil estimates carry
places, each an OS process) on an ephemeral loopback port; the test's own client session records
every OCP and every map acknowledgement (``soilmap/<id>/cells``) with its arrival time.  The map
service and each pipeline service in turn (the short form), or every process including the router
every 10 s for 5 minutes (the long form, ``slow``), is killed with SIGKILL; the supervisor starts it
again.  For each kill: the OCP stream must resume within 2 s of the restarted process being up (its
"running" log event: session open, inputs subscribed, token declared), and a service that held the
soil-strength belief must not serve an ``ok`` from the lost belief: its first records after the restart
are not ``ok``.  The map must hold every update it acknowledged, across its own kills and everyone
else's.  ``soilocp fleet status --json`` must show each restart: per process the count and the age of
the last one.  Recovery times are printed (the report quotes them).
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

from soilocp.map.store import open_store
from soilocp.schemas import keys
from soilocp.schemas.map import MapCellUpdate
from soilocp.services.runtime.settings import zenoh_config
from soilocp.services.stages.graph import PIPELINE_SERVICES
from zenoh_helpers import endpoint, free_port, wait_alive, wait_for

RESUME_WITHIN_S = 2.0
MAP_ID = "kill"


class MapAcks:
    """What the map service acknowledged (``soilmap/<id>/cells``, published after each commit): per
    vehicle its committed total, per cell its count, and the arrival time of each acknowledgement."""

    def __init__(self):
        self.lock = threading.Lock()
        self.totals: dict[str, int] = {}
        self.cells: dict[str, int] = {}
        self.times: list[float] = []

    def __call__(self, sample) -> None:
        t = time.time()
        m = MapCellUpdate.model_validate_json(sample.payload.to_bytes())
        with self.lock:
            self.times.append(t)
            for v, (_seq, total) in m.applied.items():
                self.totals[v] = max(self.totals.get(v, 0), total)
            for c in m.cells:
                self.cells[c.cell] = max(self.cells.get(c.cell, 0), c.count)


def _fleet_status(ep: str) -> dict:
    """``soilocp fleet status --json`` as a user runs it: the vehicle rows by id."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    res = subprocess.run([sys.executable, "-m", "soilocp.cli", "fleet", "status", "--connect", ep, "--json",
                          "--timeout", "5"], capture_output=True, text=True, timeout=90, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    return {r["vehicle_id"]: r for r in json.loads(res.stdout)["vehicles"]}


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
                      ocps: list, lock: threading.Lock, acks: MapAcks) -> list[dict]:
    results = []
    for name in victims:
        time.sleep(interval_s)
        before = _children(run.pid)
        pid = before.get(name)
        assert pid is not None, (name, before)
        with lock:
            n_before = len(ocps)
        with acks.lock:
            acks_before = len(acks.times)
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
        r = {"victim": name, "t_kill": t_kill, "kill_to_up_s": t_up - t_kill, "up_to_ocp_s": first[0] - t_up,
             "kill_to_ocp_s": first[0] - t_kill, "first_statuses": [o[2] for o in after[:5]]}
        if name == "map":  # its own output: the acknowledgements of committed estimates
            def acked():
                with acks.lock:
                    return next((t for t in acks.times[acks_before:] if t > t_up), None)

            t_ack = wait_for(acked, 30)
            assert t_ack is not None, "the restarted map service acknowledged nothing"
            r["up_to_ack_s"] = t_ack - t_up
        results.append(r)
    return results


def _run_kills(tmp_path, victims: list[str], interval_s: float, duration_s: float) -> list[dict]:
    vid = "kill1"
    ep = endpoint(free_port())
    log_dir = tmp_path / "logs"
    store = f"sqlite:{tmp_path / 'map.db'}"
    # the vehicle drives in a map frame: its soil estimates carry places, which the map stores
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")},
           "SOILOCP_START_POSE": "field:0,0,0"}
    run = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--synthetic", "mixed", "--duration",
                            str(duration_s), "--restart", "--plain", "--listen", ep, "--vehicle-id", vid,
                            "--log-dir", str(log_dir), "--map-store", store, "--map-id", MAP_ID],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    ocps: list[tuple[float, int, str]] = []  # (arrival wall time, seq, status)
    lock = threading.Lock()
    acks = MapAcks()

    def _ocp(sample) -> None:
        t = time.time()
        d = json.loads(sample.payload.to_bytes())
        with lock:
            ocps.append((t, d["seq"], d["status"]))

    try:
        # a client that reconnects fast (as the services do) when the router is the one killed
        with zenoh.open(zenoh_config("client", [ep], [], connect_timeout_ms=60_000)) as s:
            s.declare_subscriber(keys.ocp(vid), _ocp)
            s.declare_subscriber(keys.map_key(MAP_ID, "cells"), acks)
            assert wait_alive(s, vid, timeout=90)
            assert wait_for(lambda: len(ocps) > 50, 60), "no OCPs before the first kill"
            assert wait_for(lambda: acks.totals, 60), "the map acknowledged nothing before the first kill"
            results = _kill_and_measure(run, log_dir, victims, interval_s, vid, ocps, lock, acks)
            time.sleep(1.0)  # the last restart's report reaches the router
            rows = _fleet_status(ep)
            t_status = time.time()  # the ages are taken while the call runs: bound them by its end
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
              f"first statuses {r['first_statuses']}"
              + (f"; first map acknowledgement {r['up_to_ack_s']:.3f} s after it was up" if "up_to_ack_s" in r else ""))
    for name in victims:
        assert f"soilocp run: {name} exited" in text, text[-3000:]
    seqs = [q for _t, q, _s in ocps]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), "OCPs out of order or repeated"
    print(f"OCPs: {len(seqs)} received of seqs {seqs[0]}..{seqs[-1]}: {seqs[-1] - seqs[0] + 1 - len(seqs)} samples "
          f"without an OCP over {len(victims)} kills")
    _check_fleet_status(rows.get(vid), victims, results, t_status)
    _check_map_kept_every_ack(store, acks)
    return results


def _check_fleet_status(row, victims: list[str], results: list[dict], t_status: float) -> None:
    """`fleet status` names each restarted process with its count, and its last restart's age is
    that of its last kill (restarted after the kill, before the status call)."""
    assert row is not None, "fleet status has no row for the vehicle"
    per = row["restarts"] or {}
    assert row["restarts_total"] == len(victims), row
    for name in set(victims):
        p = per.get(name)
        assert p is not None and p["restarts"] == victims.count(name) and p["state"] == "running", (name, row)
        last_kill = max(r["t_kill"] for r in results if r["victim"] == name)
        assert 0 <= p["last_restart_age_s"] <= t_status - last_kill + 1.0, (name, p, t_status - last_kill)
        assert p["last_exit"] == -signal.SIGKILL, (name, p)
    print(f"\nfleet status: restarts {row['restarts_total']}: " + ", ".join(
        f"{n} {p['restarts']} (last {p['last_restart_age_s']:.1f} s ago)" for n, p in sorted(per.items())))


def _check_map_kept_every_ack(store_url: str, acks: MapAcks) -> None:
    """No acknowledged map update lost: each vehicle's committed total and each cell's count that the
    map service acknowledged, at any time of the run, are in the store after it."""
    st = open_store(store_url)
    try:
        ledger = st.ledger()
        got = {c.cell: c for c in st.all_cells(time.time(), "field")}
    finally:
        st.close()
    with acks.lock:
        totals, cells, n = dict(acks.totals), dict(acks.cells), len(acks.times)
    assert totals, "no map acknowledgement"
    for v, total in totals.items():
        assert v in ledger and ledger[v][1] >= total, (v, ledger.get(v), total)
    lost = {c: k for c, k in cells.items() if c not in got or got[c].count < k}
    assert not lost, f"acknowledged cells missing or behind in the store: {lost}"
    print(f"map: {n} acknowledgements, {sum(totals.values())} estimates acknowledged, store holds "
          f"{sum(a for _s, a in ledger.values())}; {len(cells)} acknowledged cells, all in the store")


@pytest.mark.timeout(300)
def test_kill9_of_each_service_under_the_supervisor_resumes_ocps(tmp_path):
    results = _run_kills(tmp_path, ["map", *PIPELINE_SERVICES], interval_s=4.0, duration_s=150.0)
    for r in results:
        assert r["up_to_ocp_s"] <= RESUME_WITHIN_S, r
        if r["victim"] == "soil-strength":  # its belief was lost: no ok until it has converged again
            assert r["first_statuses"][0] != "ok", r
    print(f"kill -9: max up -> OCP {max(r['up_to_ocp_s'] for r in results):.3f} s, max kill -> OCP "
          f"{max(r['kill_to_ocp_s'] for r in results):.2f} s")


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_kill9_of_every_process_every_10s_for_5_minutes(tmp_path):
    victims = [*PIPELINE_SERVICES, "router", "map"] * 5  # 35 kills, 10 s apart, 5 minutes and 50 s
    results = _run_kills(tmp_path, victims, interval_s=10.0, duration_s=600.0)
    for r in results:
        assert r["up_to_ocp_s"] <= RESUME_WITHIN_S, r
        if r["victim"] == "soil-strength":
            assert r["first_statuses"][0] != "ok", r
    print(f"kill -9: {len(results)} kills, max up -> OCP {max(r['up_to_ocp_s'] for r in results):.3f} s")


def test_every_deployment_restarts_what_dies():
    """Who restarts what (docs/services.md, "Who restarts what"): every systemd unit of deploy/systemd
    restarts its process (``Restart=always``, ``RestartSec=1``; not on a configuration error, exit 2);
    in every compose file each long-running container restarts (``unless-stopped``) and the one-shot
    certificate maker does not; the docs name each of these files."""
    import yaml

    root = Path(__file__).resolve().parents[1]
    units = sorted((root / "deploy" / "systemd").glob("*.service"))
    assert {u.name for u in units} >= {"soilocp@.service", "soilocp-router.service"}, units
    for unit in units:
        lines = unit.read_text().splitlines()
        for want in ("Restart=always", "RestartSec=1", "RestartPreventExitStatus=2"):
            assert want in lines, (unit.name, want)
    composes = sorted(root.glob("docker-compose*.yml"))
    assert {c.name for c in composes} >= {"docker-compose.yml", "docker-compose.plain.yml"}, composes
    for compose in composes:
        services = yaml.safe_load(compose.read_text())["services"]
        assert services, compose.name
        for name, svc in services.items():
            want = "no" if name == "certs" else "unless-stopped"
            assert svc.get("restart") == want, (compose.name, name, svc.get("restart"))
    doc = (root / "docs" / "services.md").read_text()
    section = doc[doc.index("**Who restarts what.**"):doc.index("**A hostile publisher.**")]
    for name in [u.name for u in units] + [c.name for c in composes] + ["--restart"]:
        assert name in section, f"docs/services.md 'Who restarts what' does not name {name}"
