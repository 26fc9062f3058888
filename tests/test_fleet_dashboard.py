"""Fleet view: ``soilocp fleet status`` and the dashboard, against a real fleet.

A fleet router, two vehicles each run by ``soilocp run`` (its own router linked to the fleet
router, five services, a synthetic vehicle), the dashboard server, and headless Chromium driven
over the DevTools protocol on a pipe (``--remote-debugging-pipe``: no websocket client needed).
Loopback only, ephemeral ports, multicast off; every process is reaped.  Plus fast unit tests of
:class:`soilocp.services.fleet.state.FleetState` with a fake clock.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pytest

from soilocp.schemas import keys
from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.schemas.messages import OcpReply, ServiceHealth
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.services.fleet.state import FleetState, traction_curve
from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.model.traction import net_traction

from zenoh_helpers import Procs, client, endpoint, free_port, get_payloads, wait_for

VEHICLES = {"alpha": "mixed", "beta": "sandy-slope"}
SOILS = set(DEFAULT_CONSTANTS.soils)

pytestmark = pytest.mark.timeout(240)


# ------------------------------------------------------------------------------------------------
# unit tests: FleetState (no Zenoh)
# ------------------------------------------------------------------------------------------------
class Clock:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


def _est(vid: str, seq: int, k: Optional[float] = 120.0, status: str = "ok") -> OcpEstimate:
    return OcpEstimate(vehicle_id=vid, seq=seq, stamp=seq * 0.01, soil_strength=k, soil_strength_std=10.0,
                       soil_class="EST", soil_class_confidence=0.9, mu_T=0.8, S_T=0.4, S_E=0.1, status=status,
                       mu=(0.1, 0.2, 0.3, 0.4), slip=(0.05, 0.1, 0.15, 0.2))


def test_state_fresh_stale_offline_and_rejections_from_gateway_health():
    clock = Clock()
    st = FleetState(clock=clock)
    for s in PIPELINE_SERVICES:
        st.set_alive("rover1", s, True)
    (row,) = st.rows()
    assert (row["state"], row["status"], row["K"]) == ("online", "no estimate", None)
    st.add_estimate(_est("rover1", 1))
    clock.t += 0.3
    (row,) = st.rows()
    assert row["status"] == "fresh" and row["age_s"] == pytest.approx(0.3) and row["K"] == 120.0
    clock.t += 0.3  # 0.6 s > default stale timeout 0.5 s
    assert st.rows()[0]["status"] == "stale"
    st.set_alive("rover1", "observer", False)
    row = st.rows()[0]
    assert row["state"] == "degraded" and row["services_missing"] == ["observer"]
    for s in PIPELINE_SERVICES:
        st.set_alive("rover1", s, False)
    row = st.rows()[0]
    assert row["state"] == "offline" and row["offline_since"] == clock.t
    st.add_rejection("rover1")
    assert st.rows()[0]["rejections"] == 1
    h = ServiceHealth(service="gateway", vehicle_id="rover1", pid=1, host="h", state="running", uptime_s=1,
                      received=10, published=3, rejected=7, dropped=0, errors=0, queue_depth=0, time=clock.t)
    st.set_health(h)
    assert st.rows()[0]["rejections"] == 7  # the gateway's own count includes rejections before we listened


def test_state_restarts_from_the_supervisor_and_a_second_source_from_the_gateway():
    """The supervisor's report: per process restarted (or died) its count, and its last restart's age
    as of now (the report's age plus the time since it arrived); an older report of the same
    supervisor does not replace a newer one.  The gateway's source_conflicts flag a second source."""
    from soilocp.schemas.messages import SupervisedProcess, SupervisorStatus
    from soilocp.services.fleet.commands import restarts_text

    clock = Clock()
    st = FleetState(clock=clock)
    st.set_alive("rover1", "gateway", True)
    (row,) = st.rows()
    assert row["restarts_total"] is None and row["restarts"] is None and restarts_text(row) == "-"
    assert row["second_source"] is False and row["source_conflicts"] == 0

    def report(t, ocp_restarts, age):
        return SupervisorStatus(vehicle_id="rover1", pid=7, host="h", restart=True, time=t, processes=[
            SupervisedProcess(name="router", pid=10, state="running", restarts=0),
            SupervisedProcess(name="ocp", pid=11, state="running", restarts=ocp_restarts, last_restart_age_s=age,
                              last_exit=-9),
            SupervisedProcess(name="observer", pid=12, state="died", restarts=0, last_exit=1)])

    st.set_supervisor(report(clock.t, 2, 1.5))
    clock.t += 3.0
    st.set_supervisor(report(clock.t - 10.0, 1, 0.5))  # older: ignored
    (row,) = st.rows()
    assert row["restarts_total"] == 2 and set(row["restarts"]) == {"ocp", "observer"}, row
    assert row["restarts"]["ocp"] == {"restarts": 2, "state": "running", "pid": 11, "last_exit": -9,
                                      "last_restart_age_s": pytest.approx(4.5)}
    assert restarts_text(row) == "2, ocp 4.5 s ago, died: observer"
    h = ServiceHealth(service="gateway", vehicle_id="rover1", pid=1, host="h", state="running", uptime_s=1,
                      received=10, published=3, rejected=7, dropped=0, errors=0, queue_depth=0, time=clock.t,
                      detail={"rejected_old_seq": 7, "source_conflicts": 6})
    st.set_health(h)
    (row,) = st.rows()
    assert row["second_source"] is True and row["source_conflicts"] == 6


def test_state_restarts_seen_in_health_whoever_restarts_the_process():
    """Without a supervisor (systemd, Docker: in a container the pid stays 1), a service's health from a
    process that started later than the one before is a restart; the old process's late report is not,
    nor is the same process's next report."""
    from soilocp.services.fleet.commands import restarts_text

    clock = Clock()
    st = FleetState(clock=clock)

    def health(service, pid, start, t):
        return ServiceHealth(service=service, vehicle_id="rover1", pid=pid, host="c1", state="running",
                             uptime_s=t - start, received=1, published=1, rejected=0, dropped=0, errors=0,
                             queue_depth=0, time=t)

    st.set_health(health("observer", 1, 100.0, 150.0))
    st.set_health(health("observer", 1, 100.0, 151.0))
    st.set_health(health("ocp", 1, 100.0, 151.0))
    (row,) = st.rows()
    assert row["restarts_seen_total"] == 0 and row["restarts_seen"] == {} and restarts_text(row) == "-"
    st.set_health(health("observer", 1, 160.0, 160.5))  # pid 1 again: a container restarted by Docker
    st.set_health(health("observer", 1, 100.0, 159.0))  # the old process's report, delivered late
    st.set_health(health("observer", 1, 160.2, 161.5))  # the new one's next report (its clock jittered)
    clock.t += 2.0
    (row,) = st.rows()
    assert row["restarts_seen_total"] == 1, row["restarts_seen"]
    assert row["restarts_seen"]["observer"] == {"restarts": 1, "pid": 1, "host": "c1",
                                                "last_restart_age_s": pytest.approx(2.5)}
    assert restarts_text(row) == "1 seen, observer 2.5 s ago"
    st.set_health(health("ocp", 4242, 170.0, 170.2))  # another pid, as systemd restarts it
    assert st.rows()[0]["restarts_seen_total"] == 2
    # a one-shot status sees no restart happen, but the uptimes: the youngest service, if much younger
    once = FleetState(clock=clock)
    once.set_health(health("observer", 1, 100.0, 200.0))
    once.set_health(health("ocp", 1, 190.0, 200.0))
    clock.t += 1.0
    (row,) = once.rows()
    assert row["uptime_s"] == {"observer": pytest.approx(101.0), "ocp": pytest.approx(11.0)}
    assert restarts_text(row) == "ocp up 11.0 s"


def test_state_reconcile_removes_a_service_only_after_consecutive_misses():
    st = FleetState(clock=Clock())
    st.reconcile_alive([("v1", s) for s in PIPELINE_SERVICES], misses=2)
    assert st.rows()[0]["state"] == "online"
    without_ocp = [("v1", s) for s in PIPELINE_SERVICES if s != "ocp"]
    st.reconcile_alive(without_ocp, misses=2)
    assert st.rows()[0]["state"] == "online"  # one miss: could be a get racing a new token
    st.reconcile_alive(without_ocp, misses=2)
    assert st.rows()[0]["services_missing"] == ["ocp"]


def test_state_reply_age_backfill_and_incremental_history():
    clock = Clock()
    st = FleetState(clock=clock, history_period_s=0.2)
    hist = [_est("v1", i, k=50.0 + i) for i in range(0, 301)]  # 3 s of samples at 100 Hz
    reply = OcpReply(vehicle_id="v1", stale=False, age_s=0.1, stale_timeout_s=0.5, latest=hist[-1], history=hist,
                     history_capacity=1000)
    st.add_reply(reply)
    d = st.detail("v1")
    row = st.rows()[0]
    assert row["age_s"] == pytest.approx(0.1) and row["status"] == "fresh" and row["seq"] == 300
    ts = [p["t"] for p in d["history"]]
    assert ts == sorted(ts) and len(ts) == 16  # 3 s at one point per 0.2 s, plus the latest
    assert ts[-1] == pytest.approx(clock.t - 0.1)  # the latest was produced age_s ago
    assert ts[0] == pytest.approx(clock.t - 0.1 - 3.0)
    epoch, last = d["history_epoch"], d["history"][-1]["id"]
    clock.t += 0.5
    st.add_estimate(_est("v1", 350, k=99.0))
    inc = st.detail("v1", after_id=last, epoch=epoch)
    assert not inc["history_full"] and [p["K"] for p in inc["history"]] == [99.0]
    assert st.detail("v1", after_id=last, epoch=epoch + 1)["history_full"]  # other epoch: everything again
    assert inc["wheels"][3] == {"wheel": "RR", "slip": 0.2, "mu": 0.4}
    assert st.detail("nobody") is None


def test_traction_curve_is_the_library_eq6_at_k_and_k_pm_std():
    c = traction_curve(120.0, 30.0, [0.05, 1.4, -0.3])
    slip = np.array(c["slip"])
    assert slip[0] == pytest.approx(-0.3) and slip[-1] == pytest.approx(1.0)  # widened to the wheels, capped at 1
    np.testing.assert_allclose(c["mu"], net_traction(slip, 120.0), atol=2e-4)  # values rounded to 5 decimals for the wire
    np.testing.assert_allclose(c["mu_lo"], net_traction(slip, 90.0), atol=2e-4)  # values rounded to 5 decimals for the wire
    np.testing.assert_allclose(c["mu_hi"], net_traction(slip, 150.0), atol=2e-4)  # values rounded to 5 decimals for the wire
    assert traction_curve(300.0, 1e4)["K_lo"] == pytest.approx(30.0)  # K - std floored at K/10
    assert traction_curve(None, None) is None
    with pytest.raises(ValueError, match="history_period_s"):
        FleetState(history_period_s=0)


# ------------------------------------------------------------------------------------------------
# the real fleet
# ------------------------------------------------------------------------------------------------
class Fleet:
    def __init__(self, procs: Procs, router_ep: str, empty_ep: str, dash_url: str, browser: Optional["Chromium"]):
        self.procs = procs
        self.router = router_ep
        self.empty_router = empty_ep  # a router with no vehicle behind it
        self.url = dash_url
        self.browser = browser  # started with the fleet: its start-up overlaps the vehicles'


def _fresh_vehicles(ep: str) -> set[str]:
    out = set()
    with client(ep) as s:
        for b in get_payloads(s, keys.any_vehicle_ocp(), timeout=2.0):
            rep = OcpReply.model_validate_json(b)
            if not rep.stale and rep.latest is not None and rep.latest.soil_strength is not None:
                out.add(rep.vehicle_id)
    return out


def _http_json(url: str, timeout: float = 5.0) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Fleet router + two vehicles (``soilocp run`` each, router linked to the fleet router) +
    dashboard.  Torn down with SIGTERM (the runs stop their own children), SIGKILL after 20 s."""
    base = tmp_path_factory.mktemp("fleet")
    procs = Procs(base / "logs")
    fleet_ep = endpoint(free_port())
    dash_port = free_port()
    browser = None
    try:
        if _chromium() is not None:
            browser = Chromium(_chromium())
        procs.spawn("router", ["router", "--listen", fleet_ep])
        empty_ep = endpoint(free_port())
        procs.spawn("empty-router", ["router", "--listen", empty_ep])
        for vid, scenario in VEHICLES.items():
            procs.spawn(vid, ["run", "--synthetic", scenario, "--vehicle-id", vid, "--duration", "600", "--plain",
                              # a loaded 2-core CI machine can pause a service for a while: do not
                              # call that stale (the stale path is tested by stopping a vehicle)
                              "--stale-timeout", "3",
                              "--listen", endpoint(free_port()), "--log-dir", str(base / vid)],
                        env={"SOILOCP_ROUTER_CONNECT": fleet_ep, "PYTHONUNBUFFERED": "1"})
        procs.spawn("dashboard", ["dashboard", "--port", str(dash_port), "--connect", fleet_ep])
        ok = wait_for(lambda: set(VEHICLES) <= _fresh_vehicles(fleet_ep), timeout=120, interval=1.0)
        assert ok, "vehicles never produced fresh OCPs:\n" + "\n".join(
            procs.log_text(v)[-2000:] for v in VEHICLES)
        yield Fleet(procs, fleet_ep, empty_ep, f"http://127.0.0.1:{dash_port}", browser)
    finally:
        if browser is not None:
            browser.close()
        codes = procs.close(timeout=20.0)
    dash_log = procs.log_text("dashboard")
    assert codes.get("dashboard") == 0, (codes, dash_log)
    assert "Traceback" not in dash_log, dash_log
    assert '"event": "stopped"' in dash_log  # lifespan closed the Zenoh session


def _fleet_start(*args: str) -> subprocess.Popen:
    e = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    return subprocess.Popen([sys.executable, "-m", "soilocp.cli", "fleet", "status", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=e, stdin=subprocess.DEVNULL)


def _finish(p: subprocess.Popen, timeout: float = 60.0) -> subprocess.CompletedProcess:
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def _fleet_cmd(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return _finish(_fleet_start(*args), timeout)


def _check_row(r: dict[str, Any]) -> None:
    assert r["services_alive"] == list(PIPELINE_SERVICES) and r["services_missing"] == []
    assert r["state"] == "online" and r["source_alive"] is True
    assert r["status"] == "fresh" and r["age_s"] < 5.0
    assert math.isfinite(r["K"]) and r["K"] > 0 and r["K_std"] >= 0
    assert r["soil_class"] in SOILS and 0 <= r["soil_class_confidence"] <= 1
    assert 0 < r["mu_T"] < 2 and 0 < r["S_T"] < 1 and r["S_E"] is not None
    assert r["rejections"] == 0


def test_fleet_status_json_table_and_no_answer(fleet):
    # the commands run in parallel: each is a Python start-up on a small machine.  A router with
    # no vehicle behind it, and no router at all: exit status 1 within the timeout.
    # Generous timeouts where a router exists: they bound the wait, they do not delay the answer,
    # and a loaded machine can take seconds to open a session.
    runs = {"json": _fleet_start("--connect", fleet.router, "--json", "--timeout", "10"),
            "table": _fleet_start("--connect", fleet.router, "--timeout", "10"),
            "empty": _fleet_start("--connect", fleet.empty_router, "--timeout", "5", "--json"),
            "no-router": _fleet_start("--connect", endpoint(free_port()), "--timeout", "1")}
    watch = _fleet_start("--connect", fleet.router, "--watch", "--json", "--timeout", "10")
    res = {name: _finish(p) for name, p in runs.items()}
    # --watch: one JSON object per refresh until SIGINT, then a clean exit 0
    lines = []
    try:
        for line in watch.stdout:
            lines.append(json.loads(line))
            if len(lines) == 3:
                break
        watch.send_signal(signal.SIGINT)
        out, err = watch.communicate(timeout=30)
    finally:
        if watch.poll() is None:
            watch.kill()
            watch.wait()
    assert len(lines) == 3 and watch.returncode == 0, (lines, err)
    assert lines[0]["time"] < lines[1]["time"] < lines[2]["time"]
    assert all({v["vehicle_id"] for v in doc["vehicles"]} == set(VEHICLES) for doc in lines)

    r = res["json"]
    assert r.returncode == 0, (r.stdout, r.stderr)
    doc = json.loads(r.stdout)
    rows = {row["vehicle_id"]: row for row in doc["vehicles"]}
    assert set(rows) == set(VEHICLES), doc
    for row in rows.values():
        _check_row(row)
    assert rows["beta"]["soil_class"] == "sand" and 25 < rows["beta"]["K"] < 100  # sandy-slope: K = 50

    r = res["table"]
    assert r.returncode == 0, r.stderr
    for vid in VEHICLES:
        line = next(x for x in r.stdout.splitlines() if f" {vid} " in x)
        assert "5/5" in line and "fresh" in line and re.search(r"\d+\.\d ± \d+\.\d", line), line

    r = res["empty"]
    assert r.returncode == 1 and json.loads(r.stdout)["vehicles"] == [], (r.stdout, r.stderr)
    assert "no vehicle answered" in r.stderr
    r = res["no-router"]
    assert r.returncode == 1 and "no router answered" in r.stderr, r.stderr


def test_dashboard_json_api_and_event_stream(fleet):
    status, doc = _http_json(fleet.url + "/api/vehicles")
    assert status == 200 and doc["router"]["connected"] is True
    assert {v["vehicle_id"] for v in doc["vehicles"]} == set(VEHICLES)
    for row in doc["vehicles"]:
        _check_row(row)
    status, d = _http_json(fleet.url + "/api/vehicles/beta")
    v = d["vehicle"]
    assert status == 200 and v["vehicle_id"] == "beta" and len(v["history"]) > 5
    assert [w["wheel"] for w in v["wheels"]] == ["LR", "LF", "RF", "RR"]
    c = v["curve"]
    assert c["K"] == v["K"] and len(c["mu"]) == len(c["slip"]) == len(c["mu_lo"])
    # the curve is eq. 6 at the vehicle's K, computed by the library
    np.testing.assert_allclose(c["mu"], net_traction(np.array(c["slip"]), c["K"]), atol=2e-4)  # values rounded to 5 decimals for the wire
    assert v["health"]["gateway"]["service"] == "gateway"
    assert _http_json(fleet.url + "/api/vehicles/nobody")[0] == 404
    assert _http_json(fleet.url + "/api/vehicles/bad.id")[0] == 400
    status, consts = _http_json(fleet.url + "/api/constants")
    assert consts["soils"] == DEFAULT_CONSTANTS.soils

    with urllib.request.urlopen(fleet.url + "/events", timeout=10) as r:
        assert r.headers["Content-Type"].startswith("text/event-stream")
        events: list[dict] = []
        event = None
        while len(events) < 2:
            line = r.readline().decode().rstrip("\n")
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: ") and event == "fleet":
                events.append(json.loads(line[6:]))
    first, second = events
    assert {v["vehicle_id"] for v in first["vehicles"]} == set(VEHICLES)
    assert all(v["history_full"] and v["history"] for v in first["vehicles"])
    for v in second["vehicles"]:  # the second event carries only the points added since the first
        before = next(x for x in first["vehicles"] if x["vehicle_id"] == v["vehicle_id"])
        assert not v["history_full"]
        assert all(p["id"] > before["history"][-1]["id"] for p in v["history"])


# --- headless Chromium over the DevTools protocol ------------------------------------------------
def _chromium() -> Optional[str]:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Chromium:
    """Headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``):
    JSON messages separated by NUL bytes, Chromium reads fd 3 and writes fd 4."""

    def __init__(self, exe: str, width: int = 1400, height: int = 800):
        self.width, self.height = width, height
        self.profile = tempfile.mkdtemp(prefix="soilocp-chromium-")
        to_r, self._w = os.pipe()
        self._r, from_w = os.pipe()

        def _fds() -> None:  # in the child: put the pipe ends on fds 3 and 4 (inheritable)
            import fcntl

            a = fcntl.fcntl(to_r, fcntl.F_DUPFD, 10)
            b = fcntl.fcntl(from_w, fcntl.F_DUPFD, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe", "--no-first-run",
             "--disable-extensions", "--disable-background-networking", "--disable-dev-shm-usage",
             f"--user-data-dir={self.profile}", f"--window-size={width},{height}", "--hide-scrollbars",
             "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_fds,
            close_fds=False, start_new_session=True)
        os.close(to_r)
        os.close(from_w)
        self._id = 0
        self._replies: dict[int, dict] = {}
        self._closed = False
        self._cond = threading.Condition()
        self.session: Optional[str] = None
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._r, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                with self._cond:
                    self._closed = True
                    self._cond.notify_all()
                return
            buf += chunk
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg = json.loads(raw)
                if "id" in msg:
                    with self._cond:
                        self._replies[msg["id"]] = msg
                        self._cond.notify_all()

    def call(self, method: str, params: Optional[dict] = None, *, timeout: float = 30.0, browser: bool = False):
        self._id += 1
        i = self._id
        msg: dict[str, Any] = {"id": i, "method": method, "params": params or {}}
        if self.session and not browser:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        with self._cond:
            while i not in self._replies:
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    raise TimeoutError(f"no DevTools reply to {method} within {timeout} s")
                self._cond.wait(left)
            reply = self._replies.pop(i)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply["result"]

    def open(self, url: str) -> None:
        tid = self.call("Target.createTarget", {"url": "about:blank"}, browser=True, timeout=60)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": tid, "flatten": True}, browser=True)["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": self.width, "height": self.height, "deviceScaleFactor": 1, "mobile": False})
        self.call("Page.navigate", {"url": url})

    def eval(self, expression: str):
        return self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True})["result"].get("value")

    def screenshot(self, path: Path) -> bytes:
        m = self.call("Page.getLayoutMetrics")
        size = m.get("cssContentSize") or m["contentSize"]
        data = base64.b64decode(self.call("Page.captureScreenshot", {
            "format": "png", "captureBeyondViewport": True,
            "clip": {"x": 0, "y": 0, "width": self.width, "height": math.ceil(size["height"]), "scale": 1}})["data"])
        Path(path).write_bytes(data)
        return data

    def close(self) -> None:
        try:
            self.call("Browser.close", browser=True, timeout=5)
        except (TimeoutError, RuntimeError, OSError):
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        for fd in (self._w, self._r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)


ROWS_JS = """JSON.stringify([...document.querySelectorAll('#rows tr[data-vehicle]')].map(tr => ({
  id: tr.dataset.vehicle, state: tr.dataset.state, status: tr.dataset.status, text: tr.innerText})))"""
CARDS_JS = """JSON.stringify([...document.querySelectorAll('.card')].map(c => ({
  id: c.id, svgs: c.querySelectorAll('svg').length,
  kpath: (c.querySelector('.p-k path.k') || {getAttribute: () => ''}).getAttribute('d').length,
  soils: [...c.querySelectorAll('.p-k text.soil-label')].map(t => t.textContent),
  wheels: c.querySelectorAll('.p-curve circle.wheel').length,
  curve: (c.querySelector('.p-curve path.k') || {getAttribute: () => ''}).getAttribute('d').length,
  badges: c.querySelector('.badges').innerText})))"""
K_RE = re.compile(r"\d+\.\d ± \d+\.\d")


def _rows(browser: Chromium) -> dict[str, dict]:
    raw = browser.eval(ROWS_JS)
    return {r["id"]: r for r in json.loads(raw)} if raw else {}


@pytest.mark.skipif(_chromium() is None, reason="chromium not installed (Debian: apt-get install -y chromium)")
def test_dashboard_in_headless_chromium_live_then_stopped_vehicle_marked(fleet, tmp_path):
    browser = fleet.browser
    browser.open(fleet.url + "/")

    def both_with_numbers():
        rows = _rows(browser)
        return rows if set(VEHICLES) <= set(rows) and all(K_RE.search(rows[v]["text"]) for v in VEHICLES) else None

    rows = wait_for(both_with_numbers, timeout=60, interval=0.5)
    assert rows, f"page never showed both vehicles with K: {_rows(browser)}"
    for vid in VEHICLES:
        r = rows[vid]
        assert r["state"] == "online" and r["status"] == "fresh", r
        assert "5/5" in r["text"] and "online" in r["text"] and "fresh" in r["text"]
        assert any(s in r["text"] for s in SOILS)
    # plots: wait until the history has a few points, then check every card's three SVGs
    def cards_ready():
        cards = {c["id"][5:]: c for c in json.loads(browser.eval(CARDS_JS))}
        return cards if set(VEHICLES) <= set(cards) and all(cards[v]["kpath"] > 20 for v in VEHICLES) else None

    cards = wait_for(cards_ready, timeout=20, interval=0.5)
    assert cards, browser.eval(CARDS_JS)
    for vid in VEHICLES:
        c = cards[vid]
        assert c["svgs"] == 3 and c["wheels"] == 4 and c["curve"] > 100, c
        assert c["soils"] == [f"{n} {k:g}" for n, k in DEFAULT_CONSTANTS.soils.items()], c
    browser.eval("window.scrollTo(0, 0)")
    png = browser.screenshot(tmp_path / "dashboard-live.png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000

    # stop beta (Ctrl-C to its soilocp run): its services go away with their liveliness
    beta = fleet.procs.procs["beta"]
    beta.send_signal(signal.SIGINT)
    beta.wait(30)

    def beta_marked():
        rows = _rows(browser)
        b, a = rows.get("beta"), rows.get("alpha")
        return rows if b and a and b["state"] == "offline" and b["status"] == "stale" else None

    rows = wait_for(beta_marked, timeout=30, interval=0.5)
    assert rows, _rows(browser)
    assert "offline since" in rows["beta"]["text"] and "stale" in rows["beta"]["text"]
    assert rows["alpha"]["state"] == "online" and rows["alpha"]["status"] == "fresh"
    cards = {c["id"][5:]: c for c in json.loads(browser.eval(CARDS_JS))}
    assert "offline since" in cards["beta"]["badges"] and "stale" in cards["beta"]["badges"]
    time.sleep(1.0)
    png = browser.screenshot(tmp_path / "dashboard-one-stopped.png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    for name in ("dashboard-live.png", "dashboard-one-stopped.png"):
        if os.environ.get("SOILOCP_DASHBOARD_SHOTS"):  # to refresh docs/dashboard.png by hand
            shutil.copy(tmp_path / name, Path(os.environ["SOILOCP_DASHBOARD_SHOTS"]) / name)

    # the one-shot fleet view agrees: beta no longer answers, alpha still does
    r = _fleet_cmd("--connect", fleet.router, "--json", "--timeout", "10")
    assert r.returncode == 0, r.stderr
    assert [v["vehicle_id"] for v in json.loads(r.stdout)["vehicles"]] == ["alpha"]
