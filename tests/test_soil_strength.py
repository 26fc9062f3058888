"""Soil-strength estimators: recovery of K, uncertainty, gating, holding, abrupt changes, the
paper's rule with its sign fixed, and soil classes."""

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.soil_state import classify
from soilocp.estimation.soil_strength import BayesSoilEstimator, PaperSoilEstimator
from soilocp.model.traction import gross_traction, net_traction

INFO = np.ones(4, dtype=bool)


def _feed(est, k_true, slips, steps, t0=0.0, dt=0.01, measurement="gross", noise=0.0, rng=None):
    curve = gross_traction if measurement == "gross" else net_traction
    state = None
    for i in range(steps):
        s = np.asarray(slips[i % len(slips)])
        obs = curve(s, k_true)
        if noise:
            obs = obs + rng.normal(0, noise, 4)
        state = est.update(t0 + i * dt, s, obs, np.full(4, noise**2 + 1e-8), INFO)
    return state


@settings(max_examples=25, deadline=None)
@given(log_k=st.floats(math.log(26), math.log(2000)), s0=st.floats(0.1, 0.6))
def test_recovers_k_from_noiseless_net_traction_pairs(log_k, s0):
    """The estimator recovers K from noiseless (S, mu) pairs across K in [26, 2000] (from just above
    half the weakest reference soil's K: below that, see the next test)."""
    k_true = math.exp(log_k)
    cfg = SoilConfig(measurement="net", model_sigma=0.002, slip_sigma=0.0, temper=1.0, change_per_metre=0.0, q_log_k=0.0,
                     grid_points=801)
    est = BayesSoilEstimator(DEFAULT_CONSTANTS, cfg)
    slips = [[s0, -s0, s0 * 0.5 + 0.3, -(s0 * 0.5 + 0.3)], [0.9 - s0, s0, -s0, 0.7]]
    state = _feed(est, k_true, slips, 200, measurement="net")
    assert state.status in ("ok", "uncertain")
    assert state.soil_strength == pytest.approx(k_true, rel=0.03)


def test_k_far_below_the_weakest_reference_soil_is_flagged_not_classified():
    # what a torque channel in amperes looks like: gross traction far below sand's at every slip
    est = BayesSoilEstimator()
    slips = [[0.3, -0.1, -0.1, 0.3], [0.5, -0.2, -0.2, 0.5]]
    state = _feed(est, 12.0, slips, 300)
    assert state.status == "model_mismatch" and "weakest" in state.reason
    assert state.soil_class is None


@pytest.mark.parametrize("k_true", [50, 80, 120, 200, 300])
def test_recovers_k_from_noisy_gross_traction(k_true):
    rng = np.random.default_rng(0)
    est = BayesSoilEstimator()
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 60)]
    state = _feed(est, k_true, sweep, 300, noise=0.01, rng=rng)
    assert state.soil_strength == pytest.approx(k_true, rel=0.10)
    assert state.soil_strength_std > 0
    assert state.soil_class == {50: "sand", 80: "gravel", 120: "EST", 200: "grass", 300: "firm"}[k_true]


def test_saturated_soil_reports_wide_uncertainty_not_false_precision():
    """Above K ~ 300 eq. 3's amplitude saturates (docs/method.md §9).  Driving wheels see only that
    amplitude, so a torque scale within its 1-sigma moves K anywhere above ~300: the band says so.
    A braking axle adds the motion resistance (even in S, §11), which does not saturate as fast: it
    determines K and the scale in part, and then the band is narrower but still holds the truth."""
    drive = [[s, s, s, s] for s in np.linspace(0.05, 0.6, 60)]
    hard = _feed(BayesSoilEstimator(), 1500, drive, 300, noise=0.01, rng=np.random.default_rng(1))
    soft = _feed(BayesSoilEstimator(), 50, drive, 300, noise=0.01, rng=np.random.default_rng(1))
    assert hard.log_k_std > 3 * soft.log_k_std
    assert hard.status == "uncertain"
    assert hard.soil_strength > 300
    brake = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 60)]
    both = _feed(BayesSoilEstimator(), 1500, brake, 300, noise=0.01, rng=np.random.default_rng(1))
    assert soft.log_k_std < both.log_k_std < hard.log_k_std
    assert abs(both.soil_strength - 1500) <= 2 * both.soil_strength_std


