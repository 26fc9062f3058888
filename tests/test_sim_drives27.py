"""The simulator's drives beyond straight forward traction, measured against their own truth: travel backwards (eq. 1
for the direction of travel, resistance opposing backward travel), a skid steer turning on the
spot, a speed set-point that accelerates and brakes, a descent, a stall under a draft."""

from __future__ import annotations

import numpy as np
import pytest

from soilocp.model.traction import gross_traction, motion_resistance, net_traction
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.controller import ControllerParams
from soilocp.sim.sensor_models import SensorNoise
from soilocp.sim.simulator import simulate
from soilocp.sim.variants import ROBUST_DRIVE, get_variant


def arr(records, name):
    return np.array([getattr(r, name) for r in records], dtype=float)


def eq1_for_travel(wheel_speed, v_wheel, radius, floor=0.05):
    """Eq. 1 for the direction of travel, written out here (not the simulator's code): the
    driving slip (|omega R| - |V|) / max(|omega R|, |V|) when both move the same way."""
    rim = wheel_speed * radius
    sign = np.where(v_wheel < 0, -1.0, 1.0)
    return sign * (rim - v_wheel) / np.maximum(np.maximum(np.abs(rim), np.abs(v_wheel)), floor)


@pytest.fixture(scope="module")
def reverse():
    pairs = list(simulate(ROBUST_DRIVE, duration=6.0, controller=ControllerParams(reverse=True),
                          noise=SensorNoise.noiseless()))
    return [t for _, t in pairs]


def test_reverse_drive_travels_backwards_with_eq1_slips_of_travel(reverse):
    late = [t for t in reverse if t.stamp >= 2.5]
    v = arr(late, "ground_speed")
    assert v.max() < -0.5 and np.median(v) == pytest.approx(-1.0, abs=0.1)
    s = arr(late, "slip")
    assert np.all(np.abs(s) <= 1.0)
    r = arr(late, "yaw_rate")
    v_wheel = v[:, None] - r[:, None] * np.array(DEFAULT_VEHICLE.wheel_y)
    np.testing.assert_allclose(s, eq1_for_travel(arr(late, "wheel_speed"), v_wheel, DEFAULT_VEHICLE.wheel_radius),
                               atol=1e-9)
    # the leading (rear) axle sweeps driving slip, the trailing (front) axle brakes to hold the speed
    rear, front = s[:, [0, 3]], s[:, [1, 2]]
    assert rear.max() > 0.4 and np.median(rear) > 0.05
    assert front.min() < -0.1 and np.median(front) < 0.0
    # the wheels turn backwards: the rim speed has the sign of travel
    assert np.all(arr(late, "wheel_speed") < 0)


def test_reverse_truth_is_the_traction_law_in_the_frame_of_travel(reverse):
    for t in reverse[50:]:
        k = np.array(t.wheel_soil_strength)
        np.testing.assert_allclose(t.mu, net_traction(np.array(t.slip), k), atol=5e-7)
        np.testing.assert_allclose(t.gross_traction, gross_traction(np.array(t.slip), k), atol=5e-7)
        np.testing.assert_allclose(t.motion_resistance, motion_resistance(np.array(t.slip), k), atol=5e-7)


def test_reverse_energy_balance_closes(reverse):
    """Resistance opposes backward travel: its work and the slip's dissipation stay >= 0 (grass,
    K = 200 > 125) and the books close as in forward travel."""
    work = arr(reverse, "motor_work")
    stored = arr(reverse, "kinetic_energy") + arr(reverse, "potential_energy")
    dissipated = arr(reverse, "slip_dissipation") + arr(reverse, "resistance_work") + arr(reverse, "yaw_dissipation")
    numerical = work - stored - dissipated
    assert work[-1] > 100.0
    assert numerical.min() > -1e-3 and numerical[-1] < 0.005 * work[-1]
    assert np.all(np.diff(dissipated) >= -1e-9)


