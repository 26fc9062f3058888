"""The online torque scale in the compiled core (soilocp/_core/src/torque_scale/) against the numpy kernel it
replaced (tests/reference_torque_scale.py): every output, k, F_MR and their covariance equal to the bit,
on random drives (hypothesis), on simulated drives through the pipeline and on a real Warthog log; and the
core's named errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import soilocp.estimation.batch as batch_module
import soilocp.estimation.estimator as estimator_module
import soilocp.estimation.pipeline as pipeline_module
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.torque_scale import TorqueScaleBank, TorqueScaleConfig
from soilocp.model.force_balance import longitudinal_balance, modelled_resistance
from soilocp.model.normal_force import gravity_from_attitude
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.variants import get_variant

import reference_torque_scale as ref
from test_torque_scale import ChainScale, scale_inputs

V = DEFAULT_VEHICLE


def _same(a, b) -> bool:
    """Equal to the bit, NaN where NaN."""
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def _drive(rng, n_steps: int, k_true: float, accel: float, p_bad: float, reverse: bool):
    """A drive that mostly satisfies eq. TC (torque = k_true x logged, F_MR 25 N, small slips), with bad
    samples (turning, slipping, slow, gaps, stamps that stand still, no ground speed, torque glitches) at rate
    p_bad: what passes the observer's input check, which the chain runs before the scale."""
    t, out = 0.0, []
    w = 2.0 * math.pi / rng.uniform(2.0, 6.0)
    sign = -1.0 if reverse else 1.0
    for i in range(n_steps):
        dt = 0.01
        a = accel * math.sin(w * t)
        v = sign * (1.0 + accel / w * (1.0 - math.cos(w * t)))
        slip = rng.uniform(-0.05, 0.08, 4)
        omega = v / V.wheel_radius * (1.0 + slip)
        od = 4.0 * a / V.wheel_radius
        torque = (V.mass * a + 25.0) * V.wheel_radius + V.wheel_inertia * od
        s = dict(stamp=t, f_x=a + rng.normal(0, 0.05), pitch=rng.normal(0, 0.05), yaw=rng.normal(0, 0.02),
                 ws=omega, tq=np.full(4, torque / k_true / 4.0) + rng.normal(0, 0.1, 4),
                 gs=v + rng.normal(0, 0.01), fz=np.full(4, V.mass * 9.80665 / 4.0) + rng.normal(0, 5.0, 4))
        if rng.random() < p_bad:
            kind = rng.integers(0, 7)
            if kind == 0:
                s["yaw"] = 0.5
            elif kind == 1:
                s["ws"] = s["ws"] * 1.5
            elif kind == 2:
                s["gs"] = 0.05
            elif kind == 3:
                dt = 0.4  # a gap restarts the window
            elif kind == 4:
                dt = 0.0  # a stamp that does not advance
            elif kind == 5:
                s["gs"] = math.nan  # no ground speed: the rims' mean
            else:
                s["tq"] = s["tq"] * 3.0  # a torque glitch
        t += dt
        s["stamp"] = t
        out.append(s)
    return out


