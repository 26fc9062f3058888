"""The simulated rover: physics balances, controller behaviour, sensor log contract, determinism."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from soilocp.schemas.sensor import SensorSample, parse_sensor_line
from soilocp.model.normal_force import STANDARD_GRAVITY, normal_forces, static_normal_forces
from soilocp.model.ocp import ocp_from_soil_strength
from soilocp.sim.scenarios import Scenario, Segment, SweepParams, get_scenario, list_scenarios
from soilocp.sim.sensor_models import SensorNoise
from soilocp.sim.controller import ControllerParams
from soilocp.sim.simulator import simulate
from soilocp.sim.truth import TruthRecord
from soilocp.model.slip import slip_ratio
from soilocp.model.traction import gross_traction, motion_resistance, net_traction
from soilocp.model.vehicle import DEFAULT_VEHICLE, load_vehicle

V = DEFAULT_VEHICLE
G = STANDARD_GRAVITY
NOISELESS = SensorNoise.noiseless()
ROOT = Path(__file__).resolve().parents[1]


def run(scenario, **kw):
    kw.setdefault("noise", NOISELESS)
    pairs = list(simulate(scenario, **kw))
    return [p[0] for p in pairs], [p[1] for p in pairs]


def arr(records, field):
    return np.array([getattr(r, field) for r in records], dtype=float)


@pytest.fixture(scope="module")
def sand_excitation():
    return run("sand", duration=7.0)


@pytest.fixture(scope="module")
def slope_cruise():
    return run("sandy-slope", duration=8.0, mode="cruise")


# --- statics ------------------------------------------------------------------------------------
def test_static_load_split_at_rest(sand_excitation):
    sensors, truth = sand_excitation
    t0, s0 = truth[0], sensors[0]
    fz = np.array(t0.normal_force)
    mg = V.mass * G
    assert fz[0] + fz[3] == pytest.approx(mg * V.b / (V.a + V.b), rel=1e-9)  # rear axle
    assert fz[1] + fz[2] == pytest.approx(mg * V.a / (V.a + V.b), rel=1e-9)
    assert fz[0] + fz[1] == pytest.approx(mg * V.d / (V.c + V.d), rel=1e-9)  # left side
    assert s0.specific_force == pytest.approx((0.0, 0.0, G), abs=1e-12)
    assert t0.ground_speed == 0.0 and t0.slip == (0.0, 0.0, 0.0, 0.0)


def test_cross_slope_loads_the_lower_side(slope_cruise):
    _, truth = slope_cruise
    seg = get_scenario("sandy-slope").segments[0]
    assert seg.cross_slope > 0 and seg.grade > 0  # left side up, climbing
    for t in (truth[0], truth[-1]):
        fz = np.array(t.normal_force)
        assert fz[2] + fz[3] > fz[0] + fz[1] + 5.0  # right (lower) side carries more
        assert fz[0] + fz[3] > static_normal_forces(V)[[0, 3]].sum()  # climb loads the rear
    fz0 = np.array(truth[0].normal_force)
    assert fz0 == pytest.approx(static_normal_forces(V, roll=seg.cross_slope, pitch=-seg.grade), rel=1e-9)


def test_grade_balance_at_steady_cruise_on_a_climb(slope_cruise):
    sensors, truth = slope_cruise
    grade = truth[-1].grade
    late = [i for i, t in enumerate(truth) if t.stamp >= 6.0]
    drive = np.mean([np.dot(truth[i].mu, truth[i].normal_force) for i in late])
    assert drive == pytest.approx(V.mass * G * math.sin(grade), rel=0.01)
    pitch = np.array([sensors[i].pitch for i in late])
    fx = np.array([sensors[i].specific_force[0] for i in late])
    assert np.all(pitch < 0)
    assert np.all(np.abs(fx - (-G * np.sin(pitch))) < 0.02)
    assert fx.mean() == pytest.approx(G * math.sin(grade), abs=0.005)
    # cruise tracks the wheels' rim speed (omega_ref = V_ref / R_w); the climb's slip costs ground speed
    speed = arr([truth[i] for i in late], "ground_speed")
    rim = np.array([truth[i].wheel_speed for i in late]) * V.wheel_radius
    assert np.all(np.abs(rim - 1.0) < 0.01)
    assert np.all(np.abs(speed - 1.0) < 0.05)
    # climbing in cruise needs driving slip on every wheel, all within the rising branch
    slips = np.array([truth[i].slip for i in late])
    assert np.all(slips > 0.01) and np.all(slips < truth[-1].S_T)
    # heading hold keeps the rover straight although the lower side pushes harder
    assert abs(truth[-1].heading) < 0.02
    pe = truth[-1].potential_energy
    assert pe == pytest.approx(V.mass * G * truth[-1].distance * math.sin(grade), rel=1e-3)


# --- consistency of the truth with the library ----------------------------------------------------
def test_truth_is_the_library_model(sand_excitation):
    _, truth = sand_excitation
    y = np.array(V.wheel_y)
    for t in truth[::37]:
        k = np.array(t.wheel_soil_strength)
        s = np.array(t.slip)
        vi = t.ground_speed - t.yaw_rate * y
        assert s == pytest.approx(slip_ratio(np.array(t.wheel_speed), vi, V.wheel_radius).slip, abs=1e-12)
        assert np.array(t.mu) == pytest.approx(net_traction(s, k), abs=5e-7)
        assert np.array(t.gross_traction) == pytest.approx(gross_traction(s, k), abs=5e-7)
        assert np.array(t.motion_resistance) == pytest.approx(motion_resistance(s, k), abs=5e-7)
        assert np.array(t.normal_force) == pytest.approx(normal_forces(V, np.array(t.specific_force)), rel=1e-9)
        ocp = ocp_from_soil_strength(t.soil_strength)
        assert (t.mu_T, t.S_T, t.S_E) == (ocp.mu_T, ocp.S_T, ocp.S_E)


def test_noiseless_sensors_read_the_truth(sand_excitation):
    sensors, truth = sand_excitation
    for s, t in zip(sensors[::50], truth[::50]):
        assert (s.seq, s.stamp, s.vehicle_id) == (t.seq, t.stamp, t.vehicle_id)
        assert s.wheel_speed == t.wheel_speed and s.wheel_torque == t.wheel_torque
        assert s.specific_force == t.specific_force and s.ground_speed == t.ground_speed
        assert (s.roll, s.pitch, s.yaw_rate) == (t.roll, t.pitch, t.yaw_rate)


# --- energy ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("scenario", ["sand", "grass", "sandy-slope"])
def test_energy_balance(scenario):
    _, truth = run(scenario, duration=4.0)
    work = arr(truth, "motor_work")
    stored = arr(truth, "kinetic_energy") + arr(truth, "potential_energy")
    slip_d, res_w, yaw_d = arr(truth, "slip_dissipation"), arr(truth, "resistance_work"), arr(truth, "yaw_dissipation")
    dissipated = slip_d + res_w + yaw_d
    numerical = work - stored - dissipated  # backward Euler's own dissipation, >= 0 and small
    assert work[-1] > 100.0
    assert numerical.min() > -1e-3
    assert numerical[-1] < 0.005 * work[-1]
    assert np.all(np.diff(slip_d) >= -1e-12) and np.all(np.diff(yaw_d) >= -1e-12)
    if scenario == "grass":  # K > ~125: motion resistance >= 0, so all dissipation is >= 0
        assert np.all(np.diff(dissipated) >= -1e-9)


# --- start from rest ---------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["cruise", "excitation"])
def test_abrupt_start_from_standstill_is_finite(mode):
    sensors, truth = run("grass", duration=1.5, mode=mode, controller=ControllerParams(ramp_time=0.0))
    for t in truth:
        vals = np.concatenate([t.slip, t.mu, t.gross_traction, t.normal_force, t.wheel_speed, t.wheel_torque, t.specific_force])
        assert np.all(np.isfinite(vals))
        assert np.all(np.abs(t.slip) <= 2.0)
    assert truth[-1].ground_speed > 0.5


# --- controller ------------------------------------------------------------------------------------
def test_excitation_slips_cover_the_sweep(sand_excitation):
    _, truth = sand_excitation
    late = [t for t in truth if t.stamp >= 3.0]
    s = np.array([t.slip for t in late])
    cmd = arr(late, "slip_command")
    assert cmd.max() == pytest.approx(0.6, abs=0.01) and cmd.min() == pytest.approx(0.05, abs=0.01)
    for i in (1, 2):  # front axle sweeps
        assert s[:, i].max() > 0.55 and s[:, i].min() < 0.07
        assert np.abs(s[:, i] - cmd).mean() < 0.03
    for i in (0, 3):  # rear axle brakes, on the stable side of the peak
        assert s[:, i].max() < 0 and s[:, i].min() > -0.36
    mu = np.array([t.mu for t in late])
    assert mu[:, 1].max() == pytest.approx(late[0].mu_T, abs=0.002)  # the sweep passes the peak
    speed = arr(late, "ground_speed")
    assert np.all(np.abs(speed - 1.0) < 0.2) and abs(speed.mean() - 1.0) < 0.03


def test_excitation_on_firm_soil_is_smooth_and_holds_the_speed():
    """Front driving + rear braking: the load-transfer loop is negative feedback, solved implicitly:
    no sample-to-sample oscillation of the specific force or the normal forces."""
    _, truth = run("firm", duration=6.0)
    late = [t for t in truth if t.stamp >= 2.4]  # two full sweep cycles
    f = np.array([t.specific_force for t in late])
    fz = np.array([t.normal_force for t in late])
    # a lagged load transfer oscillates sample to sample (+-5 m/s^2): second differences catch it
    assert np.abs(np.diff(f[:, 0])).max() < 0.4  # m/s^2 per 10 ms
    assert np.abs(np.diff(f[:, 0], 2)).max() < 0.15
    assert fz.min() > 100.0 and np.abs(np.diff(fz, 2, axis=0)).max() < 3.0
    s = np.array([t.slip for t in late])
    assert s[:, 1].max() > late[0].S_T  # past the traction peak (S_T = 0.51)
    speed = arr(late, "ground_speed")
    assert 0.7 < speed.min() and speed.max() < 1.3 and abs(speed.mean() - 1.0) < 0.03


def test_sweep_options():
    _, truth = run("gravel", duration=5.0, sweep=SweepParams(0.1, 0.4, 1.0, dwell=0.0))
    late = [t for t in truth if t.stamp >= 3.0]
    s = np.array([t.slip for t in late])
    cmd = arr(late, "slip_command")
    assert 0.37 < s[:, 1].max() < 0.42 and np.abs(s[:, 2] - cmd).mean() < 0.03
    # without a dwell the rear cannot hold the mean speed on gravel: the governor cuts the sweep
    assert cmd.min() < 0.09
    assert SweepParams(0.05, 0.6, 0.8, 0.4).slip_at(1.0) == 0.05  # in the dwell
    assert SweepParams(0.05, 0.6, 0.8, 0.4).slip_at(1.6) == pytest.approx(0.6)  # next peak


def test_cruise_on_flat_ground_has_near_zero_slip():
    _, truth = run("flat-cruise", duration=5.0)
    late = [t for t in truth if t.stamp >= 3.0]
    assert np.abs(np.array([t.slip for t in late])).max() < 0.01
    assert np.all(np.abs(arr(late, "ground_speed") - 1.0) < 0.01)
    assert all(t.slip_command is None and t.mode == "cruise" for t in late)


# --- terrain -------------------------------------------------------------------------------------
def test_mixed_scenario_definition():
    sc = get_scenario("mixed")
    assert [s.soil_class for s in sc.segments] == ["sand", "gravel", "grass", "firm"]
    assert [s.soil_strength for s in sc.segments] == [50.0, 80.0, 200.0, 300.0]
    assert list(sc.starts) == [0.0, 12.0, 24.0, 36.0]
    assert {"sand", "gravel", "EST", "grass", "firm", "sandy-slope", "mixed"} <= {s.name for s in list_scenarios()}


def test_terrain_changes_appear_in_order_front_wheels_first():
    short = Scenario(
        "short-mixed",
        "test",
        (Segment("sand", 50.0, 1.5), Segment("gravel", 80.0, 1.5), Segment("grass", 200.0, 1.5), Segment("firm", 300.0)),
        duration=7.0,
    )
    _, truth = run(short)
    classes = [t.soil_class for t in truth]
    order = [c for i, c in enumerate(classes) if i == 0 or c != classes[i - 1]]
    assert order == ["sand", "gravel", "grass", "firm"]
    ks = np.array([t.wheel_soil_strength for t in truth])
    first = {i: int(np.argmax(ks[:, i] == 80.0)) for i in range(4)}
    com = classes.index("gravel")
    assert first[1] == first[2] < com < first[0] == first[3]
    d = arr(truth, "distance")
    # the wheel's terrain is read at the start of each 2.5 ms sub-step: it may switch one sample after the crossing
    assert d[first[1]] >= 1.5 - V.b - 1e-9 and d[first[1] - 2] < 1.5 - V.b
    assert d[com] >= 1.5 and d[first[0]] >= 1.5 + V.a


# --- sensors, determinism, log contract ----------------------------------------------------------------
def test_same_seed_same_log_other_seed_other_noise():
    a_s, a_t = run("gravel", duration=1.0, seed=7, noise=None)
    b_s, b_t = run("gravel", duration=1.0, seed=7, noise=None)
    c_s, c_t = run("gravel", duration=1.0, seed=8, noise=None)
    assert [s.model_dump_json() for s in a_s] == [s.model_dump_json() for s in b_s]
    assert [s.model_dump_json() for s in a_s] != [s.model_dump_json() for s in c_s]
    # noise never feeds back into the dynamics: the truth does not depend on the seed
    assert [t.model_dump_json() for t in a_t] == [t.model_dump_json() for t in c_t]
    diff = np.array([s.specific_force for s in a_s]) - np.array([s.specific_force for s in c_s])
    assert 0.01 < diff.std() < 0.1


def test_default_noise_levels_and_encoder_quantisation(sand_excitation):
    sensors, truth = run("sand", duration=3.0, noise=None, seed=3)
    step = 2 * math.pi / 16384 / 0.01
    ws = np.array([s.wheel_speed for s in sensors])
    assert np.allclose(ws / step, np.round(ws / step), atol=1e-6)
    assert np.abs(ws[1:] - np.array([t.wheel_speed for t in truth])[1:]).max() < 1.0
    res_v = np.array([s.ground_speed - t.ground_speed for s, t in zip(sensors, truth)])
    assert 0.007 < res_v.std() < 0.013
    res_g = np.array([s.yaw_rate - t.yaw_rate for s, t in zip(sensors, truth)])
    assert 0.002 < res_g.std() < 0.004


def test_cli_writes_logs_that_validate_line_by_line(tmp_path):
    out, tr = tmp_path / "s.jsonl", tmp_path / "t.jsonl"
    proc = subprocess.run(
        [sys.executable, "-m", "soilocp.cli", "simulate", "--scenario", "sandy-slope", "--duration", "1.5",
         "--rate", "50", "--seed", "4", "--vehicle", str(ROOT / "soilocp/data/rover.json"),
         "--vehicle-id", "rover-7", "--out", str(out), "--truth", str(tr)],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "75 samples" in proc.stderr
    lines = out.read_text().splitlines()
    truth_lines = tr.read_text().splitlines()
    assert len(lines) == len(truth_lines) == 75
    keys = set(SensorSample.model_fields) - {"position", "geo"}  # optional, absent without a start pose
    for i, (line, tline) in enumerate(zip(lines, truth_lines)):
        assert set(json.loads(line)) == keys
        s = parse_sensor_line(line)
        t = TruthRecord.model_validate_json(tline)
        assert s.seq == t.seq == i and s.stamp == t.stamp == pytest.approx(i / 50)
        assert s.vehicle_id == t.vehicle_id == "rover-7"


def test_cli_rejects_unknown_scenario_and_lists(tmp_path):
    from click.testing import CliRunner

    from soilocp.commands.sim import simulate as command

    res = CliRunner().invoke(command, ["--scenario", "moon", "--out", str(tmp_path / "x")])
    assert res.exit_code != 0 and "sandy-slope" in res.output and "moon" in res.output
    res = CliRunner().invoke(command, ["--scenario", "sand", "--out", str(tmp_path / "x"), "--sweep-max", "0.01"])
    assert res.exit_code != 0 and "s_max" in res.output
    res = CliRunner().invoke(command, ["--list"])
    assert res.exit_code == 0 and "mixed" in res.output and "12 m .. 24 m" in res.output


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"rate": 0.0}, "rate"),
        ({"duration": -1.0}, "duration"),
        ({"mode": "race"}, "mode"),
        ({"seed": -3}, "seed"),
        ({"vehicle_id": "a/b"}, "vehicle_id"),
    ],
)
def test_bad_arguments_raise_at_call(kwargs, word):
    with pytest.raises(ValueError, match=word):
        simulate("sand", **kwargs)


def test_scenario_lookup_lists_valid_names():
    with pytest.raises(ValueError, match="sand, gravel"):
        get_scenario("mud")
    with pytest.raises(ValueError, match="s_min"):
        SweepParams(0.5, 0.2)


def test_rover_file_is_the_default_vehicle():
    assert load_vehicle(ROOT / "soilocp/data/rover.json") == DEFAULT_VEHICLE


def test_simulate_is_lazy_and_can_be_endless():
    gen = simulate("mixed", duration=math.inf)
    first = next(gen)
    assert first[0].seq == 0 and first[1].soil_class == "sand"
    for _ in range(20):
        sample, truth = next(gen)
    assert sample.seq == truth.seq == 20 and sample.stamp == pytest.approx(0.2)
    gen.close()