def test_no_information_at_zero_slip_gives_no_estimate():
    est = BayesSoilEstimator()
    state = _feed(est, 80, [[0.0, 0.01, -0.01, 0.02]], 300)
    assert state.status == "no_estimate"
    assert state.soil_strength is None and state.soil_class is None
    assert "not been informative" in state.reason


def test_uninformative_speed_flag_blocks_updates():
    est = BayesSoilEstimator()
    s = np.array([0.3, 0.3, -0.3, -0.3])
    for i in range(100):
        state = est.update(i * 0.01, s, gross_traction(s, 80), np.full(4, 1e-4), np.zeros(4, bool))
    assert state.status == "no_estimate"


def test_holds_then_withdraws_when_slip_stops_being_informative():
    cfg = SoilConfig(hold_after=0.5, expire_after=2.0)
    est = BayesSoilEstimator(DEFAULT_CONSTANTS, cfg)
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 30)]
    live = _feed(est, 80, sweep, 200)
    assert live.status == "ok"
    k_live = live.soil_strength
    held = _feed(est, 80, [[0.0] * 4], 100, t0=2.0)  # 1 s of cruise
    assert held.status == "holding"
    assert held.soil_strength == k_live  # held, not drifting
    assert "holding" in held.reason
    gone = _feed(est, 80, [[0.0] * 4], 300, t0=3.0)
    assert gone.status == "no_estimate" and gone.soil_strength is None


def test_follows_an_abrupt_terrain_change_quickly():
    rng = np.random.default_rng(2)
    est = BayesSoilEstimator()
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 60)]
    _feed(est, 50, sweep, 500, noise=0.01, rng=rng)
    t_change = 5.0
    converged_at = None
    for i in range(300):
        s = np.asarray(sweep[i % 60])
        state = est.update(t_change + i * 0.01, s, gross_traction(s, 200) + rng.normal(0, 0.01, 4), np.full(4, 1e-4), INFO)
        inside = abs(state.soil_strength - 200) / 200 <= 0.15
        if inside and converged_at is None:
            converged_at = i * 0.01
        elif not inside:
            converged_at = None
    assert converged_at is not None and converged_at < 1.5


def test_outliers_do_not_drag_the_estimate():
    rng = np.random.default_rng(3)
    est = BayesSoilEstimator()
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 60)]
    for i in range(400):
        s = np.asarray(sweep[i % 60])
        obs = gross_traction(s, 80) + rng.normal(0, 0.01, 4)
        if i % 37 == 0:
            obs[rng.integers(4)] += 2.0  # a wild torque reading
        state = est.update(i * 0.01, s, obs, np.full(4, 1e-4), INFO)
    assert state.soil_strength == pytest.approx(80, rel=0.1)


def test_bad_shapes_rejected_with_argument_name():
    est = BayesSoilEstimator()
    with pytest.raises(ValueError, match="slip"):
        est.update(0.0, [0.1, 0.2], [0.1] * 4, [1e-4] * 4, INFO)
    with pytest.raises(ValueError, match="observed"):
        est.update(0.0, [0.1] * 4, [0.1, np.nan, 0.1, 0.1], [1e-4] * 4, INFO)


def test_paper_rule_sign_is_fixed_and_it_converges_down_as_well_as_up():
    """Eq. 37's |.| could only raise K; with the sign kept K also comes down to sand."""
    for k_true in (50, 200):
        est = PaperSoilEstimator()  # starts at K=120
        sweep = [[s, s, -s, -s] for s in np.linspace(0.15, 0.6, 30)]
        state = _feed(est, k_true, sweep, 3000, measurement="net")
        assert state.soil_strength == pytest.approx(k_true, rel=0.05)


