"""Containers: the image built with no registry, the compose fleet, and what survives in it.

`test_compose_fleet_*` (skipped with the reason unless `docker info` answers and a compose tool
exists): builds the images offline with scripts/build-images.sh (debootstrap base, cached; wheels
from the host; layers cached), starts docker-compose.yml under a unique project name with the
fleet router published on a free 127.0.0.1 port, and from the host (the fleet side) watches both
vehicles' OCPs with scripts/ocp_probe.py:

1. both vehicles produce fresh OCPs through their vehicle router and the fleet router;
2. the fleet port is TLS only (a plain TCP client is refused);
   the health check says healthy in a service and a router container (the TLS fleet router);
3. rover1's observer container is killed: rover1's OCPs go stale while rover2's stay fresh;
   started again, rover1's OCPs resume;
4. rover1's router is disconnected from the fleet network: the fleet sees rover1's liveliness
   tokens disappear (rover2's stay); reconnected, they come back and rover1's OCPs flow again
   (asserted).

Image build time and every recovery time are measured and printed. The project is always torn
down (`down -v --remove-orphans`) in a finally.  OCP records must never arrive corrupted or out
of order at the fleet.

The other tests check the scripts' pure parts (apt sources parsing, health-check settings) on
any machine.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import pytest
from zenoh_helpers import json_lines_so_far

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"
PROBE = SCRIPTS / "ocp_probe.py"
IMAGE = "soilocp:local"
BASE = "soilocp-base:local"
VEHICLES = ("rover1", "rover2")
SERVICES = ("gateway", "normal-force", "observer", "soil-strength", "ocp", "vehicle")



def _load(name: str, path: Path):
    """Import a script file as a module under a private name (the scripts are not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


debian_mirror = _load("_soilocp_debian_mirror", SCRIPTS / "debian_mirror.py")
healthcheck = _load("_soilocp_healthcheck", ROOT / "deploy" / "healthcheck.py")


def compose_command() -> Optional[list[str]]:
    """`docker compose` (plugin) if it answers, else `docker-compose` (v1), else None."""
    if subprocess.run(["docker", "compose", "version"], capture_output=True).returncode == 0:
        return ["docker", "compose"]
    if shutil.which("docker-compose"):
        return ["docker-compose"]
    return None


def _docker_unavailable() -> Optional[str]:
    if shutil.which("docker") is None:
        return "the docker client is not installed"
    try:
        res = subprocess.run(["docker", "info"], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        return "`docker info` did not answer within 30 s"
    if res.returncode != 0:
        return f"no Docker Engine answers `docker info`: {res.stderr.strip()[:200]}"
    if compose_command() is None:
        return "neither `docker compose` nor `docker-compose` is installed"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]




def _present_tokens(recs: list[dict], vid: str) -> set[str]:
    """Liveliness tokens of ``vid`` present after replaying the probe's alive events."""
    present: set[str] = set()
    for r in recs:
        if r["kind"] == "alive" and r["key"].startswith(f"soilocp/{vid}/alive/"):
            (present.add if r["present"] else present.discard)(r["key"])
    return present


class Fleet:
    """One compose project and a probe on the host; everything it starts, it stops."""

    def __init__(self, tmp: Path):
        self.compose = compose_command()
        self.project = f"soilocpt{secrets.token_hex(3)}"
        self.port = _free_port()
        self.env = dict(os.environ, BASE_IMAGE=BASE, SOILOCP_IMAGE=IMAGE, SOILOCP_FLEET_PORT=str(self.port),
                        SOILOCP_DASHBOARD_PORT=str(_free_port()),
                        SOILOCP_RATE="25")  # 16 containers on a 2-core machine: a light sensor rate
        self.dashboard_port = int(self.env["SOILOCP_DASHBOARD_PORT"])
        self.out = tmp / "probe-fleet.jsonl"
        self.probe: Optional[subprocess.Popen] = None

    def run(self, *args: str, timeout: float = 300, check: bool = True) -> subprocess.CompletedProcess:
        cmd = [*self.compose, "-p", self.project, "-f", str(ROOT / "docker-compose.yml"), *args]
        res = subprocess.run(cmd, capture_output=True, text=True, env=self.env, cwd=ROOT, timeout=timeout)
        if check and res.returncode != 0:
            raise AssertionError(f"{' '.join(cmd)} failed ({res.returncode}):\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
        return res

    def container(self, service: str) -> str:
        cid = self.run("ps", "-q", service).stdout.strip()
        assert cid, f"no container for {service}"
        return cid

    def fetch_certs(self) -> Path:
        """The development certificates the compose "certs" container made (a fleet tool on the
        host needs the dashboard's to reach the TLS-only fleet router)."""
        certs = self.out.parent / "certs"
        certs.mkdir(exist_ok=True)
        subprocess.run(["docker", "cp", f"{self.container('certs')}:/etc/soilocp/certs/.", str(certs)], check=True,
                       capture_output=True, timeout=120)
        self.tls_env = {"SOILOCP_TLS_CA": str(certs / "ca.pem"), "SOILOCP_TLS_CERT": str(certs / "dashboard.pem"),
                        "SOILOCP_TLS_KEY": str(certs / "dashboard.key")}
        return certs

    def start_probe(self) -> None:
        argv = [sys.executable, str(PROBE), "--connect", f"tls/127.0.0.1:{self.port}", "--period", "0.25",
                "--query-timeout", "1.0", "--out", str(self.out)]
        for vid in VEHICLES:
            argv += ["--vehicle", vid]
        self.probe = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=open(self.out.with_suffix(".err"), "wb"),
                                      env={**os.environ, **self.tls_env})

    def records(self) -> list[dict]:
        return json_lines_so_far(self.out)

    def wait(self, what: str, cond: Callable[[list[dict]], bool], timeout: float) -> float:
        t0 = time.time()
        while time.time() - t0 < timeout:
            if cond(self.records()):
                return time.time() - t0
            if self.probe is not None and self.probe.poll() is not None:
                err = self.out.with_suffix(".err").read_text(errors="replace")[-1500:]
                pytest.fail(f"while waiting for {what}: the probe exited with {self.probe.returncode}\n{err}")
            time.sleep(0.25)
        logs = self.run("logs", "--tail", "8", timeout=120, check=False).stdout[-6000:]
        pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}\n{logs}")

    def stop_probe(self) -> Optional[int]:
        if self.probe is None or self.probe.poll() is not None:
            return None if self.probe is None else self.probe.returncode
        self.probe.send_signal(signal.SIGTERM)
        try:
            return self.probe.wait(15)
        except subprocess.TimeoutExpired:
            self.probe.kill()
            return self.probe.wait()

    def down(self) -> None:
        self.stop_probe()
        self.run("down", "-v", "--remove-orphans", "-t", "5", timeout=300, check=False)


