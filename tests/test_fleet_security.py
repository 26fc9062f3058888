"""The secure fleet with real processes: a fleet router started from
deploy/fleet/fleet-router-secure.json (mutual TLS + access control), certificates made by
`soilocp certs init`, and Zenoh client sessions holding one certificate each.

What must hold (issue: fleet links that keep strangers out):
* a client without a certificate, with a certificate of another CA, or on plain TCP is refused;
  a certificate of the fleet CA naming nobody in the access control connects but can do nothing;
* a vehicle cannot publish (or answer queries) under another vehicle's keys, nor read them;
* a dashboard certificate cannot publish, answer queries or hold liveliness tokens;
* a real vehicle (`soilocp run`, its router linked over TLS with its certificate) reaches the real
  dashboard and `soilocp fleet status`, both connected with the dashboard certificate;
* the native file deploy/zenoh/fleet-router-secure.json5 (for zenohd) enforces the same rules.

Negative checks wait for a positive control sent after the forbidden message on the same path
(it must arrive), then a grace period: "not received" is never a bare timeout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import pytest
from zenoh_helpers import Procs, free_port, wait_for

from soilocp.services.security.fleet_security import TlsFiles, apply_tls

ROOT = Path(__file__).resolve().parents[1]
FLEET_SECURE = ROOT / "deploy" / "fleet" / "fleet-router-secure.json"
NATIVE_SECURE = ROOT / "deploy" / "zenoh" / "fleet-router-secure.json5"
SOILOCP = [sys.executable, "-m", "soilocp.cli"]
GRACE_S = 1.0


def _certs(directory: Path, *args: str) -> None:
    res = subprocess.run([*SOILOCP, "certs", *args], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


class SecureFleet:
    def __init__(self, base: Path):
        self.certs = base / "certs"
        self.other = base / "other-ca"  # a second CA: same names, not the fleet's
        _certs(self.certs, "init", str(self.certs), "--vehicle", "rover1", "--vehicle", "rover2")
        _certs(self.certs, "issue", str(self.certs), "intruder")  # the fleet's CA, but named nowhere
        _certs(self.other, "init", str(self.other), "--vehicle", "rover1")
        self.port = free_port()
        self.ep = f"tls/127.0.0.1:{self.port}"
        self.procs = Procs(base / "logs")

    def tls(self, name: str, ca_dir: Path | None = None) -> TlsFiles:
        d = ca_dir or self.certs
        return TlsFiles(str(self.certs / "ca.pem"), str(d / f"{name}.pem"), str(d / f"{name}.key"))

    def env(self, name: str) -> dict[str, str]:
        t = self.tls(name)
        return {"SOILOCP_TLS_CA": t.ca, "SOILOCP_TLS_CERT": t.cert, "SOILOCP_TLS_KEY": t.key}

    def config(self, tls: TlsFiles | None, ep: str | None = None, timeout_ms: int = 3000):
        import zenoh

        c = zenoh.Config()
        c.insert_json5("mode", '"client"')
        c.insert_json5("connect/endpoints", json.dumps([ep or self.ep]))
        c.insert_json5("connect/timeout_ms", str(timeout_ms))
        c.insert_json5("scouting/multicast/enabled", "false")
        if tls is not None:
            apply_tls(c, tls, listener=False)
        else:  # trusts the fleet router, shows no certificate of its own
            c.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(self.certs / "ca.pem")))
        return c

    @contextmanager
    def session(self, name: str):
        import zenoh

        s = zenoh.open(self.config(self.tls(name), timeout_ms=20000))
        try:
            yield s
        finally:
            s.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    f = SecureFleet(tmp_path_factory.mktemp("secure-fleet"))
    try:
        f.procs.spawn("fleet-router", ["router", "--config", str(FLEET_SECURE)],
                      env={"SOILOCP_LISTEN": f.ep, **f.env("fleet-router")})
        assert wait_for(lambda: '"event": "running"' in f.procs.log_text("fleet-router")
                        or f.procs.procs["fleet-router"].poll() is not None, 60), "fleet router did not start"
        assert f.procs.procs["fleet-router"].poll() is None, f.procs.log_text("fleet-router")
        yield f
    finally:
        codes = f.procs.close(timeout=20.0)
        assert codes.get("fleet-router") == 0, (codes, f.procs.log_text("fleet-router"))


class Inbox:
    """Samples received by one subscriber, thread-safe."""

    def __init__(self):
        self._lock = threading.Lock()
        self.items: list[tuple[str, bytes]] = []

    def __call__(self, sample) -> None:
        with self._lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def payloads(self) -> set[bytes]:
        with self._lock:
            return {p for _, p in self.items}


def _wait_received(inbox: Inbox, payload: bytes, timeout: float = 20.0) -> None:
    assert wait_for(lambda: payload in inbox.payloads(), timeout), f"positive control {payload!r} never arrived"
    time.sleep(GRACE_S)


def _replies(session, selector: str) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(selector, timeout=2.0) if r.ok is not None]


def _check_refusals(fleet, *, with_cli: bool) -> None:
    import zenoh

    refused = {
        "no client certificate": fleet.config(None),
        "certificate of another CA (CN rover1)": fleet.config(fleet.tls("rover1", ca_dir=fleet.other)),
        "plain TCP on the TLS port": fleet.config(None, ep=f"tcp/127.0.0.1:{fleet.port}"),
    }
    for case, conf in refused.items():
        with pytest.raises(zenoh.ZError):
            s = zenoh.open(conf)
            s.close()
            pytest.fail(f"{case}: the fleet router accepted the session")
        print(f"refused: {case}")
    # the same client code with a certificate of the fleet CA is let in (the control)
    zenoh.open(fleet.config(fleet.tls("dashboard"))).close()

    if not with_cli:
        return
    # the fleet CLI says why, without a certificate and with a foreign one
    e = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    res = subprocess.run([*SOILOCP, "fleet", "status", "--connect", fleet.ep], env=e, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "SOILOCP_TLS_CERT" in res.stderr, res.stderr
    other = fleet.tls("rover1", ca_dir=fleet.other)
    res = subprocess.run([*SOILOCP, "fleet", "status", "--connect", fleet.ep, "--timeout", "3"], capture_output=True,
                         text=True, timeout=60, env={**e, "SOILOCP_TLS_CA": other.ca, "SOILOCP_TLS_CERT": other.cert,
                                                     "SOILOCP_TLS_KEY": other.key})
    assert res.returncode == 1 and "no router answered" in res.stdout + res.stderr, res


def _check_vehicle_confined(fleet) -> None:
    inbox, rover2_inbox = Inbox(), Inbox()
    with fleet.session("dashboard") as dash, fleet.session("rover1") as r1, fleet.session("rover2") as r2:
        dash.declare_subscriber("soilocp/**", inbox)
        r2.declare_subscriber("soilocp/rover1/**", rover2_inbox)  # reading another vehicle's data
        r1.declare_queryable("soilocp/rover2/ocp", lambda q: q.reply("soilocp/rover2/ocp", b"rover1-answers-rover2"))
        time.sleep(1.0)  # declarations reach the router
        r1.put("soilocp/rover2/ocp", b"rover1-as-rover2")
        r1.put("soilocp/rover2/raw", b"rover1-raw-as-rover2")
        r1.put("soilocp/rover1/ocp", b"rover1-own")
        r2.put("soilocp/rover2/ocp", b"rover2-own")
        _wait_received(inbox, b"rover1-own")
        _wait_received(inbox, b"rover2-own")
        got = inbox.payloads()
        assert b"rover1-as-rover2" not in got and b"rover1-raw-as-rover2" not in got, got
        assert b"rover1-answers-rover2" not in _replies(dash, "soilocp/rover2/ocp")
        assert rover2_inbox.payloads() == set(), "rover2 received rover1's data through the fleet router"
        print(f"dashboard received {sorted(got)}; rover2 saw none of rover1's data")


def _check_tools_read_only(fleet) -> None:
    inbox = Inbox()
    with fleet.session("dashboard") as dash, fleet.session("dashboard") as watcher, \
            fleet.session("rover1") as r1, fleet.session("intruder") as intruder:
        watcher.declare_subscriber("soilocp/**", inbox)
        intruder_inbox = Inbox()
        intruder.declare_subscriber("soilocp/**", intruder_inbox)
        dash.declare_queryable("soilocp/rover1/ocp", lambda q: q.reply("soilocp/rover1/ocp", b"dashboard-answers"))
        token = dash.liveliness().declare_token("soilocp/rover1/alive/ocp")
        time.sleep(1.0)
        dash.put("soilocp/rover1/ocp", b"dashboard-put")
        dash.delete("soilocp/rover1/ocp")
        intruder.put("soilocp/rover1/ocp", b"intruder-put")
        r1.put("soilocp/rover1/ocp", b"rover1-control")
        _wait_received(inbox, b"rover1-control")
        got = inbox.payloads()
        assert b"dashboard-put" not in got and b"intruder-put" not in got, got
        assert len(inbox.items) == 1, f"more than the control reached the watcher: {inbox.items}"
        assert b"dashboard-answers" not in _replies(watcher, "soilocp/rover1/ocp")
        tokens = [str(r.ok.key_expr) for r in watcher.liveliness().get("soilocp/**", timeout=2.0) if r.ok is not None]
        assert tokens == [], f"tokens visible at the fleet: {tokens}"
        # (its own put is delivered to it locally, inside its session: that never crossed the router)
        assert b"rover1-control" not in intruder_inbox.payloads(), "a certificate named in no policy read fleet data"
        token.undeclare()


def test_clients_without_a_fleet_certificate_are_refused(fleet):
    _check_refusals(fleet, with_cli=True)


def test_vehicle_cannot_publish_or_answer_under_another_vehicles_keys(fleet):
    _check_vehicle_confined(fleet)


def test_dashboard_certificate_cannot_publish_answer_or_hold_tokens(fleet):
    _check_tools_read_only(fleet)


@pytest.fixture(scope="module")
def native_fleet(tmp_path_factory):
    """deploy/zenoh/fleet-router-secure.json5 as it is, run by a plain Zenoh router session (what
    `zenohd -c` does), with only the certificate directory and the port rewritten."""
    base = tmp_path_factory.mktemp("native-fleet")
    f = SecureFleet(base)
    text = NATIVE_SECURE.read_text().replace("/etc/soilocp/certs", str(f.certs))
    text = text.replace('"tls/0.0.0.0:7447"', json.dumps(f.ep))
    conf = base / "fleet-router.json5"
    conf.write_text(text)
    log = open(base / "router.log", "wb")
    proc = subprocess.Popen([sys.executable, "-c", NATIVE_ROUTER, str(conf)], stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL)
    log.close()
    try:
        assert wait_for(lambda: b"running" in (base / "router.log").read_bytes() or proc.poll() is not None, 60)
        assert proc.poll() is None, (base / "router.log").read_text()
        yield f
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


#: a Zenoh router from a native configuration file until SIGTERM (zenohd's job, in Python)
NATIVE_ROUTER = """
import os, signal, sys, threading, zenoh
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
s = zenoh.open(zenoh.Config.from_file(sys.argv[1]))
print("running", flush=True)
stop.wait()
s.close()
os._exit(0)
"""


def test_native_json5_fleet_router_enforces_the_same_rules(native_fleet):
    import zenoh

    from soilocp.services.security.fleet_security import apply_fleet_link_qos, fleet_access_control

    # the file's access control is the one `soilocp router` builds (both read back through Zenoh)
    built = zenoh.Config()
    built.insert_json5("access_control", json.dumps(fleet_access_control(["rover1", "rover2"], ["dashboard"])))
    native = zenoh.Config.from_file(str(NATIVE_SECURE))
    assert json.loads(native.get_json("access_control")) == json.loads(built.get_json("access_control"))
    # and both native secure routers carry the "fleet links never block" rule `soilocp router` sets
    apply_fleet_link_qos(built)
    for name in ("fleet-router-secure.json5", "vehicle-router-secure.json5"):
        native = zenoh.Config.from_file(str(NATIVE_SECURE.parent / name))
        assert json.loads(native.get_json("qos/network")) == json.loads(built.get_json("qos/network")), name
    _check_refusals(native_fleet, with_cli=False)
    _check_vehicle_confined(native_fleet)
    _check_tools_read_only(native_fleet)


def _api(port: int, path: str):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
        return json.loads(r.read())


def test_vehicle_ocps_reach_dashboard_and_fleet_cli_over_tls(fleet, tmp_path):
    dash_port = free_port()
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("rover1", ["run", "--synthetic", "sand", "--vehicle-id", "rover1", "--duration", "300", "--plain",
                               "--stale-timeout", "3", "--listen", f"tcp/127.0.0.1:{free_port()}",
                               "--log-dir", str(tmp_path / "rover1")],
                    env={"SOILOCP_ROUTER_CONNECT": fleet.ep, "PYTHONUNBUFFERED": "1", **fleet.env("rover1")})
        procs.spawn("dashboard", ["dashboard", "--port", str(dash_port), "--connect", fleet.ep],
                    env=fleet.env("dashboard"))

        def fresh_row():
            try:
                rows = _api(dash_port, "/api/vehicles")["vehicles"]
            except OSError:
                return None
            return next((r for r in rows if r["vehicle_id"] == "rover1" and r["status"] == "fresh"
                         and r["K"] is not None and r["state"] == "online"), None)

        row = wait_for(fresh_row, 180, interval=1.0)
        assert row, "rover1 never fresh on the dashboard:\n" + procs.log_text("dashboard")[-2000:] + \
            procs.log_text("rover1")[-2000:]
        assert row["soil_class"] == "sand" and row["rejections"] == 0, row
        e = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
        res = subprocess.run([*SOILOCP, "fleet", "status", "--connect", fleet.ep, "--json", "--timeout", "5"],
                             capture_output=True, text=True, timeout=60, env={**e, **fleet.env("dashboard")})
        assert res.returncode == 0, res.stderr
        rows = {r["vehicle_id"]: r for r in json.loads(res.stdout)["vehicles"]}
        assert rows["rover1"]["status"] == "fresh" and rows["rover1"]["services_missing"] == [], rows
        print(f"rover1 over TLS: dashboard K={row['K']:.1f} ({row['soil_class']}), fleet status "
              f"{rows['rover1']['status']}, {len(rows['rover1']['services_alive'])}/5 services")
    finally:
        codes = procs.close(timeout=20.0)
    # `soilocp run` says 143 when SIGTERM stopped everything cleanly (1 if a child failed)
    assert codes == {"rover1": 143, "dashboard": 0}, (codes, procs.log_text("rover1")[-1500:])


def test_forged_samples_of_another_vehicle_never_reach_its_gateway(fleet, tmp_path):
    """rover1 as deployed: its router links to the secure fleet router with rover1's certificate, its
    gateway and its sensor driver are plain clients of that router.  On the fleet router, rover2 (a
    fleet certificate of another vehicle) and the intruder (the fleet's CA, named in no policy) publish
    valid samples of rover1 on rover1's raw key, ahead of rover1's own.  The fleet router refuses them:
    the gateway's clean output is exactly rover1's samples in order (a forged one let in would be
    accepted, being ahead, and refuse every later sample of rover1), and its health counts no rejection
    and no second source.  rover1's samples sent after the forged ones are the control."""
    import zenoh

    from soilocp.services.bench.stages import simulate_drive
    from zenoh_helpers import client, endpoint

    drive = simulate_drive("rover1", 1.0)
    own = [s.model_dump_json().encode() for s in drive[:60]]
    forged = [s.model_copy(update={"seq": s.seq + 10_000, "stamp": s.stamp + 100.0}).model_dump_json().encode()
              for s in drive[:60]]
    vep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    clean = Inbox()
    try:
        procs.spawn("rover1-router", ["router", "--listen", vep],
                    env={"SOILOCP_ROUTER_CONNECT": fleet.ep, **fleet.env("rover1")})
        procs.spawn("gateway", ["service", "gateway", "--vehicle-id", "rover1", "--connect", vep])
        with client(vep) as driver, fleet.session("dashboard") as dash, fleet.session("rover2") as r2, \
                fleet.session("intruder") as intruder:
            driver.declare_subscriber("soilocp/rover1/sensors/clean", clean)
            # the vehicle is on the fleet (its gateway's token seen through the fleet router)
            assert wait_for(lambda: [r for r in dash.liveliness().get("soilocp/rover1/alive/gateway", timeout=1.0)
                                     if r.ok is not None], 60), procs.log_text("rover1-router")[-2000:]
            time.sleep(1.0)
            pubs = {name: s.declare_publisher("soilocp/rover1/sensors/raw",
                                              congestion_control=zenoh.CongestionControl.BLOCK)
                    for name, s in (("rover1", driver), ("rover2", r2), ("intruder", intruder))}
            for k in range(40):
                pubs["rover1"].put(own[k])
                pubs["rover2"].put(forged[k])
                pubs["intruder"].put(forged[k])
                time.sleep(0.01)
            for k in range(40, 60):  # the control: rover1's own samples after the forged ones
                pubs["rover1"].put(own[k])
                time.sleep(0.01)
            assert wait_for(lambda: len(clean.items) >= 60, 30), (len(clean.items), procs.tail("gateway"))
            time.sleep(GRACE_S)
            (health,) = [json.loads(p) for p in _replies(driver, "soilocp/rover1/status/gateway")]
        seqs = [json.loads(p)["seq"] for _k, p in clean.items]
        assert seqs == [s.seq for s in drive[:60]], seqs
        assert health["received"] == 60 and health["rejected"] == 0, health
        assert health["detail"].get("source_conflicts", 0) == 0, health
        print(f"rover1's gateway: {health['received']} received, {health['rejected']} rejected; the 80 forged "
              "samples (rover2, intruder) refused by the fleet router")
    finally:
        procs.close(timeout=20.0)


def test_security_settings_fail_with_a_clear_message(tmp_path):
    from soilocp.services.router import router_settings
    from soilocp.services.runtime.config import ConfigError

    certs = tmp_path / "certs"
    _certs(certs, "init", str(certs), "--vehicle", "rover1")
    tls = {"SOILOCP_TLS_CA": str(certs / "ca.pem"), "SOILOCP_TLS_CERT": str(certs / "fleet-router.pem"),
           "SOILOCP_TLS_KEY": str(certs / "fleet-router.key")}
    cases = {
        "use TLS but no certificate": ({}, ("tls/0.0.0.0:7447",)),
        "SOILOCP_TLS_KEY not set": ({k: v for k, v in tls.items() if k != "SOILOCP_TLS_KEY"}, ("tls/0.0.0.0:7447",)),
        "no such file": ({**tls, "SOILOCP_TLS_CA": str(certs / "missing.pem")}, ("tls/0.0.0.0:7447",)),
        "without tls/": ({**tls, "SOILOCP_FLEET_VEHICLES": "rover1"}, ("tcp/0.0.0.0:7447",)),
        "is invalid": ({**tls, "SOILOCP_FLEET_VEHICLES": "rover1,a/b"}, ("tls/0.0.0.0:7447",)),
        "both as vehicle and as fleet tool": ({**tls, "SOILOCP_FLEET_VEHICLES": "dashboard"}, ("tls/0.0.0.0:7447",)),
    }
    for needle, (env, listen) in cases.items():
        with pytest.raises(ConfigError, match=needle):
            router_settings(None, listen, (), env=env)
    ok = router_settings(str(FLEET_SECURE), (), (), env=tls)
    assert ok["access_control"] == {"vehicles": ["rover1", "rover2"], "tools": ["dashboard"]}
    # certs: an existing CA is never replaced by accident; a vehicle may not take a tool's name
    res = subprocess.run([*SOILOCP, "certs", "init", str(certs), "--vehicle", "rover1"], capture_output=True, text=True)
    assert res.returncode == 2 and "ca.key exists" in res.stderr
    res = subprocess.run([*SOILOCP, "certs", "init", str(tmp_path / "x"), "--vehicle", "dashboard"], capture_output=True,
                         text=True)
    assert res.returncode == 2 and "could not tell them apart" in res.stderr
