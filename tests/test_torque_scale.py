"""The online torque scale (soilocp.estimation.torque_scale): eq. TC through the one library function
(soilocp.model.force_balance), learnt where the robot accelerates or brakes, the prior elsewhere."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.estimation.estimator import Estimator
from soilocp.estimation.observer_bank import ObserverInputs
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.estimation.torque_scale import TorqueScaleBank, TorqueScaleConfig
from soilocp.model.force_balance import longitudinal_balance, modelled_resistance
from soilocp.model.traction import motion_resistance
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.variants import get_variant

V = DEFAULT_VEHICLE


def scale_inputs(stamp, f_x, pitch, yaw_rate, wheel_speed, torque, speed, normal_force=None) -> ObserverInputs:
    """One sample per vehicle as the observer takes it (the torque scale's input): stamps, f_x, pitch, yaw rate,
    ground speed (k,); wheel speeds, logged torques and normal forces (k, 4) (None: the static load's)."""
    col = lambda a: np.asarray(a, dtype=float).reshape(-1)  # noqa: E731
    quad = lambda a: np.asarray(a, dtype=float).reshape(-1, 4)  # noqa: E731
    k = col(stamp).size
    return ObserverInputs(col(stamp), col(f_x), col(yaw_rate), col(pitch), quad(wheel_speed), quad(torque), col(speed),
                          np.full((k, 4), V.mass * 9.80665 / 4.0) if normal_force is None else quad(normal_force))


class ChainScale:
    """The torque scale of an estimator of n vehicles (the vehicle, constants and settings otherwise the defaults),
    stepped and fed through its chain as the estimator steps and feeds it: the observer stage's ``observe`` (the
    scale, then the observer) and ``feed`` (the soil's K and slips, where the resistance is modelled)."""

    def __init__(self, cfg: TorqueScaleConfig, n: int = 1):
        est = Estimator(PipelineConfig(torque_scale=cfg), n)
        self.scale, self.chain = est.scale, est.chain

    def step(self, ix, inputs: ObserverInputs):
        """One sample per vehicle in ``ix``: k's mean and 1-sigma after it."""
        ix = np.asarray(ix, dtype=np.int64)
        self.chain.observe(ix, inputs)
        return self.scale.scale(ix)

    def feed(self, ix, k, slip) -> None:
        """The soil's K (k,) and slips (k, 4) (NaN: none) for the vehicles ``ix``."""
        self.chain.feed(np.asarray(ix, dtype=np.int64), np.asarray(k, dtype=float), np.asarray(slip, dtype=float))


def _balance_stream(k_true: float, accel: float, resistance: float = 25.0, seconds: float = 40.0, rate: float = 100.0,
                    seed: int = 0, mass_ratio: float = 1.0):
    """Samples that satisfy eq. TC exactly (true torque = k_true x logged, true mass = mass_ratio x the vehicle
    file's: k = k_true / mass_ratio) with a constant F_MR, wheels rolling without slip at the speed 1 +
    accel-driven swing, and noisy readings."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    w = 2.0 * math.pi / 4.0
    a = accel * np.sin(w * t)
    v = 1.0 + accel / w * (1.0 - np.cos(w * t))
    omega = np.repeat((v / V.wheel_radius)[:, None], 4, axis=1)
    omega_dot_sum = 4.0 * a / V.wheel_radius
    torque_true = (mass_ratio * V.mass * a + resistance) * V.wheel_radius + V.wheel_inertia * omega_dot_sum
    logged = np.repeat((torque_true / k_true / 4.0)[:, None], 4, axis=1) + rng.normal(0, 0.05, (t.size, 4))
    f_x = a + rng.normal(0, 0.02, t.size)
    return t, f_x, omega, logged, v


def _run(stream, cfg=TorqueScaleConfig(enabled=True, prior_sigma=None)):
    t, f_x, omega, logged, v = stream
    bank = ChainScale(cfg)
    ix = np.array([0])
    out = [bank.step(ix, scale_inputs(t[i], f_x[i], 0.0, 0.0, omega[i], logged[i], v[i])) for i in range(t.size)]
    return np.array([(m[0], s[0]) for m, s in out])


def test_the_offline_fit_and_the_online_state_share_eq_tc():
    x, y = longitudinal_balance(0.5, 4.0, 12.0, V)
    assert x == pytest.approx(12.0 / V.wheel_radius)
    assert y == pytest.approx(V.mass * 0.5 + V.wheel_inertia * 4.0 / V.wheel_radius)


@pytest.mark.parametrize("k_true", [1.08, 0.8])
def test_it_converges_to_the_scale_where_the_robot_accelerates_and_brakes(k_true):
    est = _run(_balance_stream(k_true, accel=0.8))
    assert est[-1, 0] == pytest.approx(k_true, rel=0.015)
    assert est[-1, 1] < 0.02  # the posterior narrowed from the prior's 0.05
    assert abs(est[-1, 0] - k_true) < 2.5 * est[-1, 1]
    # and it started from the prior
    assert est[0, 0] == 1.0 and est[0, 1] == pytest.approx(0.05)


def test_at_constant_speed_it_stays_the_prior():
    est = _run(_balance_stream(1.08, accel=0.0))
    assert np.all(est[:, 0] == 1.0) and np.allclose(est[:, 1], 0.05)


def test_a_slip_sweep_at_constant_speed_teaches_it_nothing():
    """The robust-mix traction test: its speed swings within each sweep, but motion resistance swings
    with the slip, so its windows are left out (max_slip) and the scale stays the prior."""
    var = get_variant("nominal")
    bank = ChainScale(TorqueScaleConfig(enabled=True, prior_sigma=None))
    ix = np.array([0])
    for s, _ in var.simulate(0, duration=15.0):
        m, sd = bank.step(ix, scale_inputs(s.stamp, s.specific_force[0], s.pitch, s.yaw_rate, s.wheel_speed,
                                           s.wheel_torque, s.ground_speed))
    assert m[0] == 1.0 and sd[0] == pytest.approx(0.05)


def test_a_start_under_a_draft_that_grows_with_speed_leaves_k_until_it_brakes():
    """From 0.3 m/s, 0.6 m/s^2 for 3 s against a draft of 20 + 40 v N (docs/control.md: the closed loop read k
    0.9745 for 1.00 from such a start): windows of one sign inform F_MR alone; the braking that follows makes
    the shadow, which they informed, the state: k moves then, and only then.  The next braking window is a jump
    of F_MR (the draft has fallen with the speed) that adjoins it, and takes it back (docs/method.md §15, "A
    jump is a mixed window"): k returns to its prior, and so does its band."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 6.0, 0.01)
    a = np.where(t < 3.0, 0.6, -0.6)
    v = 0.3 + np.cumsum(a) * 0.01
    omega = np.repeat((v / V.wheel_radius)[:, None], 4, axis=1)
    torque_true = (V.mass * a + 20.0 + 40.0 * v) * V.wheel_radius + V.wheel_inertia * 4.0 * a / V.wheel_radius
    logged = np.repeat((torque_true / 4.0)[:, None], 4, axis=1) + rng.normal(0, 0.05, (t.size, 4))
    est = _run((t, a + rng.normal(0, 0.02, t.size), omega, logged, v), TorqueScaleConfig())
    assert np.all(est[t < 3.01, 0] == 1.0)  # three accelerating windows: k has not moved
    # then it moves, and not to the truth: a draft that grows with speed is no scale and no constant F_MR, and
    # the windows of the two signs at their different speeds read part of it as k (measured 0.823 for 1.00, the
    # limit docs/robustness.md states; 0.868 before the inertia term carried the payload's share of k, at the
    # shadow's k that the one-sign windows moved); a change of the model that fixes or worsens this shows here
    first = (t >= 4.0) & (t < 5.0)
    assert np.all((0.80 < est[first, 0]) & (est[first, 0] < 0.85))
    # the second braking window, a jump, takes the first back: the prior, k 1.00 +- 0.10 (the state's)
    assert est[-1, 0] == 1.0 and est[-1, 1] == pytest.approx(0.10, abs=1e-3)


def test_disabled_it_is_the_prior():
    est = _run(_balance_stream(1.08, accel=0.8, seconds=10.0), TorqueScaleConfig(enabled=False))
    assert np.all(est[:, 0] == 1.0) and np.all(est[:, 1] == 0.05)


def test_the_pipeline_learns_a_payload_and_the_batched_path_matches():
    """Offline (VehiclePipeline, the live stages' code) and batched path through the same kernel: the
    payload drive's torques are scaled by the learnt k (m / m' = 0.8 for +25 %), the nominal drive's stay."""
    from soilocp.estimation.batch import BatchPipeline
    from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline

    cfg = PipelineConfig()
    drives = {"p": [s.model_copy(update={"vehicle_id": "p"}) for s, _ in get_variant("payload+25-accel-brake").simulate(0, duration=12.0)],
              "n": [s.model_copy(update={"vehicle_id": "n"}) for s, _ in get_variant("nominal").simulate(0, duration=12.0)]}
    singles = {n: VehiclePipeline(cfg) for n in drives}
    batch = BatchPipeline(cfg, 2)
    last = {}
    for k in range(len(drives["p"])):
        samples = [drives["p"][k], drives["n"][k]]
        ref = [singles[n].process_all(s) for n, s in zip(drives, samples)]
        out = batch.step(np.array([0, 1]), samples, [r[0].normal_force for r in ref])
        for o, (nf, ob, so, oc) in zip(out, ref):
            assert o.status == oc.status and o.reason == oc.reason
            for name in ("soil_strength", "soil_strength_std"):
                a, b = getattr(o, name), getattr(oc, name)
                assert (a is None and b is None) or a == pytest.approx(b, rel=1e-9, abs=1e-9)
        last = {n: r[1] for n, r in zip(drives, ref)}
    assert last["p"].torque_scale < 0.95 and last["p"].torque_scale_std < 0.045
    assert last["n"].torque_scale == 1.0 and last["n"].torque_scale_std is None


def test_a_wider_state_prior_lets_the_balance_reach_a_payload_sooner():
    """k 0.80 (a +25 % payload) is 4 sigma of the torque constant's 0.05: with that prior the state is still
    pulled towards 1 after 10 s of swings; with the default state prior (0.10) it is nearer the truth.  The drive
    is a payload's (the wheels' inertia carries the vehicle file's mass, docs/method.md §15): read as a torque
    constant of 0.80 instead, the wider prior's inertia term takes the payload's share and reads k ~1 % low."""
    stream = _balance_stream(1.0, accel=0.8, seconds=10.0, mass_ratio=1.25)
    narrow = _run(stream)
    wide = _run(stream, TorqueScaleConfig(enabled=True))
    assert TorqueScaleConfig().prior_sigma == 0.10 and wide[0, 1] == pytest.approx(0.10)
    assert abs(wide[-1, 0] - 0.8) < abs(narrow[-1, 0] - 0.8) - 0.005


def test_k_band_combines_the_windows_information_with_the_torque_constant_prior():
    """band_sigma: the state's posterior precision less its own prior's, plus the torque constant's prior."""
    bank = TorqueScaleBank(V, TorqueScaleConfig(enabled=True, prior_sigma=0.10), 0.05, 1)
    sd = np.array([0.10, 0.05, 0.02])
    info = 1.0 / sd**2 - 1.0 / 0.10**2
    assert np.allclose(bank.band_sigma(sd), 1.0 / np.sqrt(1.0 / 0.05**2 + info))
    assert bank.band_sigma(sd)[0] == pytest.approx(0.05)  # no window's information: the torque constant's prior
    assert np.all(bank.band_sigma(sd) <= np.minimum(sd, 0.05) + 1e-12)
    same = TorqueScaleBank(V, TorqueScaleConfig(enabled=True, prior_sigma=None), 0.05, 1)
    assert np.array_equal(same.band_sigma(sd), sd)


def test_the_modelled_resistance_is_eq_4_summed_and_opposes_travel():
    slip = np.array([[0.1, -0.1, 0.05, 0.0]])
    fz = np.array([[200.0, 250.0, 250.0, 200.0]])
    want = float((fz * motion_resistance(slip, 120.0)).sum())
    assert modelled_resistance(slip, np.array([120.0]), fz, np.array([1.0]))[0] == pytest.approx(want)
    assert modelled_resistance(slip, np.array([120.0]), fz, np.array([-1.0]))[0] == pytest.approx(-want)
    x, y = longitudinal_balance(0.5, 4.0, 12.0, V, resistance=want)
    assert y == pytest.approx(V.mass * 0.5 + V.wheel_inertia * 4.0 / V.wheel_radius + want)


def _soil_change_stream(model: bool, k_true: float = 1.08, jump: float | None = None):
    """Eq. TC with F_MR = eq. 4 at slips 0.04-0.09 on a soil that alternates K 200 / 50 every 10 s (F_MR +25 / -19
    N): the soil's K is fed back as the soil stage does (the chain's feed).  ``jump``: resistance_jump (None: the
    default).  Returns k's final mean."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 40.0, 0.01)
    w = 2.0 * math.pi / 4.0
    a = 0.8 * np.sin(w * t)
    v = 1.0 + 0.8 / w * (1.0 - np.cos(w * t))
    slip = 0.04 + 0.05 * np.abs(np.sin(w * t))
    k_soil = np.where((t // 10) % 2 == 0, 200.0, 50.0)
    fz = np.full((t.size, 4), V.mass * 9.80665 / 4.0)
    f_mr = modelled_resistance(np.repeat(slip[:, None], 4, axis=1), k_soil, fz, np.ones(t.size))
    omega = np.repeat((v / (1.0 - slip) / V.wheel_radius)[:, None], 4, axis=1)
    torque_true = (V.mass * a + f_mr) * V.wheel_radius + V.wheel_inertia * np.gradient(omega.sum(axis=1), t)
    logged = np.repeat((torque_true / k_true / 4.0)[:, None], 4, axis=1) + rng.normal(0, 0.05, (t.size, 4))
    f_x = a + rng.normal(0, 0.02, t.size)
    extra = {} if jump is None else {"resistance_jump": jump}
    cfg = TorqueScaleConfig(enabled=True, model_resistance=model, prior_sigma=None, **extra)
    bank = ChainScale(cfg)
    ix, no_slip = np.array([0]), np.full((1, 4), np.nan)
    for i in range(t.size):
        bank.feed(ix, k_soil[i:i + 1], no_slip)
        m, _ = bank.step(ix, scale_inputs(t[i], f_x[i], 0.0, 0.0, omega[i], logged[i], v[i], fz[i]))
    return m[0]


def test_eq_4_in_the_balance_removes_the_random_walk_lag_behind_a_soil_change():
    """The random-walk F_MR alone follows each soil's resistance late and reads k 0.97 for 1.08; eq. 4 at the
    fed-back K reads it within 1.5 % (on the simulated drives the estimator's own K and slips are not this good: off
    by default, docs/robustness.md), and so does the random walk when a soil change is taken as a jump of F_MR
    (resistance_jump, the default)."""
    assert _soil_change_stream(True) == pytest.approx(1.08, rel=0.015)
    assert abs(_soil_change_stream(False, jump=0.0) - 1.08) > 0.05
    assert _soil_change_stream(False) == pytest.approx(1.08, rel=0.015)