def _run_both(samples_per_vehicle, cfg, prior_sigma, rng, feed: bool, with_ref: bool = False):
    n = len(samples_per_vehicle)
    assert prior_sigma == SoilConfig().gross_scale_sigma  # the estimator's scale prior
    bank = ChainScale(cfg, n)
    core = bank.scale
    numpy_ = ref.ReferenceTorqueScale(V, cfg, prior_sigma, n)
    learnt = 0
    for j in range(len(samples_per_vehicle[0])):
        ix = np.flatnonzero(rng.random(n) < 0.8)
        if ix.size == 0:
            continue
        rows = [samples_per_vehicle[i][j] for i in ix]
        args = [np.array([r[k] for r in rows], dtype=float) for k in ("stamp", "f_x", "pitch", "yaw", "ws", "tq", "gs")]
        fz = np.array([r["fz"] for r in rows])
        m1, s1 = bank.step(ix, scale_inputs(*args, fz))
        m2, s2 = numpy_.step(ix, *args, fz)
        assert _same(m1, m2) and _same(s1, s2), (j, m1, m2, s1, s2)
        learnt += int(np.any(m1 != 1.0))
        if feed and rng.random() < 0.5:
            k = rng.choice([np.nan, -1.0, 40.0, 120.0, 400.0], ix.size)
            slip = rng.normal(0, 0.1, (ix.size, 4))
            slip[rng.random((ix.size, 4)) < 0.3] = np.nan
            bank.feed(ix, k, slip)
            numpy_.feed_soil(ix, list(k), slip)
    assert _same(core.theta, numpy_.theta) and _same(core.P, numpy_.P)
    assert _same(core.band_sigma(np.sqrt(core.P[:, 0, 0])), numpy_.band_sigma(np.sqrt(numpy_.P[:, 0, 0])))
    return (learnt, numpy_) if with_ref else learnt


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), k_true=st.floats(0.7, 1.3),
       accel=st.sampled_from([0.0, 0.3, 0.8, 1.2]), p_bad=st.sampled_from([0.0, 0.002, 0.02, 0.2]),
       model=st.booleans(), prior=st.sampled_from([None, 0.10, 0.15]), window=st.sampled_from([0.5, 1.0]),
       reverse=st.booleans())
def test_the_core_is_the_numpy_kernel_on_random_drives(seed, n, k_true, accel, p_bad, model, prior, window,
                                                        reverse):
    rng = np.random.default_rng(seed)
    cfg = TorqueScaleConfig(model_resistance=model, prior_sigma=prior, window=window)
    drives = [_drive(rng, 800, k_true, accel, p_bad, reverse) for _ in range(n)]
    _run_both(drives, cfg, 0.05, rng, feed=True)


def test_the_random_drives_exercise_learning():
    """The property above is not vacuous: its drives close windows that inform k, and some are taken as jumps of
    F_MR (the fed-back K moves the modelled resistance), some of them adjoining the previous window, which is then
    taken back (docs/method.md §15, "A jump is a mixed window"), while k is not 1 (the inertia term's 1 / rho)."""
    rng = np.random.default_rng(1)
    learnt, numpy_ = _run_both([_drive(rng, 1500, 0.8, 0.8, 0.002, False)], TorqueScaleConfig(model_resistance=True),
                               0.05, rng, feed=True, with_ref=True)
    assert learnt > 500
    assert numpy_.jumps.sum() > 0
    assert numpy_.taken_back.sum() > 0


class _Checked(TorqueScaleBank):
    """The product's bank with the numpy reference beside it, fed the same inputs (the estimator steps the
    core's bank inside its chain calls: _checked_chain, _checked_observe)."""

    calls: list = []

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.ref = ref.ReferenceTorqueScale(*args, **kw)
        self.slot = len(_Checked.calls)
        _Checked.calls.append([0, 0])

    def check(self, ix, inputs):
        """The reference takes the step's logged inputs; returns its relative 1-sigma (None: at the prior)."""
        _, want_sigma = self.ref.apply_arrays(np.asarray(ix), inputs.stamp, inputs.specific_force_x, inputs.pitch,
                                              inputs.yaw_rate, inputs.wheel_speed, inputs.wheel_torque,
                                              inputs.ground_speed, inputs.normal_force)
        _Checked.calls[self.slot][0] += 1
        _Checked.calls[self.slot][1] += int(want_sigma is not None)
        return want_sigma


_chain_step = estimator_module.Estimator.step_all
_observe = estimator_module.Estimator.observe
_feed = estimator_module.Estimator.feed


