"""The network-namespace rig shared by the netns suites (scripts/netns-vehicle.sh): whether this
machine can run it, the processes started inside the namespaces (always stopped by id), bounded
waits that fail with the log of a dead process, and the fixture that creates and deletes the
namespaces of one run."""

from __future__ import annotations

import os
import secrets
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import pytest

from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.services.supervisor.processes import ProcessGroup

ROOT = Path(__file__).resolve().parents[1]
NETNS = ROOT / "scripts" / "netns-vehicle.sh"
PROBE = ROOT / "scripts" / "ocp_probe.py"
ESTIMATION = ROOT / "deploy" / "vehicle-two-unit" / "estimation.json"
SENSING_SECURE = ROOT / "deploy" / "vehicle-two-unit" / "sensing-secure.json"
FLEET_SECURE = ROOT / "deploy" / "fleet" / "fleet-router-secure.json"
SOILOCP = [sys.executable, "-m", "soilocp.cli"]
#: The run's addresses (scripts/netns-vehicle.sh): the fleet router, the sensing unit's router on
#: the link to the estimation unit, and each unit's own loopback router.
VID = "rover1"
VEHICLE_ROUTER_EP = "tcp/10.99.1.1:7447"
LOCAL_EP = "tcp/127.0.0.1:7447"


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


class Processes(ProcessGroup):
    """Processes started inside the run's namespaces by the product's supervisor; stopped by
    name (SIGTERM in reverse order, then SIGKILL)."""

    def __init__(self, run_id: str, logdir: Path):
        # never inherit endpoint settings from the caller's shell
        super().__init__(logdir, drop_env=("SOILOCP_CONNECT", "SOILOCP_LISTEN", "SOILOCP_ROUTER_CONNECT", "SOILOCP_CONFIG"),
                         exit_with_parent=False)
        self.run_id = run_id

    def start(self, name: str, unit: str, argv: list[str], env: dict[str, str]) -> subprocess.Popen:
        # netns-vehicle.sh execs `ip netns exec`, which execs argv: the pid is the process itself
        return self.start_argv(name, [str(NETNS), "exec", self.run_id, unit, *argv], env=env, cwd=self.log_dir,
                               new_session=False).proc


#: The pipeline rows of the sensing unit (deploy/vehicle-two-unit); the others run on the estimation unit.
SENSING_ROWS = ("gateway", "normal-force")


def start_two_unit_vehicle(procs: Processes, sense: dict[str, str], est: dict[str, str], fleet_ep: str, *,
                           duration_s: float, vehicle_router_env: Optional[dict[str, str]] = None) -> None:
    """The vehicle of deploy/vehicle-two-unit inside the run's namespaces: its router on the
    sensing unit (uplink ``fleet_ep``), the estimation unit's router linked to it, the pipeline
    rows split between the two units, and a synthetic vehicle on sand at 50 Hz for ``duration_s``."""
    procs.start("vehicle-router", "sense", [*SOILOCP, "router"],
                {**sense, "SOILOCP_ROUTER_CONNECT": fleet_ep, **(vehicle_router_env or {})})
    procs.start("unit-router", "est", [*SOILOCP, "router"], {**est, "SOILOCP_ROUTER_CONNECT": VEHICLE_ROUTER_EP})
    for name in PIPELINE_SERVICES:
        unit, env = ("sense", sense) if name in SENSING_ROWS else ("est", est)
        procs.start(name, unit, [*SOILOCP, "service", name], env)
    procs.start("vehicle", "sense", [*SOILOCP, "service", "vehicle", "--scenario", "sand", "--rate", "50",
                                     "--duration", f"{duration_s:g}", "--wait-timeout", "120"], sense)


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
