"""The control loop live over Zenoh: real router, pipeline, controller and closed-loop vehicle as
OS processes (explicit endpoints, multicast off).  The OCP service is killed mid-run and the
controller must fall back to the safe set-point; a restarted OCP service brings the estimate back."""

from __future__ import annotations

import signal
import threading

import pytest

from soilocp.schemas import keys
from soilocp.schemas.messages import ServiceHealth, SlipSetpoint
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.control import fallback_slip
from soilocp.model.ocp import ocp_from_soil_strength

from zenoh_helpers import PIPELINE, Procs, client, endpoint, free_port, get_payloads, start_pipeline, wait_alive, wait_for

pytestmark = pytest.mark.timeout(300)

STALE = "0.5"


class Stream:
    def __init__(self, cls):
        self.cls, self.items, self.lock = cls, [], threading.Lock()

    def __call__(self, sample):
        m = self.cls.model_validate_json(sample.payload.to_bytes())
        with self.lock:
            self.items.append(m)

    def snapshot(self):
        with self.lock:
            return list(self.items)


def _vehicle_health(session, vid):
    for p in get_payloads(session, keys.status(vid, "vehicle")):
        return ServiceHealth.model_validate_json(p)
    return None


def test_live_loop_follows_the_estimate_and_falls_back_when_the_ocps_die(tmp_path):
    vid = "ctl1"
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        start_pipeline(procs, ep, vid, ["--stale-timeout", STALE])
        ctl_args = ["service", "controller", "--vehicle-id", vid, "--connect", ep, "--control", "ocp_traction",
                    "--stale-timeout", STALE]
        procs.spawn("controller", ctl_args)
        with client(ep) as s:
            setpoints, ocps = Stream(SlipSetpoint), Stream(OcpEstimate)
            subs = [s.declare_subscriber(keys.control_slip(vid), setpoints), s.declare_subscriber(keys.ocp(vid), ocps)]
            assert wait_alive(s, vid, (*PIPELINE, "controller")), procs.log_text("controller")
            # before any OCP the controller already publishes the safe fallback
            first = wait_for(lambda: setpoints.snapshot(), 30.0)
            assert first and first[0].source == "fallback" and first[0].slip == (fallback_slip("S_T"),) * 4
            procs.spawn("vehicle", ["service", "vehicle", "--vehicle-id", vid, "--connect", ep, "--scenario",
                                    "drawbar-sand", "--control", "ocp_traction", "--stale-timeout", STALE,
                                    "--duration", "200"])

            # 1. closed loop on the live estimate: S_T of the OCP of the same sample, near the true S_T
            def estimated(n):
                got = [m for m in setpoints.snapshot() if m.source == "estimate"]
                return got if len(got) >= n else None

            est = wait_for(lambda: estimated(200), 150.0)
            assert est, (setpoints.snapshot()[-3:], procs.log_text("vehicle")[-2000:])
            by_seq = {o.seq: o for o in ocps.snapshot()}
            checked = 0
            for m in est[-50:]:
                o = by_seq.get(m.seq)
                if o is not None:
                    assert m.slip == (pytest.approx(o.S_T),) * 4 and m.soil_strength == o.soil_strength
                    checked += 1
            assert checked > 10
            assert abs(est[-1].slip[0] - ocp_from_soil_strength(50.0).S_T) < 0.03  # sand, K = 50
            h = wait_for(lambda: (lambda x: x if x and x.detail.get("loop_latency_n", 0) > 0
                                  and x.detail.get("setpoint_source") == "estimate" else None)(_vehicle_health(s, vid)),
                         30.0)
            assert h is not None, _vehicle_health(s, vid)
            assert h.detail["loop_latency_p50_ms"] > 0

            # 2. kill the OCP service: the controller falls back, the vehicle follows the fallback
            n_before = len(setpoints.snapshot())
            procs.procs["ocp"].send_signal(signal.SIGKILL)
            procs.procs["ocp"].wait(10)

            def fell_back():
                new = setpoints.snapshot()[n_before:]
                return [m for m in new if m.source == "fallback" and "stale" in m.reason] or None

            fb = wait_for(fell_back, 30.0)
            assert fb, setpoints.snapshot()[-3:]
            assert fb[0].slip == (fallback_slip("S_T"),) * 4 and fb[0].ocp_age_s is not None
            h = wait_for(lambda: (lambda x: x if x and x.detail.get("setpoint_source") == "fallback" else None)(
                _vehicle_health(s, vid)), 30.0)
            assert h is not None and h.detail["setpoint"] == pytest.approx(fallback_slip("S_T"))
            assert procs.procs["vehicle"].poll() is None and procs.procs["controller"].poll() is None

            # 3. a new OCP service brings the estimate back
            n_before = len(setpoints.snapshot())
            procs.spawn("ocp", ["service", "ocp", "--vehicle-id", vid, "--connect", ep, "--stale-timeout", STALE])
            back = wait_for(lambda: [m for m in setpoints.snapshot()[n_before:] if m.source == "estimate"] or None, 90.0)
            assert back, setpoints.snapshot()[-3:]
            for sub in subs:
                sub.undeclare()
    finally:
        codes = procs.close()
    for name in ("controller", "vehicle"):
        assert codes[name] == 0, (name, codes, procs.log_text(name)[-2000:])