def _checked_chain(self, idx, samples, normal_forces):
    """Estimator.step_all, whose one core call steps the scale inside the chain: the reference takes the
    same logged inputs first, the states must then be its to the bit, and it is fed the records' K and slips."""
    ix = np.asarray(idx)
    scale = self.scale
    scale.check(ix, pipeline_module.observer_inputs(samples, normal_forces))
    ob, soils, ocps = _chain_step(self, idx, samples, normal_forces)
    assert _same(scale.theta, scale.ref.theta) and _same(scale.P, scale.ref.P)
    ks = np.array([np.nan if s.soil_strength is None else s.soil_strength for s in soils])
    scale.ref.feed_soil(ix, ks, np.array([s.slip for s in soils], dtype=float))
    return ob, soils, ocps


def _checked_observe(self, j, sample, forces):
    """Estimator.observe (the observer stage): the scale's state and the torque scale the message carries are
    the reference's to the bit."""
    want_sigma = self.scale.check([j], pipeline_module.observer_inputs([sample], [forces.normal_force]))
    out = _observe(self, j, sample, forces)
    scale = self.scale
    assert _same(scale.theta, scale.ref.theta) and _same(scale.P, scale.ref.P)
    assert (out.torque_scale_std is None) == (want_sigma is None)
    assert want_sigma is None or (out.torque_scale_std == want_sigma[0] and out.torque_scale == scale.ref.theta[j, 0])
    return out


def _checked_feed(self, j, soil):
    """Estimator.feed (the soil estimate back to the scale): the reference is fed the same K and slips."""
    _feed(self, j, soil)
    if self.feeds_soil:
        k = np.array([np.nan if soil.soil_strength is None else soil.soil_strength])
        self.scale.ref.feed_soil(np.array([j]), k, np.array([soil.slip], dtype=float))


@pytest.fixture()
def checked(monkeypatch):
    _Checked.calls = []
    monkeypatch.setattr(estimator_module, "TorqueScaleBank", _Checked)
    monkeypatch.setattr(estimator_module.Estimator, "step_all", _checked_chain)
    monkeypatch.setattr(estimator_module.Estimator, "observe", _checked_observe)
    monkeypatch.setattr(estimator_module.Estimator, "feed", _checked_feed)
    return _Checked.calls


@pytest.mark.parametrize("variant", ["payload+25-accel-brake", "motor+8-accel-brake", "reverse-braking",
                                     "slope-cruise-12"])
@pytest.mark.parametrize("model", [False, True])
def test_the_core_is_the_numpy_kernel_step_by_step_on_simulated_drives(checked, variant, model):
    """Through the pipeline (the live stages' code), the soil stage's K and slips fed back."""
    cfg = pipeline_module.PipelineConfig(torque_scale=TorqueScaleConfig(model_resistance=model))
    pipe = pipeline_module.VehiclePipeline(cfg)
    for s, _ in get_variant(variant).simulate(0, duration=12.0):
        pipe.process_all(s)
    steps, learnt = checked[0]
    assert steps > 1000
    if variant.endswith("accel-brake"):
        assert learnt > 100  # k learnt: the torques were scaled


def test_the_core_is_the_numpy_kernel_in_the_batched_path(checked):
    from soilocp.estimation.batch import BatchPipeline
    from soilocp.model.normal_force import NormalForceSolver

    cfg = pipeline_module.PipelineConfig(torque_scale=TorqueScaleConfig(model_resistance=True))
    drives = [[s for s, _ in get_variant(v).simulate(0, duration=6.0)] for v in ("payload+25-accel-brake", "nominal",
                                                                                  "reverse")]
    batch = BatchPipeline(cfg, 3)
    solver = NormalForceSolver(cfg.vehicle)
    rng = np.random.default_rng(0)
    for j in range(min(len(d) for d in drives)):
        ix = np.flatnonzero(rng.random(3) < 0.9)
        if ix.size:
            samples = [drives[i][j] for i in ix]
            batch.step(ix, samples, list(solver(np.array([s.specific_force for s in samples]))))
    assert checked[0][0] > 400