def _wait_dashboard(port: int, timeout: float) -> float:
    """Seconds until the dashboard's GET /api/vehicles lists every vehicle (fails on timeout)."""
    import urllib.error
    import urllib.request

    t0, last = time.time(), "no answer"
    while time.time() - t0 < timeout:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/vehicles", timeout=5) as resp:
                body = json.loads(resp.read())
            seen = {row.get("vehicle_id") for row in body.get("vehicles", [])}
            if set(VEHICLES) <= seen:
                return time.time() - t0
            last = f"vehicles {sorted(map(str, seen))}"
        except (OSError, urllib.error.URLError, ValueError) as exc:
            last = f"{type(exc).__name__}: {exc}"
        time.sleep(1.0)
    pytest.fail(f"the dashboard did not list {VEHICLES} within {timeout:.0f} s ({last})")


def fresh(vid: str, after: float = 0.0) -> Callable[[list[dict]], bool]:
    return lambda recs: any(r["kind"] == "query" and r["vid"] == vid and r["t"] > after and r["stale"] is False
                            for r in recs)


def first_time(recs: list[dict], pred: Callable[[dict], bool]) -> Optional[float]:
    return next((r["t"] for r in recs if pred(r)), None)


@pytest.fixture(scope="module")
def image_build_seconds():
    reason = _docker_unavailable()
    if reason:
        pytest.skip(reason)
    t0 = time.time()
    res = subprocess.run([str(SCRIPTS / "build-images.sh")], capture_output=True, text=True, timeout=1500,
                         env=dict(os.environ, BASE_IMAGE=BASE, SOILOCP_IMAGE=IMAGE, PYTHON=sys.executable))
    assert res.returncode == 0, f"image build failed:\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    took = time.time() - t0
    print(f"\nimage build (offline, cached where possible): {took:.1f} s\n" +
          "\n".join(line for line in res.stdout.splitlines() if line.startswith("build-")))
    return took


