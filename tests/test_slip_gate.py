"""The compiled slip gate (soilocp/_core/src/soil/gate.rs, usability.rs) and soil classes (classes.rs) against
the numpy code they replaced (tests/reference_soil.py's ReferenceSlipGate, classify_many): every field equal, on random observer
outputs (hypothesis: refreshes, resets, reversals, lifted wheels, stamps that jump or go back) and step by
step on simulated drives whose slow wheel-speed stream makes refresh pairs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reference_soil import ReferenceRecords, ReferenceSlipGate
from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.estimation.soil_strength import SoilBank, SoilInputs
from tests.test_soil_core import _inputs
from soilocp.estimation.observer_bank import BLOCK_FIELDS, RESET_REASONS, ROWS, ObserverBlocks
from soilocp.estimation.pipeline import NormalForceStage, ObserverStage, PipelineConfig
from soilocp.estimation.slip_gate import GATE_FIELDS, SlipGate, pack_message, pack_output
from soilocp.estimation.soil_config import SoilConfig
from soilocp.model.vehicle import DEFAULT_VEHICLE

CONFIGS = {
    "default": PipelineConfig(),
    "net": PipelineConfig(soil=SoilConfig(measurement="net")),
    "no-smoothing": PipelineConfig(soil=SoilConfig(gate_smoothing=0.0)),
    "per-side": PipelineConfig(vehicle=DEFAULT_VEHICLE.model_copy(update={"drive": "per_side"})),
}


def _blocks(rows: dict, rejected, reset_reason) -> ObserverBlocks:
    """An observer output of named rows ((k, 4) or (k,) each, every core row), the rejections and reset reasons."""
    assert rows.keys() == ROWS.keys(), rows.keys() ^ ROWS.keys()
    blocks = [np.array([rows[f] for f in names], dtype=kind) for names, kind in zip(BLOCK_FIELDS, (float, float, bool, bool))]
    codes = [RESET_REASONS.index(r) + 1 if r else 0 for r in reset_reason]
    return ObserverBlocks(*blocks, np.asarray(rejected, dtype=np.int64), np.array(codes, dtype=np.uint8))


def _output(rng: np.random.Generator, k: int) -> ObserverBlocks:
    def quad(lo, hi, zero=0.2):
        a = rng.uniform(lo, hi, (k, 4))
        return np.where(rng.random((k, 4)) < zero, 0.0, a)

    interval = np.where(rng.random((k, 4)) < 0.4, rng.uniform(0.005, 1.5, (k, 4)), 0.0)
    ground = np.where(rng.random(k) < 0.2, rng.uniform(-0.03, 0.03, k), rng.uniform(-3.0, 3.0, k))
    return _blocks(dict(
        mu=quad(-1.2, 1.2), mu_var=quad(1e-6, 0.3), mu_determined=rng.random((k, 4)) < 0.8,
        resistance=quad(0.0, 0.2), gross=quad(-1.5, 1.5), gross_var=quad(1e-6, 0.3),
        wheel_speed=quad(-20.0, 20.0), ground_speed=ground, yaw_rate=rng.uniform(-2.5, 2.5, k) * (rng.random(k) < 0.6),
        reset=rng.random(k) < 0.1,
        normal_force=quad(-50.0, 900.0, 0.05), speed_age=quad(0.0, 0.2), torque_age=quad(0.0, 0.2),
        ground_speed_age=rng.uniform(0.0, 1.0, k), ground_speed_measured=rng.random(k) < 0.85,
        ground_speed_latency=np.zeros(k), ground_speed_excess=np.where(rng.random(k) < 0.5, 0.0, rng.uniform(0.0, 0.1, k)),
        interval=interval, interval_gross=quad(-1.5, 1.5),
        interval_gross_var=quad(1e-6, 0.3), interval_rim_start=quad(-3.0, 3.0), interval_rim_end=quad(-3.0, 3.0),
        interval_ground_start=quad(-3.0, 3.0), interval_ground_end=quad(-3.0, 3.0),
        interval_rim_sigma=quad(0.0, 0.05), interval_learning=rng.random((k, 4)) < 0.3,
        speed_rejected=rng.random((k, 4)) < 0.2,
    ), np.zeros(k, dtype=int), [""] * k)


#: the low-pass's weight 1 - e^(-dt / tau) is libm's expm1 in the core; numpy's (SVML on AVX-512 machines)
#: differs from it in the last bit on ~5 % of arguments.  The low-pass slip and its 1-sigma are only compared
#: with the gate's thresholds (soil/bank.rs wheel_flags), so the records do not see it; every other field is
#: equal bit for bit.
LOW_PASS = {"gate_slip", "gate_sigma"}


def _same(a, b, what: str) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is None or y is None:
            assert x is None and y is None, f"{what}: {f.name} {x} vs {y}"
        elif f.name in LOW_PASS:
            np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-14, err_msg=f"{what}: {f.name}")
        else:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=f"{what}: {f.name}")


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), steps=st.integers(1, 8),
       config=st.sampled_from(sorted(CONFIGS)))
def test_core_gate_equals_the_numpy_gate_on_random_outputs(seed, n, steps, config):
    rng = np.random.default_rng(seed)
    cfg = CONFIGS[config]
    core, ref = SlipGate(cfg, n), ReferenceSlipGate(cfg, n)
    stamp = np.zeros(n)
    for step in range(steps):
        ix = np.sort(rng.choice(n, size=rng.integers(1, n + 1), replace=False))
        stamp[ix] += np.where(rng.random(ix.size) < 0.15, rng.uniform(-0.2, 1.6, ix.size), rng.uniform(0.005, 0.05, ix.size))
        ob = _output(rng, ix.size)
        _same(core.step(ix, stamp[ix], ob), ref.step(ix, stamp[ix], ob), f"step {step}")
    np.testing.assert_allclose(core.core.lp, ref._lp, rtol=1e-13, atol=1e-14)
    np.testing.assert_array_equal(core.core.lp_stamp, ref._lp_stamp)


@pytest.mark.parametrize("variant", ["wheel-speed-5hz", "nominal"])
def test_core_gate_equals_the_numpy_gate_step_by_step_on_a_drive(variant):
    from soilocp.sim.variants import get_variant

    cfg = PipelineConfig()
    normal, observer = NormalForceStage(cfg), ObserverStage(cfg)
    core, ref = SlipGate(cfg, 1), ReferenceSlipGate(cfg, 1)
    ix = np.zeros(1, dtype=int)
    refreshes = 0
    for sample, _ in get_variant(variant).simulate(0, duration=6.0):
        msg = observer.step(sample, normal.step(sample))
        rows = pack_message(msg)
        ob = _blocks({f: [getattr(msg, f)] for f in ROWS}, [msg.rejected_measurements], [msg.reset_reason])
        np.testing.assert_array_equal(np.array([rows], dtype=float), pack_output(ob))
        stamp = np.array([msg.stamp])
        a, b = core.step(ix, stamp, rows), ref.step(ix, stamp, ob)
        _same(a, b, f"{variant} #{msg.seq}")
        refreshes += a.span is not None
    assert refreshes > 10 if variant == "wheel-speed-5hz" else refreshes == 0


def test_packed_rows_follow_the_core_layout():
    from soilocp import _core

    # the observer's 17 per-wheel rows and the gate's 2 flags, 4 columns each, then 6 per-vehicle numbers
    cols = _core.SlipGateBank.columns
    assert len(GATE_FIELDS) == 25 and cols == 19 * 4 + 6
    gate = SlipGate(PipelineConfig(), 2)
    with pytest.raises(ValueError, match="rows"):
        gate.step(np.array([0]), np.array([0.0]), np.zeros((1, cols - 1)))
    for idx in ([1, 1], [2], [-1]):
        with pytest.raises(ValueError, match=r"idx must be distinct vehicle indices in \[0, 2\)"):
            gate.step(np.array(idx), np.zeros(len(idx)), np.zeros((len(idx), cols)))


def test_a_rejected_wheel_speed_informs_no_k():
    """docs/method.md §18: a wheel whose new speed reading the observer's gate rejected has a predicted slip; it
    is not informative, the same wheel without the flag is."""
    cfg = PipelineConfig()
    r = cfg.vehicle.wheel_radius

    def gated(rejected, speed_age=0.0):
        ob = _blocks(dict(
            mu=np.full((1, 4), 0.5), mu_var=np.full((1, 4), 1e-3), mu_determined=np.ones((1, 4), bool),
            resistance=np.full((1, 4), 0.05), gross=np.full((1, 4), 0.55), gross_var=np.full((1, 4), 1e-3),
            wheel_speed=np.full((1, 4), 1.0 / (0.8 * r)), ground_speed=np.array([1.0]), yaw_rate=np.zeros(1),
            reset=np.zeros(1, bool), normal_force=np.full((1, 4), 150.0), speed_age=np.full((1, 4), speed_age),
            torque_age=np.zeros((1, 4)), ground_speed_age=np.zeros(1), ground_speed_measured=np.ones(1, bool),
            ground_speed_latency=np.zeros(1), ground_speed_excess=np.zeros(1), interval=np.zeros((1, 4)), interval_gross=np.zeros((1, 4)),
            interval_gross_var=np.zeros((1, 4)), interval_rim_start=np.zeros((1, 4)), interval_rim_end=np.zeros((1, 4)),
            interval_ground_start=np.zeros((1, 4)), interval_ground_end=np.zeros((1, 4)),
            interval_rim_sigma=np.zeros((1, 4)), interval_learning=np.zeros((1, 4), bool),
            speed_rejected=np.array([rejected]),
        ), [int(sum(rejected))], [""])
        out = SlipGate(cfg, 1).step(np.zeros(1, dtype=int), np.zeros(1), ob)
        np.testing.assert_allclose(out.slip[0], 0.2, rtol=1e-12)
        return out.informative[0].tolist(), out.held[0].tolist()

    assert gated([False] * 4) == ([True] * 4, [False] * 4)
    assert gated([False, True, True, False]) == ([True, False, False, True], [False] * 4)
    # a held wheel (its speed reading older than soil.fresh_age) informs no K by being held, and keeps that
    # reason whether or not its prediction left the reading: informative, held, as without the flag
    age = 2 * cfg.soil.fresh_age
    assert gated([False] * 4, age) == gated([True] * 4, age) == ([True] * 4, [True] * 4)


def test_the_blocks_and_the_messages_pack_alike():
    """pack_output on a bank step's blocks (the batched path) and pack_message on each vehicle's message (the
    soil service's) give the same rows, every column the observer row of its name."""
    from soilocp import _core
    from soilocp.estimation.observer_bank import ObserverBank, ObserverInputs, observer_message

    bank = ObserverBank(DEFAULT_VEHICLE, None, 3)
    rng = np.random.default_rng(2)
    for n in range(30):
        k = 3
        out = bank.step(None, ObserverInputs(
            np.full(k, 1.0 + 0.01 * n), rng.normal(0, 0.5, k), rng.normal(0, 0.1, k), np.zeros(k),
            rng.uniform(3.0, 5.0, (k, 4)), rng.uniform(0.0, 8.0, (k, 4)),
            np.where(rng.random(k) < 0.3, np.nan, rng.uniform(0.5, 0.8, k)), np.full((k, 4), 150.0)))
        rows = pack_output(out)
        assert rows.shape == (k, _core.SlipGateBank.columns) and rows.dtype == np.float64 and rows.flags.c_contiguous
        for j in range(k):
            msg = observer_message("v", n, 1.0 + 0.01 * n, out, j)
            assert list(rows[j]) == list(pack_message(msg)), (n, j)
            want = [x for f in GATE_FIELDS for x in np.atleast_1d(getattr(out, f)[j]).astype(float)]
            assert list(rows[j]) == want, (n, j)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_core_soil_classes_equal_the_numpy_classes(seed):
    from reference_soil import classify_many as reference
    from soilocp.estimation.soil_state import classify_many

    rng = np.random.default_rng(seed)
    log_k = rng.uniform(0.0, 9.5, 300)
    log_k_std = rng.choice([0.0, 1e-8, 0.01, 0.13, 0.5, 3.0], 300) * rng.uniform(0.0, 1.0, 300)
    names, conf = classify_many(log_k, log_k_std, DEFAULT_CONSTANTS)
    want_names, want_conf = reference(log_k, log_k_std, DEFAULT_CONSTANTS)
    assert names == want_names
    np.testing.assert_array_equal(conf, want_conf)


class _Recording:
    """The core bank, its ``step`` arrays kept for the reference records."""

    def __init__(self, core):
        self._core, self.last = core, None

    def __getattr__(self, name):
        return getattr(self._core, name)

    def step(self, *args):
        self.last = self._core.step(*args)
        return self.last


def _worded(states):
    """The states as the reference words them (it has the reasons' texts, not their codes): each state's
    code checked against its text (a code exactly when there is a reason), then left out."""
    import dataclasses

    for st in states:
        assert (st.reason_code == "none") == (st.reason == ""), st
    return [dataclasses.replace(st, reason_code="none") for st in states]


#: The records' numbers against the reference's: the core's band takes libm's hypot where the reference takes
#: CPython's math.hypot, which differ in the last bit on some arguments
RECORD_RTOL = 1e-12


def _assert_records_close(got, want, what) -> None:
    """Every field of the records equal, their floats within RECORD_RTOL (NaN and None as themselves)."""
    import dataclasses

    assert len(got) == len(want), (what, got, want)
    for a, b in zip(got, want):
        for f in dataclasses.fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if isinstance(x, float) and isinstance(y, float):
                assert x == pytest.approx(y, rel=RECORD_RTOL, abs=1e-300, nan_ok=True), (what, f.name, x, y)
            else:
                assert x == y, (what, f.name, x, y)


@pytest.mark.parametrize("variant", ["skid-spot-turn", "wheel-speed-5hz", "payload+25", "mass-com+20", "nominal"])
def test_core_records_equal_the_python_records_step_by_step(variant):
    """The records (soilocp/_core/src/soil/status.rs: K held or withdrawn, band, status, reason, class) against
    the Python that made them before (tests/reference_soil.py's ReferenceRecords) on the same core steps."""
    from soilocp.sim.variants import get_variant

    cfg = PipelineConfig()
    variant_ = get_variant(variant)
    normal, observer = NormalForceStage(cfg), ObserverStage(cfg)
    gate, bank = SlipGate(cfg, 1), SoilBank(cfg.constants, cfg.soil, 1)
    bank.core = recording = _Recording(bank.core)
    ref = ReferenceRecords(bank)
    ix = np.zeros(1, dtype=int)
    statuses = set()
    for sample, _ in variant_.simulate(0, duration=12.0, nominal=cfg.vehicle, constants=cfg.constants):
        msg = observer.step(sample, normal.step(sample))
        stamp = np.array([msg.stamp])
        inp = gate.step(ix, stamp, pack_message(msg))
        sigma = None if msg.torque_scale_std is None else np.array([msg.torque_scale_std])
        got = bank.update(ix, stamp, inp, sigma)
        codes = np.asarray(inp.unusable, dtype=np.int64)
        want = ref.summaries(ix, stamp, recording.last, inp, codes if codes.any() else None)
        _assert_records_close(_worded(got), want, (variant, msg.seq))
        statuses.add(got[0].status)
    assert len(statuses) >= 2, statuses


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), steps=st.integers(1, 80), refresh=st.booleans(), codes=st.booleans(),
       online_scale=st.booleans())
