"""Slip controllers (soilocp.control): saturation, anti-windup, set-point fallback, the simulator
hooks, the closed loop against simulator truth, and the ``control compare`` JSON contract."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from soilocp.schemas.pipeline import OcpEstimate
from soilocp.control import DEFAULT_GAINS, LoopGains, OcpSetPoint, WheelTorqueLoop, fallback_slip, make_policy
from soilocp.control.compare import METRICS
from soilocp.control.rig import get_rig_scenario, run_closed_loop
from soilocp.model.ocp import ocp_from_soil_strength
from soilocp.sim.simulator import simulate
from soilocp.model.vehicle import DEFAULT_VEHICLE

R = DEFAULT_VEHICLE.wheel_radius


def _est(stamp: float, k: float | None, status: str = "ok") -> OcpEstimate:
    o = ocp_from_soil_strength(k) if k is not None else None
    return OcpEstimate(vehicle_id="r", seq=int(stamp * 100), stamp=stamp, soil_strength=k,
                       soil_strength_std=None if k is None else 0.05 * k, soil_class=None, soil_class_confidence=None,
                       status=status, reason="", mu=(0.0,) * 4, slip=(0.0,) * 4,
                       mu_T=o.mu_T if o else None, S_T=o.S_T if o else None, S_E=o.S_E if o else None, te_at_S_E=None)


def _spin(loop: WheelTorqueLoop, steps: int, t0: float, slip: float, setpoint, speed_cmd=1.0):
    """Step the loop with wheels turning at a given slip (V = 1 m/s); returns the outputs."""
    w = 1.0 / (R * (1.0 - slip))
    return [loop.step(t0 + 0.01 * k, (w,) * 4, 1.0, 0.0, speed_cmd, setpoint) for k in range(steps)]


# --- torque loop -----------------------------------------------------------------------------------
def test_saturation_bounds_every_torque():
    loop = WheelTorqueLoop()
    outs = _spin(loop, 300, 0.0, slip=0.0, setpoint=None, speed_cmd=5.0)  # huge speed error
    lim = DEFAULT_GAINS.torque_limit
    assert max(max(o.torque) for o in outs) == pytest.approx(lim)
    assert all(abs(q) <= lim for o in outs for q in o.torque)
    assert outs[-1].saturated == (True,) * 4
    outs = _spin(loop, 300, 3.0, slip=0.9, setpoint=0.1, speed_cmd=0.0)  # huge negative errors
    assert min(min(o.torque) for o in outs) == pytest.approx(-lim)


def _windup_then_reverse(loop: WheelTorqueLoop) -> list[float]:
    # 10 s pinned at the limit with a slip error of +0.6 (the speed channel saturated too: its
    # command stays far above the rim speed), then the wheel spins past the set-point (error -0.3)
    _spin(loop, 1000, 0.0, slip=0.0, setpoint=0.6, speed_cmd=20.0)
    return [o.torque[0] for o in _spin(loop, 50, 10.0, slip=0.9, setpoint=0.6, speed_cmd=20.0)]


def test_anti_windup_leaves_saturation_at_once_after_a_long_pin():
    loop = WheelTorqueLoop()
    torques = _windup_then_reverse(loop)
    lim = DEFAULT_GAINS.torque_limit
    assert np.all(np.abs(loop.i_speed) <= lim * 1.1)
    # within 0.5 s the torque is off the limit and still falling
    assert torques[-1] < 0.9 * lim and torques[-1] < torques[-10], torques


def test_without_back_calculation_the_same_case_winds_up():
    # the test above can fail: with a negligible tracking term the integrator winds up (a plain
    # integrator holds ki T0 e 10 s ~ 260 N m) and stays pinned at the limit
    torques = _windup_then_reverse(WheelTorqueLoop(gains=LoopGains(tracking_time=1e6)))
    assert torques[-1] == pytest.approx(DEFAULT_GAINS.torque_limit)


def test_slip_channel_limits_only_past_the_setpoint():
    loop = WheelTorqueLoop()
    low = _spin(loop, 50, 0.0, slip=0.05, setpoint=0.2, speed_cmd=1.2)[-1]
    assert low.limiting == (False,) * 4  # speed loop in charge below the set-point
    high = _spin(loop, 50, 0.5, slip=0.4, setpoint=0.2, speed_cmd=3.0)[-1]  # rim 1.67 m/s < 3
    assert high.limiting == (True,) * 4


def test_loop_rejects_bad_input():
    loop = WheelTorqueLoop()
    with pytest.raises(ValueError, match="finite"):
        loop.step(0.0, (math.nan, 0, 0, 0), 1.0, 0.0, 1.0, 0.2)
    with pytest.raises(ValueError, match="slip_setpoint"):
        loop.step(0.0, (1, 1, 1, 1), 1.0, 0.0, 1.0, 1.5)
    with pytest.raises(ValueError, match="tracking_time"):
        LoopGains(tracking_time=0.0)


# --- set-points and fallback ---------------------------------------------------------------------
def test_ocp_setpoint_uses_the_estimate_and_falls_back_safely():
    pol = OcpSetPoint("S_T", stale_timeout_s=0.5)
    fb = fallback_slip("S_T")
    assert fb == pytest.approx(ocp_from_soil_strength(50.0).S_T)  # weakest reference soil
    for k in (80.0, 200.0, 300.0):  # at or below the traction peak of every stronger soil
        assert fb <= ocp_from_soil_strength(k).S_T
    sp = pol(10.0, _est(10.0, 300.0))
    assert sp.source == "estimate" and sp.value == pytest.approx(ocp_from_soil_strength(300.0).S_T)
    assert pol(10.0, None).value == fb and pol(10.0, None).source == "fallback"
    assert pol(10.0, _est(10.0, None, "no_estimate")).source == "fallback"
    assert pol(10.0, _est(10.0, 300.0, "stale")).value == fb
    old = pol(10.0, _est(9.0, 300.0))  # 1 s old > 0.5 s
    assert old.source == "fallback" and "old" in old.reason
    assert pol(10.0, _est(10.0, 300.0, "holding")).source == "estimate"


def test_efficiency_setpoint_has_a_floor_where_eq10_gives_zero():
    pol = make_policy("ocp_efficiency")
    sp = pol(1.0, _est(1.0, 800.0))  # K > alpha: S_E = 0 would stop the rover
    assert sp.source == "estimate" and sp.value == pytest.approx(pol.min_slip)
    assert pol(1.0, None).value == pytest.approx(ocp_from_soil_strength(50.0).S_E)


def test_policy_names():
    assert make_policy("fixed_0.15")(0.0, None).value == 0.15
    assert make_policy("speed")(0.0, None).value is None
    with pytest.raises(ValueError, match="controller must be one of"):
        make_policy("ocp_magic")
    with pytest.raises(ValueError, match="fixed slip"):
        make_policy("fixed_1.5")


# --- simulator hooks -----------------------------------------------------------------------------
def test_simulator_applies_the_commanded_torque_and_checks_it():
    cmds = []

    def cmd(sample):
        t = (5.0, 6.0, 7.0, 8.0) if sample.seq < 50 else (100.0, -100.0, 0.0, 0.0)
        cmds.append(t)
        return t

    recs = list(simulate("firm", duration=1.0, mode="cruise", wheel_torque_command=cmd))
    assert recs[10][1].wheel_torque == pytest.approx((5.0, 6.0, 7.0, 8.0))
    assert recs[60][1].wheel_torque == pytest.approx((40.0, -40.0, 0.0, 0.0))  # clamped to the motor limit
    with pytest.raises(ValueError, match="4 finite torques"):
        list(simulate("firm", duration=0.1, wheel_torque_command=lambda s: (1.0, 2.0)))
    with pytest.raises(ValueError, match="draft force"):
        list(simulate("firm", duration=0.1, drawbar_load=lambda t, v: -1.0))


def test_draft_slows_the_rover_and_never_pulls_it_backwards():
    free = list(simulate("firm", duration=4.0, mode="cruise"))[-1][1]
    heavy = list(simulate("firm", duration=4.0, mode="cruise", drawbar_load=lambda t, v: 2000.0))[-1][1]
    assert free.ground_speed > 0.9
    assert -0.01 < heavy.ground_speed < 0.1


# --- the closed loop against truth ------------------------------------------------------------------
def test_fixed_slip_is_tracked_and_ocp_traction_pulls_more_on_firm_soil():
    rig = get_rig_scenario("drawbar-firm")
    fixed, tr_f = run_closed_loop(rig, "fixed_0.20")
    ocp, tr_o = run_closed_loop(rig, "ocp_traction")
    # while the slip limiter holds the rover (pull plateau, still moving), the slip sits at 0.20
    s = np.asarray(tr_f.slip)[(np.asarray(tr_f.speed) > 0.3) & (np.asarray(tr_f.t) > 35.0)]
    assert len(s) > 50 and abs(np.median(s) - 0.20) < 0.02
    # the estimate (not truth) drove the set-point, close to the true S_T
    share = ocp["estimate_share"]
    assert share > 0.5
    sp = np.asarray(tr_o.setpoint)[np.asarray(tr_o.source) == "estimate"]
    assert abs(np.median(sp[-200:]) - ocp_from_soil_strength(300.0).S_T) < 0.03
    assert ocp["drawbar_pull_n"] >= 1.10 * fixed["drawbar_pull_n"]


# --- control compare CLI ----------------------------------------------------------------------------
def test_control_compare_json_shape_on_a_short_run(tmp_path):
    out = tmp_path / "cmp.json"
    plots = tmp_path / "plots"
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "control", "compare", "--scenario", "drawbar-sand",
                        "--scenario", "mixed-drive", "--duration", "4", "--json", str(out), "--plots", str(plots)],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert [s["name"] for s in doc["scenarios"]] == ["drawbar-sand", "mixed-drive"]
    for s in doc["scenarios"]:
        assert list(s["controllers"]) == ["speed", "fixed_0.15", "fixed_0.20", "ocp_traction", "ocp_efficiency"]
        for m in s["controllers"].values():
            for key in METRICS:
                assert key in m
                assert m[key] is None or (isinstance(m[key], float) and math.isfinite(m[key]))
            assert m["distance_m"] > 0
    assert "ocp_traction" in r.stdout and "drawbar-sand" in r.stdout
    assert sorted(p.name for p in plots.iterdir()) == ["control-drawbar-sand.png", "control-mixed-drive.png"]
    bad = subprocess.run([sys.executable, "-m", "soilocp.cli", "control", "compare", "--scenario", "nowhere"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "scenario must be one of" in bad.stderr


# --- the closed-loop vehicle's set-point inbox (no Zenoh needed) ------------------------------------
def test_vehicle_inbox_follows_set_points_falls_back_when_silent_and_times_the_loop():
    from soilocp.schemas.messages import SlipSetpoint
    from soilocp.services.control.vehicle_control import SetpointInbox

    inbox = SetpointInbox("rover1", "ocp_traction", stale_timeout_s=0.5)
    fb = fallback_slip("S_T")
    assert inbox.current(now=0.0).value == fb and inbox.current(now=0.0).source == "fallback"
    inbox.sent(1.25, 100.0)  # sample stamp 1.25 published at t = 100.0 s
    sp = SlipSetpoint(vehicle_id="rover1", controller="ocp_traction", slip=(0.5,) * 4, source="estimate",
                      fallback=fb, seq=125, stamp=1.25, soil_strength=300.0, stale_timeout_s=0.5, issued_at=0.0)
    inbox.offer(sp.model_dump_json().encode(), wall=100.004)
    cur = inbox.current(now=100.2)
    assert cur.value == 0.5 and cur.source == "estimate"
    assert inbox.latency_summary()["loop_latency_n"] == 1
    assert inbox.latency_summary()["loop_latency_p50_ms"] == pytest.approx(4.0)
    # the controller went silent: after the stale timeout the vehicle applies the fallback itself
    late = inbox.current(now=100.6)
    assert late.value == fb and late.source == "fallback" and "no set-point for" in late.reason
    # garbage and other vehicles' set-points are counted and ignored
    inbox.offer(b"{not json", wall=100.7)
    inbox.offer(sp.model_copy(update={"vehicle_id": "other"}).model_dump_json().encode(), wall=100.7)
    assert inbox.bad == 2 and inbox.current(now=100.71).value == fb
    with pytest.raises(ValueError, match="controller must be one of"):
        SetpointInbox("rover1", "nope", 0.5)