def test_paper_rule_skips_slip_where_mu_decreases_with_k():
    est = PaperSoilEstimator()
    # at S = 0.05 and K = 120 d(mu)/dK < 0 for the printed constants? use a low K where it is
    est.k = 20.0
    s = np.array([0.05] * 4)
    state = est.update(0.0, s, net_traction(s, 20) + 0.2, None, INFO)
    assert est.k == 20.0 and not any(state.used)


def test_paper_rule_holds_then_withdraws_and_forgets_a_restarted_source():
    """Its K is held (flagged 'holding') hold_after s after the last update, withdrawn hold_after +
    expire_after s after it, and stamps going backwards withdraw it and forget the update time."""
    est = PaperSoilEstimator()
    cfg = est.cfg
    s = np.array([0.3, 0.3, 0.3, 0.3])
    none = np.zeros(4, dtype=bool)
    st = est.update(0.0, s, net_traction(s, 80.0), None, INFO)
    assert any(st.used) and st.status == "ok" and st.last_update_stamp == 0.0
    k = st.soil_strength
    st = est.update(cfg.hold_after / 2, s, net_traction(s, 80.0), None, none)
    assert (st.status, st.soil_strength, st.last_update_stamp) == ("ok", k, 0.0)
    st = est.update(cfg.hold_after + 0.1, s, net_traction(s, 80.0), None, none)
    assert st.status == "holding" and st.soil_strength == k and "holding the last estimate" in st.reason
    st = est.update(cfg.hold_after + cfg.expire_after + 0.1, s, net_traction(s, 80.0), None, none)
    assert st.status == "no_estimate" and st.soil_strength is None and "withdrawn" in st.reason
    st = est.update(1.0, s, net_traction(s, 80.0), None, INFO)  # a new update at t = 1 s
    assert st.status == "ok" and st.last_update_stamp == 1.0
    st = est.update(0.5, s, net_traction(s, 80.0), None, none)  # the source restarted
    assert (st.status, st.soil_strength, st.last_update_stamp) == ("no_estimate", None, None)
    assert "backwards" in st.reason
    st = est.update(0.6, s, net_traction(s, 80.0), None, none)
    assert st.status == "no_estimate" and "not been informative yet" in st.reason


def test_classify_by_log_k_with_confidence():
    assert classify(50, 0.05) [0] == "sand"
    assert classify(1000, 0.05)[0] == "firm"
    name, conf = classify(np.sqrt(50 * 80), 0.05)  # on the sand/gravel boundary
    assert 0.4 < conf < 0.6
    assert classify(200, 0.01)[1] > 0.99


def test_stamps_going_backwards_withdraw_the_estimate_instead_of_holding_it_as_fresh():
    est = BayesSoilEstimator()
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 30)]
    assert _feed(est, 80, sweep, 150, t0=1000.0).status == "ok"
    state = est.update(10.0, np.zeros(4), np.zeros(4), np.full(4, 1e-4), INFO)  # the source restarted
    assert state.status == "no_estimate" and state.soil_strength is None and "backwards" in state.reason
    assert _feed(est, 80, sweep, 150, t0=11.0).status == "ok"


def test_a_long_time_gap_resets_the_belief_at_once():
    # 30 years: a diffusion loop over the gap's length would never return (the suite's timeout
    # would fail this test); the reset is immediate
    est = BayesSoilEstimator()
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 30)]
    _feed(est, 80, sweep, 50)
    est.update(1e9, np.zeros(4), np.zeros(4), np.full(4, 1e-4), INFO)
    assert np.allclose(est.p, 1.0 / est.p.size)


def test_paper_rule_learns_from_braking_wheels_too():
    est = PaperSoilEstimator()  # K0 = 120
    sweep = [[-s] * 4 for s in np.linspace(0.15, 0.6, 30)]
    state = _feed(est, 50, sweep, 3000, measurement="net")
    assert all(state.used) and state.soil_strength == pytest.approx(50, rel=0.05)


def _mass_near(est, k, rel=0.5):
    near = np.abs(np.log(est.k_grid / k)) <= math.log1p(rel)
    return float(est.p[near].sum())


