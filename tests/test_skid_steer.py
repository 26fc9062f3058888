"""Skid steer (vehicle drive per_side): the vehicle option, and the simulator driving such a robot
and writing what its sensors measure (one speed and one torque per side)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from soilocp.sim.sensor_models import SensorNoise
from soilocp.sim.simulator import simulate
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams, load_vehicle


def test_drive_option_default_and_file(tmp_path):
    assert DEFAULT_VEHICLE.drive == "per_wheel"
    p = tmp_path / "v.json"
    p.write_text(json.dumps({"mass": 300.0, "drive": "per_side"}))
    assert load_vehicle(p).drive == "per_side"
    p.write_text(json.dumps({"drive": "tracks"}))
    with pytest.raises(ValueError, match="drive"):
        load_vehicle(p)
    with pytest.raises(ValueError, match="mass"):
        VehicleParams(mass=float("nan"))


@pytest.mark.parametrize("mode", ["excitation", "cruise"])
def test_per_side_log_shares_speed_and_halves_side_torque(mode):
    v = VehicleParams(drive="per_side")
    pairs = list(simulate("sand", duration=6.0, vehicle=v, mode=mode, noise=SensorNoise.noiseless()))
    s = np.array([p[0].wheel_speed for p in pairs])
    t = np.array([p[0].wheel_torque for p in pairs])
    ws = np.array([p[1].wheel_speed for p in pairs])
    wt = np.array([p[1].wheel_torque for p in pairs])
    assert np.array_equal(s[:, 0], s[:, 1]) and np.array_equal(s[:, 2], s[:, 3])
    np.testing.assert_allclose(t[:, 0], (wt[:, 0] + wt[:, 1]) / 2, atol=1e-12)
    np.testing.assert_allclose(t[:, 3], (wt[:, 2] + wt[:, 3]) / 2, atol=1e-12)
    # the wheels of a side are chained to one motor: one speed, exactly
    assert np.array_equal(ws[:, 0], ws[:, 1]) and np.array_equal(ws[:, 2], ws[:, 3])
    # front and rear wheels of a side carry different loads, hence different ground forces: how the
    # side's torque splits between them is the estimator's job (by normal force), not the sensor's
    if mode == "excitation":
        g = np.array([p[1].gross_traction for p in pairs]) * np.array([p[1].normal_force for p in pairs])
        late = slice(300, None)
        assert np.max(np.abs(g[late, 0] - g[late, 1])) > 0.5


def test_per_wheel_simulation_unchanged_by_the_option():
    a = [p[0] for p in simulate("sand", duration=1.0, seed=2)]
    b = [p[0] for p in simulate("sand", duration=1.0, seed=2, vehicle=VehicleParams(drive="per_wheel"))]
    assert a == b
    assert a[-1].wheel_speed[0] != a[-1].wheel_speed[1]  # four independent wheels
