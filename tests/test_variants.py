"""The robustness variants do what their descriptions say (soilocp.sim.variants), measured on the
simulated streams against the nominal drive with the same seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.sim.variants import VARIANTS, get_variant, list_variants
from soilocp.model.vehicle import DEFAULT_VEHICLE


def _run(name: str, duration: float, seed: int = 0):
    pairs = list(get_variant(name).simulate(seed, duration=duration))
    return [s for s, _ in pairs], [t for _, t in pairs]


@pytest.fixture(scope="module")
def nominal():
    return _run("nominal", 4.0)


def test_every_variant_is_named_described_and_classified():
    names = [v.name for v in list_variants()]
    assert len(names) == len(set(names)) >= 20
    for v in list_variants():
        assert v.description and "\n" not in v.description
        assert v.identifiable in ("yes", "limited", "no")
        assert (v.identifiable == "limited") == bool(v.why_limited)
    with pytest.raises(ValueError, match="nominal"):
        get_variant("no-such-variant")


def test_issue_list_is_covered():
    v = VARIANTS
    assert {v[n].rate for n in ("rate-20hz", "rate-50hz", "nominal", "rate-200hz")} == {20.0, 50.0, 100.0, 200.0}
    sweeps = [x.sweep for x in list_variants() if x.name.startswith("sweep-")]
    assert min(s.period for s in sweeps) == 3.0 and max(s.period for s in sweeps) == 12.0
    assert min(s.s_max for s in sweeps) == 0.1 and max(s.s_max for s in sweeps) == 0.5


def test_same_seed_same_stream_other_seed_other_noise():
    a, _ = _run("imu-bias", 0.5, seed=3)
    b, _ = _run("imu-bias", 0.5, seed=3)
    c, _ = _run("imu-bias", 0.5, seed=4)
    assert a == b
    assert a != c


def test_epoch_stamps_start_near_1_7e9_and_keep_the_clock(nominal):
    samples, truth = _run("epoch-stamps", 1.0)
    assert samples[0].stamp == pytest.approx(1.7e9)
    for s, t in zip(samples, truth):
        assert s.stamp - 1.7e9 == pytest.approx(t.stamp, abs=1e-6)
    # only the stamps differ from the nominal stream
    for s, n in zip(samples, nominal[0]):
        assert s.model_copy(update={"stamp": n.stamp}) == n


def test_torque_scale_multiplies_the_torque_channel_only(nominal):
    for name, scale in (("torque+10", 1.10), ("torque-10", 0.90)):
        samples, _ = _run(name, 4.0)
        for s, n in zip(samples, nominal[0]):
            np.testing.assert_allclose(s.wheel_torque, scale * np.asarray(n.wheel_torque), rtol=1e-12, atol=1e-12)
            assert s.wheel_speed == n.wheel_speed and s.specific_force == n.specific_force
        assert max(abs(q) for s in samples for q in s.wheel_torque) > 1.0  # the test saw real torques


def test_wheel_speeds_refresh_every_0_2_s_and_hold(nominal):
    samples, _ = _run("wheel-speed-5hz", 4.0)
    base = nominal[0]
    changes = 0
    for i in range(1, len(samples)):
        same_window = math.floor(samples[i].stamp * 5 + 1e-9) == math.floor(samples[i - 1].stamp * 5 + 1e-9)
        if same_window:
            assert samples[i].wheel_speed == samples[i - 1].wheel_speed
        else:
            assert samples[i].wheel_speed == base[i].wheel_speed  # refreshed with the current reading
            changes += samples[i].wheel_speed != samples[i - 1].wheel_speed
    assert changes >= 15  # 4 s at 5 Hz, moving after the first samples


def test_wheel_speeds_at_4_7_hz_refresh_between_samples_and_hold(nominal):
    """Refreshes at k / 4.7 s fall between the 100 Hz samples: each reports the reading interpolated
    there, held until the next (the 5 Hz variant's refreshes coincide with samples and the sweep's kinks)."""
    samples, _ = _run("wheel-speed-4.7hz", 4.0)
    base = nominal[0]
    refreshes = 0
    for i in range(1, len(samples)):
        if math.floor(samples[i].stamp * 4.7 + 1e-9) == math.floor(samples[i - 1].stamp * 4.7 + 1e-9):
            assert samples[i].wheel_speed == samples[i - 1].wheel_speed
            continue
        refreshes += 1
        lo = np.minimum(base[i - 1].wheel_speed, base[i].wheel_speed)
        hi = np.maximum(base[i - 1].wheel_speed, base[i].wheel_speed)
        assert np.all(lo - 1e-12 <= samples[i].wheel_speed) and np.all(samples[i].wheel_speed <= hi + 1e-12)
    assert refreshes == math.floor(samples[-1].stamp * 4.7 + 1e-9)


@pytest.mark.parametrize("name, hz", [("torque-10hz", 10), ("torque-2hz", 2)])
def test_torques_refresh_at_their_rate_and_hold(nominal, name, hz):
    samples, _ = _run(name, 4.0)
    base = nominal[0]
    changes = 0
    for i in range(1, len(samples)):
        assert samples[i].wheel_speed == base[i].wheel_speed  # only the torque channel is held
        if math.floor(samples[i].stamp * hz + 1e-9) == math.floor(samples[i - 1].stamp * hz + 1e-9):
            assert samples[i].wheel_torque == samples[i - 1].wheel_torque
        else:
            assert samples[i].wheel_torque == pytest.approx(base[i].wheel_torque, rel=1e-12, abs=1e-12)
            changes += samples[i].wheel_torque != samples[i - 1].wheel_torque
    assert changes >= 4 * hz - 1


def test_ground_speed_lags_50_ms_and_refreshes_at_10_hz(nominal):
    samples, _ = _run("ground-speed-lag", 4.0)
    base = nominal[0]
    for i in range(1, len(samples)):
        if math.floor(samples[i].stamp * 10 + 1e-9) == math.floor(samples[i - 1].stamp * 10 + 1e-9):
            assert samples[i].ground_speed == samples[i - 1].ground_speed
        elif i >= 5:  # at 100 Hz a refresh reports the reading 5 samples earlier
            assert samples[i].ground_speed == pytest.approx(base[i - 5].ground_speed, abs=1e-12)
    assert samples[-1].ground_speed != base[-1].ground_speed  # really late, not a copy


def test_imu_bias_is_constant_and_of_the_stated_size(nominal):
    samples, _ = _run("imu-bias", 4.0)
    df = np.array([s.specific_force for s in samples]) - np.array([n.specific_force for n in nominal[0]])
    dg = np.array([s.yaw_rate for s in samples]) - np.array([n.yaw_rate for n in nominal[0]])
    np.testing.assert_allclose(np.abs(df), 0.1, atol=1e-9)
    np.testing.assert_allclose(df, np.broadcast_to(df[0], df.shape), atol=1e-9)
    np.testing.assert_allclose(np.abs(dg), 0.01, atol=1e-12)


def test_rates_give_their_sample_spacing():
    for name, rate in (("rate-20hz", 20.0), ("rate-200hz", 200.0)):
        samples, _ = _run(name, 1.0)
        assert len(samples) == int(rate)
        assert np.diff([s.stamp for s in samples]) == pytest.approx(1.0 / rate)


def test_true_vehicle_differs_from_the_nominal_one():
    r = get_variant("radius+3").true_vehicle()
    assert r.wheel_radius == pytest.approx(1.03 * DEFAULT_VEHICLE.wheel_radius)
    m = get_variant("mass-com+20").true_vehicle()
    assert m.mass == pytest.approx(72.0) and m.a == pytest.approx(1.2 * DEFAULT_VEHICLE.a)
    assert m.a + m.b == pytest.approx(DEFAULT_VEHICLE.a + DEFAULT_VEHICLE.b) and m.h == pytest.approx(0.36)
    # the simulator really drives the true vehicle: at rest the normal forces carry the true weight
    _, truth = _run("mass-com+20", 0.05)
    assert sum(truth[0].normal_force) == pytest.approx(72.0 * 9.80665, rel=1e-6)
    # and its slip (eq. 1) uses the true radius, not the nominal one the estimator gets
    _, truth = _run("radius+3", 3.0)
    t = truth[-1]
    vi = [t.ground_speed - t.yaw_rate * y for y in DEFAULT_VEHICLE.wheel_y]
    slip = [(w * r.wheel_radius - v) / max(abs(w * r.wheel_radius), abs(v)) for w, v in zip(t.wheel_speed, vi)]
    np.testing.assert_allclose(t.slip, slip, atol=1e-9)


def test_rear_mirror_brakes_at_about_minus_the_front_slip():
    _, truth = _run("rear-mirror", 10.0)
    s = np.array([t.slip for t in truth])[300:]  # after the 2 s ramp and the first second
    front, rear = (s[:, 1] + s[:, 2]) / 2, (s[:, 0] + s[:, 3]) / 2
    assert front.max() > 0.3 and rear.min() < -0.3
    assert np.median(np.abs(front + rear)) < 0.06
    assert np.corrcoef(front, rear)[0, 1] < -0.9
    # the nominal traction test holds the speed with the rear instead: far from a mirror image
    _, nominal = _run("nominal", 10.0)
    sn = np.array([t.slip for t in nominal])[300:]
    assert np.median(np.abs((sn[:, 1] + sn[:, 2]) / 2 + (sn[:, 0] + sn[:, 3]) / 2)) > 2 * np.median(np.abs(front + rear))


def test_s_turns_swing_the_yaw_rate(nominal):
    _, truth = _run("s-turns", 8.0)
    yaw = np.array([t.yaw_rate for t in truth])
    assert yaw.max() > 0.2 and yaw.min() < -0.2
    assert max(abs(t.yaw_rate) for t in nominal[1]) < 0.05


def test_sweep_variants_follow_their_sweep():
    _, truth = _run("sweep-3s-0.1", 6.0)
    cmd = np.array([t.slip_command for t in truth[250:]])
    assert 0.09 < cmd.max() <= 0.1 + 1e-12 and cmd.min() == pytest.approx(0.02, abs=1e-9)


def test_cruise_has_no_traction_test():
    _, truth = _run("cruise", 2.0)
    assert all(t.mode == "cruise" and t.slip_command is None for t in truth)