def test_terrain_change_hazard_is_per_metre_a_robot_that_stands_keeps_its_soil():
    """The belief mixes with the change prior over the distance travelled, not the time: after
    5 s parked (speed 0) the belief is still on the soil it stands on; after the same 5 s at
    1 m/s (5 m, 2.5 expected changes at 0.5 / m) most of it is gone."""
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.6, 30)]
    masses = {}
    for speed in (0.0, 1.0):
        est = BayesSoilEstimator()
        _feed(est, 80, sweep, 200)
        before = _mass_near(est, 80)
        for i in range(500):  # 5 s without information at this speed
            est.update(2.0 + i * 0.01, np.zeros(4), np.zeros(4), np.full(4, 1e-4), INFO, speed=speed)
        masses[speed] = (before, _mass_near(est, 80))
    (b0, a0), (b1, a1) = masses[0.0], masses[1.0]
    assert b0 > 0.9 and b1 > 0.9
    assert a0 > 0.8  # only the slow random walk of ln K (0.1 / sqrt(s)) spreads it
    assert a1 < 0.5 * a0  # e^(-0.5 x 5) = 8 % kept, spread by the same walk


def _drive_and_brake(est, k_true, scale, steps, t0=0.0, seed=0, states=None):
    """A traction test: front wheels drive and rear wheels brake through |S| 0.05..0.5; the torque channel
    reads ``scale`` x the true gross traction, scattered by 0.01, with the observer's 1-sigma stated at 0.05.
    ``k_true`` is one K or a function of the step giving each wheel's (4,).  Returns the last state (and
    appends every state to ``states``)."""
    rng = np.random.default_rng(seed)
    sweep = [[s, s, -s, -s] for s in np.linspace(0.05, 0.5, 50)]
    state = None
    for i in range(steps):
        s = np.asarray(sweep[i % len(sweep)])
        k = k_true(i) if callable(k_true) else k_true
        obs = scale * gross_traction(s, k) + rng.normal(0, 0.01, 4)
        state = est.update(t0 + i * 0.01, s, obs, np.full(4, 0.05**2), INFO)
        if states is not None:
            states.append(state)
    return state


@pytest.mark.parametrize("k_true", [200.0, 300.0])
@pytest.mark.parametrize("scale", [0.9, 1.1])
def test_a_wrong_torque_constant_is_inside_the_band_and_named(k_true, scale):
    """A torque constant 10 % off is a 2-sigma event of the 5 % prior; linearised at the estimate, the
    band missed it (torque-10: firm 300 read 203 +- 0.14 in ln K).  Propagated through the curve under
    the scale's posterior (a braking axle tells the scale apart in part, docs/method.md §9 "The band"),
    the band holds the truth, and where the scale dominates the reason gives the data's scale."""
    state = _drive_and_brake(BayesSoilEstimator(), k_true, scale, 700)
    assert abs(state.soil_strength - k_true) > 0.1 * k_true  # the scale does move K
    assert abs(state.soil_strength - k_true) <= 2 * state.soil_strength_std
    if state.status == "uncertain":
        assert "mostly systematic" in state.reason and "calibrate-torque" in state.reason
        data_scale = float(state.reason.split("lean to ")[1].split(")")[0])
        assert (data_scale - 1.0) * (scale - 1.0) > 0 and abs(data_scale - 1.0) > 0.05


def test_the_calibrate_hint_survives_a_restarted_clock():
    """A source that restarts (stamps back to 0): the data still lean to the wrong torque constant on the
    new clock, and the hint comes back after the evidence window on that clock (kept on the old one, it
    waited until the new stamps passed the old lean's start, 100 s on)."""
    est = BayesSoilEstimator()
    before = _drive_and_brake(est, 300.0, 0.9, 700, t0=100.0)
    assert "calibrate-torque" in before.reason
    states = []
    _drive_and_brake(est, 300.0, 0.9, 500, t0=0.0, seed=1, states=states)
    assert any("calibrate-torque" in s.reason for s in states)