def test_core_records_equal_the_python_records_on_random_sequences(seed, steps, refresh, codes, online_scale):
    """As the drive test, on tests/test_soil_core.py's random sequences (k of N vehicles, stamps that repeat,
    jump and go back, held, unidentifiable and unusable wheels, refresh pairs, an online scale)."""
    n = 3
    bank = SoilBank(DEFAULT_CONSTANTS, SoilConfig(), n)
    bank.core = recording = _Recording(bank.core)
    ref = ReferenceRecords(bank)
    rng = np.random.default_rng(seed)
    clock = np.zeros(n)
    for _ in range(steps):
        k = int(rng.integers(1, n + 1))
        ix = np.sort(rng.choice(n, k, replace=False))
        clock[ix] += rng.choice([0.01, 0.01, 0.05, 0.0, -0.02, 2.0, 11.0], k)
        stamp = clock[ix].copy()
        inp = _inputs(rng, k, refresh, codes)
        if codes:
            inp.unusable = np.where(rng.random((k, 4)) < 0.1, rng.integers(1, 5, (k, 4)), inp.unusable)
        sigma = rng.uniform(0.0, 0.08, k) if online_scale else None
        got = bank.update(ix, stamp, inp, sigma)
        c = None if inp.unusable is None or not np.asarray(inp.unusable).any() else np.asarray(inp.unusable, np.int64)
        _assert_records_close(_worded(got), ref.summaries(ix, stamp, recording.last, inp, c), seed)