@pytest.mark.docker
@pytest.mark.e2e
@pytest.mark.timeout(1500)
def test_compose_fleet_survives_service_kill_and_fleet_partition(image_build_seconds, tmp_path):
    fleet = Fleet(tmp_path)
    times: dict[str, float] = {}
    try:
        t0 = time.time()
        fleet.run("up", "-d", timeout=600)
        times["compose up"] = time.time() - t0
        fleet.fetch_certs()
        fleet.start_probe()
        times["both vehicles fresh at the fleet"] = fleet.wait(
            "fresh OCPs of both vehicles at the fleet", lambda r: fresh("rover1")(r) and fresh("rover2")(r), 300
        ) + times["compose up"]

        # the dashboard on the fleet network, if the image has the command (see docs/deploy.md)
        has_dashboard = subprocess.run(["docker", "exec", fleet.container("fleet-router"), "soilocp", "dashboard",
                                        "--help"], capture_output=True, timeout=120).returncode == 0
        if has_dashboard:
            try:
                times["dashboard lists both vehicles"] = _wait_dashboard(fleet.dashboard_port, 120) + \
                    times["both vehicles fresh at the fleet"]
            except BaseException:
                print(fleet.run("logs", "--tail", "20", "dashboard", timeout=120, check=False).stdout[-4000:])
                raise

        # the published fleet port is TLS only: a plain TCP client gets nothing (the refusal cases of
        # TLS clients are tests/test_fleet_security.py)
        no_cert = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
        res = subprocess.run([sys.executable, "-m", "soilocp.cli", "fleet", "status", "--connect",
                              f"tcp/127.0.0.1:{fleet.port}", "--timeout", "3"], capture_output=True, text=True,
                             env=no_cert, timeout=120)
        assert res.returncode == 1 and "no router answered" in res.stdout + res.stderr, res

        # 2. health checks, as docker runs them, in a service and in a router container
        for service in ("rover1-ocp", "fleet-router"):
            res = subprocess.run(["docker", "exec", fleet.container(service), "soilocp-healthcheck"],
                                 capture_output=True, text=True, timeout=120)
            assert res.returncode == 0 and res.stdout.startswith("healthy"), (service, res.stdout, res.stderr)

        # 3. kill rover1's observer: rover1 goes stale, rover2 does not notice; start it again
        observer = fleet.container("rover1-observer")
        t_kill = time.time()
        subprocess.run(["docker", "kill", observer], check=True, capture_output=True)
        fleet.wait("rover1 stale after its observer was killed",
                   lambda recs: any(r["kind"] == "query" and r["vid"] == "rover1" and r["t"] > t_kill
                                    and r["stale"] is True for r in recs), 60)
        time.sleep(1.0)
        t_start = time.time()
        subprocess.run(["docker", "start", observer], check=True, capture_output=True)
        fleet.wait("rover1 fresh again after its observer restarted", fresh("rover1", t_start), 180)
        recs = fleet.records()
        times["rover1 stale after observer kill"] = first_time(
            recs, lambda r: r["kind"] == "query" and r["vid"] == "rover1" and r["t"] > t_kill and r["stale"]) - t_kill
        times["rover1 fresh after observer start"] = first_time(
            recs, lambda r: r["kind"] == "query" and r["vid"] == "rover1" and r["t"] > t_start
            and r["stale"] is False) - t_start
        rover2_during = [r for r in recs if r["kind"] == "query" and r["vid"] == "rover2" and t_kill < r["t"] < t_start]
        assert rover2_during and all(r["stale"] is False for r in rover2_during), \
            "rover2 went stale while only rover1's observer was down"

        # 4. cut rover1's router off the fleet network, then reconnect it
        router = fleet.container("rover1-router")
        networks = json.loads(subprocess.run(["docker", "inspect", "--format", "{{json .NetworkSettings.Networks}}",
                                              router], check=True, capture_output=True, text=True).stdout)
        fleet_net = next(n for n in networks if n.endswith("_fleet"))
        before = _present_tokens(fleet.records(), "rover1")
        assert before == {f"soilocp/rover1/alive/{s}" for s in SERVICES}, f"rover1 tokens at the fleet: {before}"
        t_cut = time.time()
        subprocess.run(["docker", "network", "disconnect", fleet_net, router], check=True, capture_output=True)
        fleet.wait("rover1's liveliness gone from the fleet", lambda recs: not _present_tokens(recs, "rover1"), 90)
        times["rover1 liveliness gone after disconnect"] = time.time() - t_cut
        assert len(_present_tokens(fleet.records(), "rover2")) == len(SERVICES), "rover2 lost tokens"
        t_join = time.time()
        subprocess.run(["docker", "network", "connect", fleet_net, router], check=True, capture_output=True)
        fleet.wait("rover1's liveliness back at the fleet",
                   lambda recs: len(_present_tokens(recs, "rover1")) == len(SERVICES), 120)
        times["rover1 liveliness back after reconnect"] = time.time() - t_join
        # ... and its OCPs flow again: publications and fresh query answers after the reconnect
        # (the long-outage fixes, docs/deploy.md "Long fleet outages"; many outages in a row:
        # tests/test_fleet_outage_netns.py)
        fleet.wait("rover1's OCPs at the fleet again after the reconnect",
                   lambda recs: any(r["kind"] == "sample" and r["vid"] == "rover1" and r["t"] > t_join + 1.0
                                    for r in recs) and fresh("rover1", t_join + 1.0)(recs), 60)
        times["rover1 OCPs at the fleet after reconnect"] = time.time() - t_join
        time.sleep(1.0)
        assert fleet.stop_probe() == 0
    finally:
        fleet.down()

    recs = fleet.records()
    for vid in VEHICLES:
        assert not [r for r in recs if r["kind"] == "corrupt" and r["vid"] == vid], f"{vid}: corrupted OCPs"
        seqs = [r["seq"] for r in recs if r["kind"] == "sample" and r["vid"] == vid]
        assert len(seqs) > 50, f"{vid}: only {len(seqs)} OCP records at the fleet"
        bad = [(a, b) for a, b in zip(seqs, seqs[1:]) if b <= a]
        assert not bad, f"{vid}: OCP seq not strictly increasing at the fleet: {bad[:5]}"
    left = subprocess.run(["docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={fleet.project}"],
                          capture_output=True, text=True).stdout.split()
    assert not left, f"containers left after down: {left}"

    print(f"compose project {fleet.project} ({' '.join(fleet.compose)}), 16 containers + certs, fleet links TLS:")
    print(f"  image build {image_build_seconds:.1f} s")
    for name, value in times.items():
        print(f"  {name}: {value:.2f} s")
    if not has_dashboard:
        print("  dashboard: the image's soilocp has no 'dashboard' command: not checked")