def test_the_data_narrow_the_torque_scale_band_where_a_braking_axle_tells_the_scale_apart():
    """With the right torque constant the drive-and-brake test keeps firm soil's band well below the
    prior's alone (ln K 1-sigma 0.52 at K = 300 with driving wheels only: the §9 vectors)."""
    state = _drive_and_brake(BayesSoilEstimator(), 300.0, 1.0, 400)
    assert state.soil_strength == pytest.approx(300.0, rel=0.03)
    assert state.log_k_std < 0.2 and state.status == "ok"


def test_the_reason_names_the_systematic_term_that_widens_the_band():
    """Sand at |S| 0.045-0.05: a 1 % wheel radius is a 20 % slip error there and dominates the band;
    grass at the same slips: the torque scale does (the curve is flatter in K)."""
    def small_slips(k_true):
        est, rng = BayesSoilEstimator(), np.random.default_rng(0)
        sweep = [[s, s, -s, -s] for s in np.linspace(0.045, 0.05, 20)]
        for i in range(600):
            s = np.asarray(sweep[i % len(sweep)])
            state = est.update(i * 0.01, s, gross_traction(s, k_true) + rng.normal(0, 0.003, 4), np.full(4, 1e-5), INFO)
        return state

    sand, grass = small_slips(50.0), small_slips(200.0)
    assert sand.status == grass.status == "uncertain"
    assert "wheel-radius" in sand.reason and "torque scale" not in sand.reason
    assert "torque scale" in grass.reason and "calibrate-torque" not in grass.reason


def test_a_soil_change_under_the_axles_does_not_call_a_right_torque_constant_wrong():
    """While the front axle is on the new soil and the rear still on the old (0.4 s), the window leans
    the scale (to 0.90 on the robustness drive's 300 -> 100) and the band widens; the reason names
    calibrate-torque only for a lean that outlasts the window (with 1 s it did, here: 60 records)."""
    def crossing(i):
        return np.full(4, 100.0) if i < 800 else np.array([300.0, 300.0, 100.0, 100.0]) if i < 840 else np.full(4, 300.0)

    states = []
    _drive_and_brake(BayesSoilEstimator(), crossing, 1.0, 1200, states=states)
    assert states[-1].soil_strength == pytest.approx(300.0, rel=0.05)
    assert not [s for s in states if "calibrate-torque" in s.reason]


def test_the_band_statistics_restart_when_a_change_is_taken():
    """After sand -> firm, K's systematic term is the firm samples' alone: what an estimator that only
    ever saw firm soil reports (with the sand samples kept, the scale's posterior read 0.98 for 1.00)."""
    changed = BayesSoilEstimator()
    _drive_and_brake(changed, 50.0, 1.0, 400)
    after = _drive_and_brake(changed, 300.0, 1.0, 300, t0=4.0)
    fresh = BayesSoilEstimator()
    only = _drive_and_brake(fresh, 300.0, 1.0, 300)
    assert after.soil_strength == pytest.approx(only.soil_strength, rel=1e-3)
    assert changed.bank.scale_sys[0] == pytest.approx(fresh.bank.scale_sys[0], abs=1e-3)


@pytest.mark.parametrize("k_true", [1000.0, 3000.0])
def test_a_clean_sweep_on_saturated_soil_reports_a_finite_band_not_an_overflow(k_true):
    """Far above K ~ 300 the curve is flat in K, so the systematic (torque-scale) shift of K has
    no bound; it once overflowed math.sinh in the summary.  The band is capped at the grid's ln K
    span and the status says K is not determined."""
    est = BayesSoilEstimator()
    state = _feed(est, k_true, [[0.2] * 4], 200)
    assert state.status == "uncertain"
    assert math.isfinite(state.soil_strength_std) and state.log_k_std <= math.log(est.cfg.k_max / est.cfg.k_min) + 1e-9
    assert state.soil_class is not None and state.soil_class_confidence < 0.9