def test_one_call_equals_gate_then_update_and_a_refused_step_moves_nothing():
    """The soil stage's one core call (the chain's update, as Estimator.update makes it: gate, update, records)
    against the two-call path (SlipGate.step, then SoilBank.update) on a drive; and a step the core refuses (a
    non-finite packed row, a scale sigma of the wrong length) leaves the gate's low-pass and the beliefs as they
    were."""
    from soilocp.estimation.estimator import Estimator
    from soilocp.sim.variants import get_variant

    cfg = PipelineConfig()
    normal, observer = NormalForceStage(cfg), ObserverStage(cfg)
    one = Estimator(cfg, 1)
    two_gate, two_bank = SlipGate(cfg, 1), SoilBank(cfg.constants, cfg.soil, 1)
    ix = np.zeros(1, dtype=int)

    def one_call(stamp, rows, scale_sigma=None):
        fields, report = one.chain.update(ix, stamp, rows, scale_sigma, None)
        inp = SoilInputs(*fields)
        return inp, one.soil.states(ix, stamp, inp, report)

    refused = 0
    for n, (sample, _) in enumerate(get_variant("nominal").simulate(0, duration=6.0)):
        msg = observer.step(sample, normal.step(sample))
        rows, stamp = np.array([pack_message(msg)], dtype=float), np.array([msg.stamp])
        if n % 97 == 50:  # a bad step between good ones
            lp, lp_stamp, belief = one.gate.core.lp, one.gate.core.lp_stamp, one.soil.core.p.copy()
            bad = rows.copy()
            bad[0, 4 * GATE_FIELDS.index("gross")] = np.nan  # the gross traction the soil update reads
            for args in ((bad, None), (rows, np.array([0.01, 0.02]))):
                with pytest.raises(ValueError):
                    one_call(stamp, *args)
                refused += 1
            np.testing.assert_array_equal(one.gate.core.lp, lp)
            np.testing.assert_array_equal(one.gate.core.lp_stamp, lp_stamp)
            np.testing.assert_array_equal(one.soil.core.p, belief)
        inp_one, got = one_call(stamp, rows)
        inp_two = two_gate.step(ix, stamp, rows)
        want = two_bank.update(ix, stamp, inp_two)
        _same(inp_one, inp_two, f"#{msg.seq}")
        assert got == want, (msg.seq, got, want)
    assert refused >= 4