# ---------------------------------------------------------------------------------------------
# pure parts of the scripts (any machine)
# ---------------------------------------------------------------------------------------------
def _apt_root(tmp_path: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = tmp_path / "etc/apt" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def test_debian_mirror_reads_deb822_and_one_line_sources(tmp_path):
    root = _apt_root(tmp_path, {
        "sources.list": "# deb http://old.invalid/debian bookworm main\n"
                        "deb-src http://src.invalid/debian bookworm main\n"
                        "deb [arch=amd64 signed-by=/k.gpg] http://one.invalid/debian/ bookworm contrib\n",
        "sources.list.d/debian.sources": "Types: deb\n# URIs: http://commented.invalid/debian\n"
                                         "URIs: http://mirror.invalid/debian\nSuites: bookworm bookworm-updates\n"
                                         "Components: main\n\nTypes: deb\nURIs: http://sec.invalid/debian-security\n"
                                         "Suites: bookworm-security\nComponents: main\n",
        "sources.list.d/other.list.disabled": "deb http://disabled.invalid/debian trixie main\n",
        "sources.list.d/off.sources": "Enabled: no\nTypes: deb\nURIs: http://off.invalid/x\nSuites: sid\n"
                                      "Components: main\n",
    })
    # contrib-only one-line entry and deb-src are skipped: the deb822 mirror with main wins
    assert debian_mirror.mirror_for("bookworm", str(root) + "/") == "http://mirror.invalid/debian"
    assert debian_mirror.mirror_for("bookworm-security", str(root) + "/") == "http://sec.invalid/debian-security"
    for absent in ("trixie", "sid"):  # disabled file, Enabled: no
        with pytest.raises(LookupError, match=absent):
            debian_mirror.mirror_for(absent, str(root) + "/")
    with pytest.raises(ValueError, match="suite"):
        debian_mirror.mirror_for("../etc", str(root) + "/")


def test_debian_mirror_one_line_format(tmp_path):
    root = _apt_root(tmp_path, {"sources.list": "deb [trusted=yes] http://a.invalid/debian/ bookworm main non-free\n"})
    assert debian_mirror.mirror_for("bookworm", str(root) + "/") == "http://a.invalid/debian"


def test_healthcheck_finds_soilocp_in_command_lines():
    assert healthcheck.soilocp_args(["/opt/soilocp/bin/python3", "/opt/soilocp/bin/soilocp", "service", "ocp"]) == \
        ["service", "ocp"]
    assert healthcheck.soilocp_args(["/sbin/docker-init", "--", "soilocp", "router", "--listen", "tcp/0.0.0.0:7447"]) \
        == ["router", "--listen", "tcp/0.0.0.0:7447"]
    assert healthcheck.soilocp_args(["python", "-m", "soilocp.cli", "service", "gateway"]) == ["service", "gateway"]
    assert healthcheck.soilocp_args(["python", "/usr/local/bin/soilocp-healthcheck"]) is None
    assert healthcheck.soilocp_args(["soilocp", "run", "--synthetic", "sand"]) is None


def test_healthcheck_settings_match_the_services_loaders(tmp_path):
    """The health check's pydantic-free fast path resolves settings exactly as the services do."""
    from soilocp.schemas import keys
    from soilocp.services.router import router_settings
    from soilocp.services.runtime.config import DEFAULT_ENDPOINT, load_service_config

    assert healthcheck.DEFAULT_ENDPOINT == DEFAULT_ENDPOINT
    assert healthcheck.alive_key("rover9", "soil-strength") == keys.alive("rover9", "soil-strength")
    cases = [
        (["service", "ocp"], {}),
        (["service", "ocp"], {"SOILOCP_VEHICLE_ID": "r2,r3", "SOILOCP_CONNECT": "tcp/a:1, tcp/b:2"}),
        (["service", "gateway", "--vehicle-id", "x1", "--connect=tcp/c:3"], {"SOILOCP_VEHICLE_ID": "r2"}),
    ]
    for args, env in cases:
        got = healthcheck.settings_of(args, env)
        opts = healthcheck._options(args[1:])
        cfg = load_service_config(args[1], overrides={"vehicle_ids": opts.get("vehicle-id"),
                                                      "connect": opts.get("connect")}, env=env)
        assert got == {"vehicle_ids": cfg.vehicle_ids, "connect": cfg.connect}, (args, env)
    for args, env in [(["router"], {}), (["router"], {"SOILOCP_LISTEN": "tcp/0.0.0.0:9"}),
                      (["router", "--listen", "tcp/1.2.3.4:5"], {"SOILOCP_LISTEN": "tcp/0.0.0.0:9"})]:
        listen = healthcheck._options(args[1:]).get("listen", ())
        assert healthcheck.settings_of(args, env)["listen"] == router_settings(None, tuple(listen), (), env=env)["listen"]
    # with a config file the services' own loaders are used
    conf = tmp_path / "unit.json"
    conf.write_text(json.dumps({"vehicle_id": "unit7", "connect": ["tcp/u:7"], "router": {"listen": ["tcp/0.0.0.0:8"]}}))
    assert healthcheck.settings_of(["service", "observer", "--config", str(conf)], {}) == \
        {"vehicle_ids": ["unit7"], "connect": ["tcp/u:7"]}
    assert healthcheck.settings_of(["router"], {"SOILOCP_CONFIG": str(conf)}) == {"listen": ["tcp/0.0.0.0:8"]}