# docs/method.md §9, test vectors: K_true -> (status, K, ln K 1-sigma) at t = 2.0, 2.6, 12.4 s
_S9_VECTORS = {
    50: [("ok", 50.0, 0.0866), ("holding", 50.0, 0.287), ("holding", 50.0, 2.36)],
    80: [("ok", 80.0, 0.0958), ("holding", 80.0, 0.182), ("holding", 80.0, 2.36)],
    200: [("uncertain", 200.3, 0.223), ("holding", 200.3, 0.267), ("holding", 200.3, 2.37)],
    300: [("uncertain", 301.6, 0.523), ("holding", 301.6, 0.549), ("holding", 301.6, 2.42)],
    1000: [("uncertain", 1688.0, 6.91), ("holding", 1688.0, 6.91), ("holding", 1688.0, 6.91)],
}


@pytest.mark.parametrize("k_true", sorted(_S9_VECTORS))
def test_method_notes_section_9_vectors(k_true):
    est = BayesSoilEstimator()
    got = {}
    for i in range(1261):  # 100 Hz to t = 12.6 s
        s = np.full(4, 0.2 if i < 200 else 0.01)
        got[i] = est.update(i * 0.01, s, gross_traction(s, k_true), np.full(4, 1e-4), INFO)
    final = got[1260]
    for i, (status, k, log_std) in zip((200, 260, 1240), _S9_VECTORS[k_true]):
        state = got[i]
        assert state.status == status
        assert state.soil_strength == pytest.approx(k, rel=2e-3)
        assert state.log_k_std == pytest.approx(log_std, rel=0.01)
    assert final.status == "no_estimate" and final.soil_strength is None


@settings(max_examples=60, deadline=None)
@given(log_k=st.floats(math.log(5.0), math.log(5000.0)),
       slips=st.lists(st.lists(st.floats(-0.95, 0.95), min_size=4, max_size=4), min_size=1, max_size=8),
       noise=st.sampled_from([0.0, 1e-3, 0.03]), steps=st.integers(1, 150), seed=st.integers(0, 2**16))
@example(log_k=math.log(1000.0), slips=[[0.2] * 4], noise=0.0, steps=150, seed=0)  # once overflowed math.sinh
def test_any_soil_and_slip_pattern_gives_finite_summaries(log_k, slips, noise, steps, seed):
    """Property: whatever the soil (K over the whole grid) and the slip pattern, clean or noisy,
    every summary is finite and the status is one of the estimator's (no overflow, no NaN)."""
    rng = np.random.default_rng(seed)
    est = BayesSoilEstimator()
    for i in range(steps):
        s = np.asarray(slips[i % len(slips)])
        obs = gross_traction(s, math.exp(log_k)) + rng.normal(0, noise, 4)
        state = est.update(i * 0.01, s, obs, np.full(4, noise**2 + 1e-6), INFO)
        for v in (state.soil_strength, state.soil_strength_std, state.log_k_std, state.soil_class_confidence):
            assert v is None or math.isfinite(v)
        assert state.status in ("ok", "uncertain", "holding", "no_estimate", "not_observable", "model_mismatch")


def _feed_axles(est, k_front, k_rear, steps, t0=0.0, noise=0.01, rng=None):
    """A traction test (front wheels 1, 2 drive, rear wheels 0, 3 brake) where the front wheels see
    the gross coefficient of K = k_front and the rear ones of k_rear(t) (a number or a function of
    t); every state, in order."""
    rng = rng or np.random.default_rng(3)
    sweep = np.linspace(0.08, 0.5, 40)
    states = []
    for i in range(steps):
        t = t0 + i * 0.01
        s = sweep[i % 40] * np.array([-1.0, 1.0, 1.0, -1.0])
        kr = k_rear(t) if callable(k_rear) else k_rear
        obs = np.array([gross_traction(s[0], kr), gross_traction(s[1], k_front), gross_traction(s[2], k_front),
                        gross_traction(s[3], kr)]) + rng.normal(0, noise, 4)
        states.append(est.update(t, s, obs, np.full(4, noise**2), INFO))
    return states


