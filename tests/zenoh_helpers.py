"""Helpers for the services tests: ephemeral ports, child processes that are always reaped,
client sessions with explicit endpoints (multicast scouting off) and bounded waits."""

from __future__ import annotations

import json
import socket
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Optional

from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.services.supervisor import liveliness
from soilocp.services.supervisor.processes import ProcessGroup

PIPELINE = PIPELINE_SERVICES  # the rig starts the rows the graph declares


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nobody listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def wait_for(pred: Callable[[], object], timeout: float, interval: float = 0.05):
    """Poll ``pred`` until it returns something truthy (returned) or ``timeout`` s pass (None)."""
    deadline = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            return None
        time.sleep(interval)


class Procs(ProcessGroup):
    """Child processes of one test (the product's supervisor, with no SOILOCP_* setting inherited);
    :meth:`close` stops and reaps every one (SIGTERM, then SIGKILL)."""

    def __init__(self, log_dir: Path):
        super().__init__(log_dir, drop_env=("SOILOCP_",), exit_with_parent=False)

    def spawn(self, name: str, args: Iterable[str], env: Optional[dict] = None) -> subprocess.Popen:
        return self.start(name, args, env=env).proc


def client_config(ep: str):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([ep]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


@contextmanager
def client(ep: str):
    """A client session on ``ep`` (waits up to ~20 s for the router)."""
    import zenoh

    last = None
    for _ in range(40):
        try:
            s = zenoh.open(client_config(ep))
            break
        except zenoh.ZError as exc:
            last = exc
            time.sleep(0.5)
    else:
        raise RuntimeError(f"no router on {ep}: {last}")
    try:
        yield s
    finally:
        s.close()


def alive_services(session, vid: str) -> set[str]:
    return {s for _v, s in liveliness.alive_services(session, vid)}


def wait_alive(session, vid: str, services: Iterable[str] = PIPELINE, timeout: float = 120.0) -> bool:
    return not liveliness.wait_alive(session, [vid], services, timeout)


def get_payloads(session, selector: str, timeout: float = 3.0) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(selector, timeout=timeout) if r.ok is not None]


def start_pipeline(procs: Procs, ep: str, vid: str, extra: Iterable[str] = ()) -> None:
    for name in PIPELINE:
        procs.spawn(name, ["service", name, "--vehicle-id", vid, "--connect", ep, *extra])


def fleet_status(ep: str, vid: str) -> tuple[dict, str]:
    """``soilocp fleet status`` against the router at ``ep``, as a user runs it (no SOILOCP_* environment): the
    row of ``vid`` from ``--json``, and the table."""
    import os
    import sys

    env = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    out = {}
    for fmt in (["--json"], []):
        res = subprocess.run([sys.executable, "-m", "soilocp.cli", "fleet", "status", "--connect", ep, "--timeout",
                              "3", *fmt], capture_output=True, text=True, timeout=60, env=env)
        assert res.returncode == 0, res.stdout + res.stderr
        out["json" if fmt else "table"] = res.stdout
    rows = {r["vehicle_id"]: r for r in json.loads(out["json"])["vehicles"]}
    assert vid in rows, rows
    return rows[vid], out["table"]


def write_log(path: Path, vid: str, duration: float, scenario: str = "sandy-slope", seed: int = 1) -> list[str]:
    """A sensor log from the simulator (JSON Lines, one SensorSample per line); returns the lines."""
    from soilocp.sim.simulator import simulate

    lines = [s.model_dump_json() for s, _t in simulate(scenario, duration=duration, seed=seed, vehicle_id=vid)]
    path.write_text("\n".join(lines) + "\n")
    return lines


def wait_count(count: Callable[[], int], target: int, *, stall_s: float = 20.0, overall_s: float = 100.0) -> bool:
    """Wait until ``count() >= target``, failing only if it stops growing for ``stall_s`` (a loaded
    machine is slow, not broken) or after ``overall_s``."""
    start = last_change = time.monotonic()
    last = count()
    while last < target:
        time.sleep(0.1)
        now = time.monotonic()
        n = count()
        if n != last:
            last, last_change = n, now
        elif now - last_change > stall_s or now - start > overall_s:
            return False
    return True


def json_lines_so_far(path: Path) -> list[dict]:
    """JSON lines a child process has written so far (a partly written last line is ignored)."""
    out = []
    try:
        text = path.read_text()
    except OSError:
        return out
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass
    return out
