"""The compiled soil-grid update (soilocp._core.SoilGridBank, soilocp/_core/src/soil/) against the numpy
reference it replaced (tests/reference_soil.py), step by step on random sequences: k of N vehicles per
step, stamps that repeat and go backwards, slips of both signs and inside the zero-slip bridge, held and
unusable wheels, refresh intervals with slip paths, an online torque-scale 1-sigma, both measurements."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.model.traction import gross_traction
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.soil_state import SoilInputs
from soilocp.estimation.soil_strength import SoilBank
from tests.reference_soil import ReferenceSoilBank

N = 3
#: relative agreement of every number: the core's exp / log are libm's, numpy's are its SIMD ones (last bit), and
#: the core sums the grid in eight lanes where numpy splits it pairwise (the last bits of a sum of 241 terms)
REL = 1e-9
#: a decision whose deciding number lies this close to its threshold is a tie that rounding decides: the change
#: test (no-change weight w_stay < 1/2 and stay log-likelihood ratio < 0) right after the two beliefs were equal
TIE = 1e-9


def _tie(w_stay: float, stay_llr: float) -> bool:
    """The change test at (w_stay, stay_llr) is within TIE of flipping."""
    return (abs(stay_llr) <= TIE and w_stay < 0.5 + TIE) or (abs(w_stay - 0.5) <= TIE and stay_llr < TIE)


def _inputs(rng, k: int, refresh: bool, codes: bool) -> SoilInputs:
    slip = rng.uniform(-0.6, 0.6, (k, 4)) * (rng.random((k, 4)) < 0.9)
    slip[rng.random((k, 4)) < 0.05] = 0.003  # inside the bridge
    k_true = np.exp(rng.uniform(np.log(20.0), np.log(2000.0)))
    obs = gross_traction(slip, k_true) * rng.uniform(0.8, 1.2) + 0.02 * rng.standard_normal((k, 4))
    span = slip_ends = None
    if refresh:
        span = np.where(rng.random((k, 4)) < 0.5, rng.uniform(0.05, 0.5, (k, 4)), 0.0)
        slip_ends = slip[:, :, None] + rng.uniform(-0.1, 0.1, (k, 4, 2))
        slip_ends[rng.random((k, 4)) < 0.1] = np.nan
    return SoilInputs(
        slip=slip, informative=rng.random((k, 4)) < 0.85, observed=obs,
        variance=rng.choice([1e-4, 2.5e-3, 0.01, 0.2], (k, 4)), slip_sigma=rng.uniform(0.002, 0.02, (k, 4)),
        gate_slip=slip + 0.01 * rng.standard_normal((k, 4)), gate_sigma=rng.uniform(0.001, 0.01, (k, 4)),
        held=rng.random((k, 4)) < 0.05, ground_stale=rng.random(k) < 0.03, identifiable=rng.random(k) < 0.97,
        speed=np.where(rng.random(k) < 0.1, np.nan, rng.uniform(-2.0, 2.0, k)), span=span, slip_ends=slip_ends,
        unusable=np.where(rng.random((k, 4)) < 0.05, 2, 0) if codes else None)


def _close(name, got, want, atol=1e-12):
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert np.array_equal(np.isnan(got), np.isnan(want)), name
    ok = ~np.isnan(want)
    assert np.allclose(got[ok], want[ok], rtol=REL, atol=atol), (name, np.abs(got - want).max(), got, want)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), steps=st.integers(1, 60), measurement=st.sampled_from(["gross", "net"]),
       change_evidence=st.sampled_from([1.0, 0.0]), stay_forgetting=st.sampled_from([0.5, 0.0]),
       refresh=st.booleans(), codes=st.booleans(), online_scale=st.booleans())
def test_core_update_equals_the_numpy_reference(seed, steps, measurement, change_evidence, stay_forgetting, refresh,
                                                codes, online_scale):
    cfg = SoilConfig(measurement=measurement, change_evidence=change_evidence, stay_forgetting=stay_forgetting)
    bank, ref = SoilBank(DEFAULT_CONSTANTS, cfg, N), ReferenceSoilBank(DEFAULT_CONSTANTS, cfg, N)
    rng = np.random.default_rng(seed)
    clock = np.zeros(N)
    for _ in range(steps):
        k = int(rng.integers(1, N + 1))
        ix = np.sort(rng.choice(N, k, replace=False))
        clock[ix] += rng.choice([0.01, 0.01, 0.05, 0.0, -0.02, 2.0], k)
        stamp = clock[ix].copy()
        inp = _inputs(rng, k, refresh, codes)
        sigma = rng.uniform(0.0, 0.08, k) if online_scale else None
        want = ref.update(ix, stamp, inp.slip, inp.observed, inp.variance, inp.informative, inp.slip_sigma,
                          inp.gate_slip, inp.gate_sigma, inp.held, inp.identifiable, inp.speed, inp.ground_stale,
                          inp.span, inp.slip_ends, sigma, inp.unusable)
        codes_in = None if inp.unusable is None or not inp.unusable.any() else inp.unusable
        got = bank.core.step(ix.astype(np.int64), stamp, inp.arrays(k), codes_in, sigma)
        wheel, dt, info, taken, k_report, log_stat, stats, scale, axle_off, axle, floor_cdf = got
        if not np.array_equal(taken, want["taken"]):
            # the two took different decisions on a change: only a tie may do that, and from there the two
            # sequences are different sequences (the one that took restarted its no-change belief)
            for j in np.flatnonzero(taken != want["taken"]):
                i = ix[j]
                kept = bank.core if not taken[j] else ref  # the one that did not take: its numbers are the test's
                w, llr = float(np.asarray(kept.w_stay)[i]), float(np.asarray(kept.stay_llr)[i])
                assert _tie(w, llr), (i, w, llr)
            return
        assert np.array_equal((wheel & 1) > 0, want["use"])
        assert np.array_equal((wheel & 2) > 0, want["undetermined"])
        assert np.array_equal((wheel & 4) > 0, want["held"])
        assert np.array_equal(info, want["info"]) and np.array_equal(taken, want["taken"])
        assert np.array_equal(axle_off, want["axle_mismatch"])
        for name, g, w in (("dt", dt, want["dt"]), ("k_report", k_report, want["k_report"]),
                           ("log_stat", log_stat, want["log_stat"]), ("stats", stats, want["stats"]),
                           ("axle", axle, want["axle"]),
                           ("floor_cdf", floor_cdf, want["floor_cdf"]), ("p", bank.core.p, ref.p),
                           ("p_stay", bank.core.p_stay, ref.p_stay), ("w_stay", bank.core.w_stay, ref.w_stay),
                           ("stay_llr", bank.core.stay_llr, ref.stay_llr), ("axle_p", bank.core.axle_p, ref.axles.p)):
            _close(name, g, w)
        # the scale profile (systematic ln K 1-sigma, c's posterior mean and 1-sigma) is a softmax over c of
        # window sums: the core's exp is libm's (numpy's SIMD exp differs in the last bit), its weighted sums run
        # in eight lanes where the reference calls BLAS, and the 1-sigmas are sqrt(E[x^2] - E[x]^2) of numbers of
        # order 1: their rounding is absolute (of order 1e-16 / sigma), so they agree absolutely, not relatively
        _close("scale", scale, want["scale"], atol=1e-9)


def test_bad_input_is_refused_with_its_name():
    bank = SoilBank(DEFAULT_CONSTANTS, SoilConfig(), 2)
    inp = _inputs(np.random.default_rng(0), 1, False, False).arrays(1)
    with pytest.raises(ValueError, match=r"idx must be distinct vehicle indices in \[0, 2\), got \[5\]"):
        bank.core.step(np.array([5]), np.array([0.0]), inp)
    with pytest.raises(ValueError, match="slip must have shape"):
        bank.core.step(np.array([0]), np.array([0.0]), dataclasses.replace(inp, slip=inp.slip[:, :3]))
    with pytest.raises(ValueError, match="stamp"):
        bank.core.step(np.array([0]), np.array([np.nan]), inp)
    with pytest.raises(ValueError, match=r"distinct vehicle indices in \[0, 2\), got \[1, 1\]"):
        two = SoilInputs(*(None if a is None else np.repeat(a, 2, axis=0) for a in dataclasses.astuple(inp)))
        bank.core.step(np.array([1, 1]), np.array([0.0, 0.0]), two)
    with pytest.raises(ValueError, match="observed must be a finite array"):  # the struct's own check names it
        dataclasses.replace(inp, observed=np.full((1, 4), np.nan)).arrays(1)