def test_axles_reading_different_soils_are_a_model_mismatch_with_a_band_over_both():
    """Front wheels read K = 200, rear wheels K = 70: what a wrong centre of mass does to the normal
    forces (docs/method.md §16).  The pooled K would be confidently wrong; the axle check says
    model_mismatch, why, and widens the band over both axles' soils."""
    est = BayesSoilEstimator()
    state = _feed_axles(est, 200.0, 70.0, 400)[-1]
    assert state.status == "model_mismatch" and "axles read different soils" in state.reason
    assert state.soil_class is None
    lo, hi = state.soil_strength - 2 * state.soil_strength_std, state.soil_strength + 2 * state.soil_strength_std
    assert lo <= 70.0 and hi >= 200.0


def test_axles_on_one_soil_and_a_front_first_terrain_change_are_no_mismatch():
    est = BayesSoilEstimator()
    rng = np.random.default_rng(4)
    states = _feed_axles(est, 200.0, 200.0, 300, rng=rng)
    # a change to sand that the front wheels reach 0.25 s before the rear ones (b / V at 1 m/s)
    states += _feed_axles(est, 50.0, lambda t: 200.0 if t < 3.25 else 50.0, 300, t0=3.0, rng=rng)
    assert not [s for s in states if "axles" in s.reason]
    assert states[-1].soil_strength == pytest.approx(50.0, rel=0.1)


def _small_slip_drive(est, k_true, seconds, t0=0.0, rng=None, slip=(0.04, 0.06), noise=0.008, stated=0.05):
    """A traction test at small slip: front wheels drive, rear brake, |S| sweeping ``slip``; the
    gross coefficient measured with ``noise`` but stated with the observer's larger 1-sigma
    ``stated`` (what the observer's covariance says on the robustness drives: 0.05 for a real 0.008)."""
    rng = rng or np.random.default_rng(5)
    states = []
    for i in range(int(seconds * 100)):
        a = slip[0] + (slip[1] - slip[0]) * 0.5 * (1 + math.sin(2 * math.pi * i / 300))
        s = a * np.array([-1.0, 1.0, 1.0, -1.0])
        obs = gross_traction(s, k_true) + rng.normal(0, noise, 4)
        states.append(est.update(t0 + i * 0.01, s, obs, np.full(4, stated**2), INFO, slip_sigma=np.full(4, 0.009),
                                 speed=1.0))
    return states


def test_stated_variance_above_the_scatter_does_not_pull_k_to_the_flattest_curve():
    """docs/method.md §9, "The likelihood's variance": the slip term (dh/dS sigma_S)^2 of each sample's
    variance is taken at the belief's median, the same for every K.  Evaluated per K, with a stated
    variance six times the real scatter, the density's 1/sigma(K) pulled firm soil (300) towards a
    weaker one as the slip fell to 0.04-0.06, where a flatter curve has the smaller variance."""
    est = BayesSoilEstimator()
    sweep = np.linspace(0.08, 0.3, 30)
    for i in range(300):  # 3 s of a clean sweep: K is learnt
        s = sweep[i % 30] * np.array([-1.0, 1.0, 1.0, -1.0])
        est.update(i * 0.01, s, gross_traction(s, 300.0), np.full(4, 1e-4), INFO, speed=1.0)
    states = _small_slip_drive(est, 300.0, 4.0, t0=3.0)
    ks = np.array([s.soil_strength for s in states])
    assert np.median(ks) == pytest.approx(300.0, rel=0.05) and ks.min() > 0.9 * 300.0


def _learn_hold_then(est, k_after, after_slip, seconds_after, hold=2.4, w_trace=None):
    """3 s of a clean sweep (|S| 0.08-0.3) on K = 300 at 1 m/s, ``hold`` s at S = 0.01 (nothing
    informs K while the robot travels on), then ``seconds_after`` of ``after_slip`` (a (4,) pattern)
    on K = k_after; the states after the hold (``w_trace``: P(no change) after each of them)."""
    sweep = np.linspace(0.08, 0.3, 30)
    t = 0.0
    for i in range(300):
        s = sweep[i % 30] * np.array([-1.0, 1.0, 1.0, -1.0])
        est.update(t, s, gross_traction(s, 300.0), np.full(4, 1e-4), INFO, speed=1.0)
        t += 0.01
    for _ in range(int(hold * 100)):
        s = np.full(4, 0.01)
        est.update(t, s, gross_traction(s, 300.0), np.full(4, 1e-4), INFO, speed=1.0)
        t += 0.01
    out = []
    for _ in range(int(seconds_after * 100)):
        s = np.asarray(after_slip)
        out.append(est.update(t, s, gross_traction(s, k_after), np.full(4, 0.05**2), INFO, speed=1.0))
        if w_trace is not None:
            w_trace.append(float(est.bank.w_stay[0]))
        t += 0.01
    return out