def test_the_core_is_the_numpy_kernel_on_a_real_log(checked):
    """The first 1500 records of a Warthog log (skid steer, held readings, a current of unknown scale)."""
    real = pytest.importorskip("test_real_logs")
    if not real.WARTHOG.is_dir():
        pytest.skip("real logs not present (shared/data/real)")
    from soilocp.estimation.estimate import EstimateSummary, estimate_lines

    lines = (real.WARTHOG / "warthog_asphalt_20240925.jsonl").read_text().splitlines()[:1500]
    cfg = real.warthog_config()
    cfg = cfg.model_copy(update={"torque_scale": TorqueScaleConfig(model_resistance=True)})
    recs = list(estimate_lines(lines, cfg, summary=EstimateSummary()))
    assert len(recs) == len(lines) and sum(c[0] for c in checked) == len(lines)


def test_eq_tc_and_eq_20_are_the_core_and_the_reference():
    rng = np.random.default_rng(4)
    f_x, od, tq, res = (rng.normal(0, 1, 50), rng.normal(0, 10, 50), rng.normal(0, 20, 50), rng.normal(0, 30, 50))
    for r in (None, res):
        got, want = longitudinal_balance(f_x, od, tq, V, r), ref.longitudinal_balance(f_x, od, tq, V, r)
        assert _same(got[0], want[0]) and _same(got[1], want[1])
    x, y = longitudinal_balance(0.5, 4.0, 12.0, V)  # scalars stay scalars
    assert x.shape == () and y.shape == ()
    slip, fz = rng.normal(0, 0.2, (50, 4)), rng.uniform(50, 300, (50, 4))
    k, d = rng.uniform(20, 500, 50), np.where(rng.random(50) < 0.5, -1.0, 1.0)
    assert _same(modelled_resistance(slip, k, fz, d), ref.modelled_resistance(slip, k, fz, d))
    roll, pitch = rng.uniform(-1, 1, (7, 3)), rng.uniform(-1, 1, (7, 3))
    assert _same(gravity_from_attitude(roll, pitch), ref.gravity_from_attitude(roll, pitch))
    assert gravity_from_attitude(0.1, 0.2).shape == (3,)
    assert _same(gravity_from_attitude(0.1, pitch[0]), ref.gravity_from_attitude(0.1, pitch[0]))


def test_bad_calls_are_named():
    bank = ChainScale(TorqueScaleConfig(), 2)
    one = [np.zeros(1)] * 4
    with pytest.raises(ValueError, match=r"idx must be distinct vehicle indices in \[0, 2\), got \[2\]"):
        bank.step(np.array([2]), scale_inputs(*one, np.zeros((1, 4)), np.zeros((1, 4)), np.zeros(1)))
    with pytest.raises(ValueError, match="distinct"):
        bank.step(np.array([1, 1]), scale_inputs(*[np.zeros(2)] * 4, np.zeros((2, 4)), np.zeros((2, 4)), np.zeros(2)))
    x = scale_inputs(*one, np.zeros((1, 4)), np.zeros((1, 4)), np.zeros(1))
    x.wheel_torque = np.zeros((1, 3))
    with pytest.raises(ValueError, match=r"inputs.wheel_torque must be a finite array of shape \(1, 4\)"):
        bank.step(np.array([0]), x)
    x.wheel_torque, x.specific_force_x = np.zeros((1, 4)), np.array([np.nan])
    with pytest.raises(ValueError, match="inputs.specific_force_x must be a finite array"):
        bank.step(np.array([0]), x)
    assert _same(bank.scale.theta, np.tile([1.0, 0.0], (2, 1)))  # refused before any vehicle stepped
    with pytest.raises(ValueError, match=r"k must have shape \(2,\)"):
        ChainScale(TorqueScaleConfig(model_resistance=True), 2).feed([0, 1], [1.0], np.zeros((2, 4)))
    with pytest.raises(ValueError, match="soil_strength"):
        modelled_resistance(np.zeros((1, 4)), [0.0], np.ones((1, 4)), [1.0])
    with pytest.raises(ValueError, match="broadcast"):
        longitudinal_balance(np.zeros(3), np.zeros(2), 0.0, V)
