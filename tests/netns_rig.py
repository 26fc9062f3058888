"""The network-namespace rig shared by the netns suites (scripts/netns-vehicle.sh): whether this
machine can run it, the processes started inside the namespaces (always stopped by id), bounded
waits that fail with the log of a dead process, and the fixture that creates and deletes the
namespaces of one run."""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import pytest

ROOT = Path(__file__).resolve().parents[1]
NETNS = ROOT / "scripts" / "netns-vehicle.sh"


def netns_unavailable() -> Optional[str]:
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "needs root to create network namespaces (ip netns add)"
    if shutil.which("ip") is None:
        return "iproute2's `ip` command is not installed"
    name = f"soilocp-chk{os.getpid()}"
    res = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if res.returncode != 0:
        return f"`ip netns add` is not permitted here: {res.stderr.strip()[:200]}"
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return None


class Processes:
    """Processes started inside the run's namespaces; stopped by id (SIGTERM, then SIGKILL)."""

    def __init__(self, run_id: str, logdir: Path):
        self.run_id = run_id
        self.logdir = logdir
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, unit: str, argv: list[str], env: dict[str, str]) -> subprocess.Popen:
        full_env = dict(os.environ, PYTHONUNBUFFERED="1", **env)
        # never inherit endpoint settings from the caller's shell
        for k in ("SOILOCP_CONNECT", "SOILOCP_LISTEN", "SOILOCP_ROUTER_CONNECT", "SOILOCP_CONFIG"):
            if k not in env:
                full_env.pop(k, None)
        log = open(self.logdir / f"{name}.log", "wb")
        # netns-vehicle.sh execs `ip netns exec`, which execs argv: the pid is the process itself
        proc = subprocess.Popen([str(NETNS), "exec", self.run_id, unit, *argv], stdout=log,
                                stderr=subprocess.STDOUT, env=full_env, cwd=str(self.logdir))
        log.close()
        self.procs[name] = proc
        return proc

    def dead(self) -> dict[str, int]:
        return {n: p.returncode for n, p in self.procs.items() if p.poll() is not None}

    def stop(self, names: Optional[list[str]] = None, timeout: float = 8.0) -> dict[str, int]:
        names = list(self.procs) if names is None else names
        for n in reversed(names):
            if self.procs[n].poll() is None:
                self.procs[n].send_signal(signal.SIGTERM)
        deadline = time.time() + timeout
        codes = {}
        for n in names:
            p = self.procs[n]
            try:
                codes[n] = p.wait(max(0.1, deadline - time.time()))
            except subprocess.TimeoutExpired:
                p.kill()
                codes[n] = p.wait()
                codes[n] = -9 if codes[n] is None else codes[n]
        return codes

    def tail(self, name: str, n: int = 15) -> str:
        try:
            lines = (self.logdir / f"{name}.log").read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(lines[-n:])




def wait_until(what: str, cond: Callable[[], bool], timeout: float, procs: Processes) -> float:
    """Poll ``cond`` until true; fail with the logs of dead processes if it never becomes true."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return time.time() - t0
        dead = procs.dead()
        if dead:
            name = next(iter(dead))
            pytest.fail(f"while waiting for {what}: {name} exited with {dead[name]}:\n{procs.tail(name)}")
        time.sleep(0.2)
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")


@pytest.fixture
def vehicle_netns():
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    run_id = secrets.token_hex(3)
    subprocess.run([str(NETNS), "up", run_id], check=True, capture_output=True, text=True)
    try:
        yield run_id
    finally:
        subprocess.run([str(NETNS), "down", run_id], capture_output=True, text=True)
        left = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert f"soilocp-{run_id}-" not in left, f"namespaces of run {run_id} left behind:\n{left}"