WEAK = 0.045 * np.array([-1.0, 1.0, 1.0, -1.0])
STRONG = 0.25 * np.array([-1.0, 1.0, 1.0, -1.0])


def test_weak_samples_after_a_hold_keep_the_learnt_soil():
    """docs/method.md §9, "Reporting across a possible change": after 2.4 m without information half
    the belief is the uniform change prior, and samples at |S| 0.045 that agree with the soil learnt
    before move the mixture's median far from it; the reported K stays within 15 % of it, and the
    band still includes a change."""
    pooled = _learn_hold_then(BayesSoilEstimator(config=SoilConfig(change_evidence=0.0)), 300.0, WEAK, 0.5)
    assert max(abs(s.soil_strength / 300.0 - 1) for s in pooled) > 0.15  # what change_confirm prevents
    states = _learn_hold_then(BayesSoilEstimator(), 300.0, WEAK, 0.5)
    assert all(abs(s.soil_strength / 300.0 - 1) <= 0.15 for s in states)


def test_a_change_after_a_hold_is_taken():
    """The same drive, but the soil after the hold is sand (K = 50) at |S| 0.25: the data take the
    change (the no-change belief restarts from the pooled one: P(no change) back to 1 from below
    1/2), and the reported K is within 15 % of the new soil no later than the pooled median, give
    or take 0.1 s.  Weakly agreeing samples (the test above) take none."""
    def first_within(states):
        return next(i for i, s in enumerate(states) if all(abs(x.soil_strength / 50.0 - 1) <= 0.15 for x in states[i:]))

    pooled = first_within(_learn_hold_then(BayesSoilEstimator(config=SoilConfig(change_evidence=0.0)), 50.0, STRONG, 2.0))
    w = []
    reported = first_within(_learn_hold_then(BayesSoilEstimator(), 50.0, STRONG, 2.0, w_trace=w))
    assert reported <= pooled + 10
    assert any(before < 0.5 and after == 1.0 for before, after in zip(w, w[1:])) or w[0] == 1.0
    kept = []
    _learn_hold_then(BayesSoilEstimator(), 300.0, WEAK, 0.5, w_trace=kept)
    assert all(x < 1.0 for x in kept)


def _belief_spread_after_one_second(rate_hz: float, k_true: float = 80.0) -> float:
    """ln K 1-sigma of the belief itself (no systematic term) after 1 s of the same clean sweep at rate_hz."""
    est = BayesSoilEstimator()
    n = int(round(rate_hz))
    for i in range(n + 1):
        s = np.full(4, 0.05 + 0.15 * i / n)
        est.update(i / rate_hz, s, gross_traction(s, k_true), np.full(4, 2.5e-3), INFO)
    p = est.p
    t16, t84 = np.interp((0.15865, 0.84135), np.cumsum(p) - 0.5 * p, est.theta)
    return (t84 - t16) / 2.0  # half the 16-84 % interval (moments: the change prior's tails)


def test_k_learns_per_second_not_per_sample():
    """docs/method.md §9, "Information per second": a 200 Hz log says what a 100 Hz one says about K in a
    second (a fixed exponent per sample: twice as much), and a 20 Hz log says less, its samples capped at
    temper_max (a fixed exponent: a fifth as much)."""
    s100, s200, s20 = (_belief_spread_after_one_second(r) for r in (100.0, 200.0, 20.0))
    assert s200 == pytest.approx(s100, rel=0.05)
    # 20 samples x 0.3 against 100 x 0.15 (1.26 here; a fixed exponent: 1.57; uncapped, 0.75 each: ~1)
    assert 1.1 < s20 / s100 < 1.4