def test_reverse_crosses_the_soils_backwards_rear_wheels_first():
    truth = [t for _, t in get_variant("reverse").simulate(0, duration=13.0)]
    change = next(t for t in truth if t.wheel_soil_strength[0] != truth[0].wheel_soil_strength[0])
    assert change.wheel_soil_strength[3] == change.wheel_soil_strength[0] == 50.0  # the rear wheels lead
    assert change.wheel_soil_strength[1] == change.wheel_soil_strength[2] == 200.0
    assert change.distance < -9.0


def test_skid_steer_turns_on_the_spot_each_wheel_driving_its_own_way():
    truth = [t for _, t in get_variant("skid-spot-turn").simulate(0, duration=6.0)]
    late = [t for t in truth if t.stamp >= 3.0]
    assert np.abs(arr(late, "ground_speed")).max() < 0.02
    assert np.median(arr(late, "yaw_rate")) == pytest.approx(0.6, abs=0.05)
    w = arr(late, "wheel_speed")
    assert np.all(w[:, [0, 1]] < 0) and np.all(w[:, [2, 3]] > 0)  # left side backwards, right forwards
    s = arr(late, "slip")
    assert np.all(np.abs(s) <= 1.0)
    # eq. 12's lateral resistance (mu_y 0.5) asks each wheel for a large driving slip in its own direction
    assert np.median(s) > 0.05
    tq = arr(late, "wheel_torque")
    assert np.allclose(tq[:, 0], tq[:, 1]) and np.allclose(tq[:, 2], tq[:, 3])  # one motor per side


def test_skid_arcs_hold_their_yaw_rate():
    truth = [t for _, t in get_variant("skid-arcs").simulate(0, duration=6.0)]
    r = arr([t for t in truth if t.stamp >= 3.0], "yaw_rate")
    assert np.median(r) == pytest.approx(0.4, abs=0.1) and np.percentile(r, 95) < 0.8


@pytest.mark.parametrize("name", ["payload+25-accel-brake", "motor+8-accel-brake", "reverse-braking"])
def test_accel_brake_drives_accelerate_and_brake(name):
    truth = [t for _, t in get_variant(name).simulate(0, duration=10.0)]
    fx = np.array([t.specific_force[0] for t in truth if t.stamp >= 3.0])
    assert np.percentile(fx, 5) < -0.5 and np.percentile(fx, 95) > 0.5
    v = np.abs(arr(truth, "ground_speed"))[300:]
    assert v.min() < 0.75 and v.max() > 1.25


def test_payload_and_motor_constant_are_unknown_to_the_estimator():
    payload, motor = get_variant("payload+25"), get_variant("motor+8")
    assert payload.true_vehicle().mass == pytest.approx(1.25 * DEFAULT_VEHICLE.mass)
    assert payload.known_vehicle() == DEFAULT_VEHICLE == motor.known_vehicle()
    assert motor.true_vehicle().mass == DEFAULT_VEHICLE.mass
    nominal = [s for s, _ in get_variant("nominal").simulate(0, duration=3.0)]
    for s, n in zip([s for s, _ in motor.simulate(0, duration=3.0)], nominal):
        np.testing.assert_allclose(np.array(s.wheel_torque) * 1.08, n.wheel_torque, rtol=1e-12, atol=1e-12)


def test_descent_brakes_every_wheel():
    truth = [t for _, t in get_variant("slope-cruise-12").simulate(0, duration=6.0)]
    late = [t for t in truth if t.stamp >= 3.0]
    assert late[0].pitch == pytest.approx(np.radians(12.0))  # nose down
    assert np.all(arr(late, "slip") < 0) and np.median(arr(late, "mu")) == pytest.approx(-0.21, abs=0.03)
    assert np.median(arr(late, "ground_speed")) == pytest.approx(1.0, abs=0.1)


def test_the_draft_stalls_the_robot_with_its_wheels_spinning():
    truth = [t for _, t in get_variant("stall-draft").simulate(0, duration=25.0)]
    late = [t for t in truth if t.stamp >= 18.0]
    v = arr(late, "ground_speed")
    assert v.max() < 0.1 and v.min() >= 0.0
    s = arr(late, "slip")
    assert np.all(s > 0.5) and np.all(s <= 1.0)
