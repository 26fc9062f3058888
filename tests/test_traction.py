"""Improved Brixius model (eqs. 2-6, 9): values, symmetry, the split g = mu + r, the bridge at S = 0,
and rejection of bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import (
    gross_traction,
    gross_traction_with_derivatives,
    motion_resistance,
    net_traction,
    net_traction_with_derivatives,
    tractive_efficiency,
)

C = DEFAULT_CONSTANTS
slips = st.floats(-1.0, 1.0, allow_nan=False)
strengths = st.floats(1.0, 5000.0, allow_nan=False)
FAST = settings(max_examples=200, deadline=None)


def printed_eq6(s: float, k: float, c: ModelConstants = C) -> float:
    """Eq. 6 typed in from the paper, independently of the library (S != 0)."""
    sg = 1.0 if s > 0 else -1.0
    return sg * (c.C1 * (1 - math.exp(-c.C2 * k)) * (1 - math.exp(-sg * c.C3 * s)) - (c.C5 / k + sg * c.C6 * s / math.sqrt(k)))


@pytest.mark.parametrize("s", [0.1, 0.26, 0.6, 1.0, -0.1, -0.5, -1.0])
@pytest.mark.parametrize("k", [50.0, 80.0, 120.0, 200.0])
def test_net_traction_matches_printed_eq6_outside_bridge(s, k):
    assert net_traction(s, k) == pytest.approx(printed_eq6(s, k), abs=1e-12)


def test_net_traction_known_value_sand():
    # eq. 6 by hand at S = 0.3, K = 50: 1.3 (1-e^-0.5)(1-e^-2.1174) - (-0.1 + 4*0.3/sqrt(50))
    amp = 1.3 * (1 - math.exp(-0.5))
    expect = amp * (1 - math.exp(-7.058 * 0.3)) + 0.1 - 1.2 / math.sqrt(50)
    assert net_traction(0.3, 50.0) == pytest.approx(expect, rel=1e-12)
    assert net_traction(0.3, 50.0) == pytest.approx(0.3802, abs=1e-4)  # 0.51151 * 0.87966 + 0.1 - 0.16971


@FAST
@given(slips, strengths)
def test_mu_is_odd_and_resistance_even_in_slip(s, k):
    # docs/method.md §11: net traction (eq. 6) is odd, motion resistance (eq. 4 with |S|) is even
    assert net_traction(-s, k) == pytest.approx(-net_traction(s, k), abs=1e-12)
    assert motion_resistance(-s, k) == pytest.approx(motion_resistance(s, k), abs=1e-12)


def test_braking_wheel_gross_is_net_plus_even_resistance_not_eq3_lower_branch():
    # §11 test vector: K = 80, S = -0.3.  gross = mu + r = -mu(0.3) + r(0.3), |gross| < |mu|;
    # eq. 3's printed lower branch -(amp (1 - e^{-C3 |S|}) + C4) would be larger in magnitude.
    k, s = 80.0, 0.3
    r = C.C5 / k + C.C4 + C.C6 * s / np.sqrt(k)
    amp = C.C1 * (1 - np.exp(-C.C2 * k))
    mu = amp * (1 - np.exp(-C.C3 * s)) - (C.C5 / k + C.C6 * s / np.sqrt(k))
    assert gross_traction(-s, k) == pytest.approx(-mu + r, rel=1e-12)
    assert abs(gross_traction(-s, k)) < abs(net_traction(-s, k))
    assert abs(gross_traction(-s, k) - (-(amp * (1 - np.exp(-C.C3 * s)) + C.C4))) > 0.1
    assert gross_traction(s, k) == pytest.approx(amp * (1 - np.exp(-C.C3 * s)) + C.C4, rel=1e-12)  # eq. 3


@FAST
@given(slips, strengths)
def test_gross_is_net_plus_resistance(s, k):
    # eq. 2: F_DP = F_GT - F_MR, per unit load
    assert gross_traction(s, k) == pytest.approx(net_traction(s, k) + motion_resistance(s, k), abs=1e-12)


def test_c4_cancels_in_net_traction():
    s = np.linspace(-1, 1, 41)
    a = net_traction(s, 80.0, C.model_copy(update={"C4": 0.0}))
    b = net_traction(s, 80.0, C.model_copy(update={"C4": 0.3}))
    np.testing.assert_allclose(a, b, atol=1e-14)
    assert not np.allclose(gross_traction(0.3, 80.0, C.model_copy(update={"C4": 0.3})), gross_traction(0.3, 80.0, C))


@pytest.mark.parametrize("k", [5.0, 50.0, 200.0, 2000.0])
@pytest.mark.parametrize("fn", [net_traction, gross_traction, motion_resistance])
def test_bridge_is_continuous_and_zero_at_origin(fn, k):
    b = C.bridge_slip
    eps = 1e-9
    for edge in (b, -b):
        inside = fn(edge - math.copysign(eps, edge), k)
        outside = fn(edge + math.copysign(eps, edge), k)
        assert inside == pytest.approx(outside, abs=1e-6)
    assert fn(0.0, k) == 0.0
    # linear inside the bridge
    assert fn(b / 2, k) == pytest.approx(fn(b, k) / 2, rel=1e-12)


def test_without_bridge_eq6_jumps_at_zero_slip():
    c = C.model_copy(update={"bridge_slip": 0.0})
    up, down = net_traction(1e-12, 50.0, c), net_traction(-1e-12, 50.0, c)
    # docs/method.md §8: -C5/K = +0.1 above zero, -0.1 below
    assert up == pytest.approx(0.1, abs=1e-9)
    assert down == pytest.approx(-0.1, abs=1e-9)


@FAST
@given(st.floats(0.02, 0.95), st.floats(5.0, 3000.0))
def test_derivatives_match_finite_differences(s, k):
    h = 1e-6
    for fn, fd in ((net_traction_with_derivatives, net_traction), (gross_traction_with_derivatives, gross_traction)):
        _, d_s, d_k = fn(s, k)
        assert d_s == pytest.approx((fd(s + h, k) - fd(s - h, k)) / (2 * h), rel=1e-4, abs=1e-6)
        hk = 1e-4 * k
        assert d_k == pytest.approx((fd(s, k + hk) - fd(s, k - hk)) / (2 * hk), rel=1e-4, abs=1e-8)


@FAST
@given(st.floats(0.01, 1.0), strengths)
def test_gross_traction_monotone_in_k(s, k):
    # docs/method.md §9: gross traction (seen through wheel torque) is monotone in K
    assert gross_traction_with_derivatives(s, k)[2] > 0
    assert gross_traction(s, k * 1.5) >= gross_traction(s, k)
    if k <= 1000:  # above, 1 - exp(-C2 K) saturates to 1 in double precision
        assert gross_traction(s, k * 1.5) > gross_traction(s, k)


def test_vectorised_broadcast_shapes():
    s = np.linspace(0.1, 0.6, 6)
    k = np.array([[50.0], [200.0]])
    out = net_traction(s, k)
    assert out.shape == (2, 6)
    assert out[1, 3] == pytest.approx(net_traction(s[3], 200.0))


def test_tractive_efficiency_eq9():
    s, k = 0.2, 120.0
    expect = net_traction(s, k) / gross_traction(s, k) * (1 - s)
    assert tractive_efficiency(s, k) == pytest.approx(expect, rel=1e-12)
    # docs/method.md §5: with C5 = -5, TE exceeds 1 near zero slip for sand; with C5 = +5 it has a peak near 0.1
    assert tractive_efficiency(0.01, 50.0) > 1.0
    c = C.model_copy(update={"C5": 5.0})
    grid = np.linspace(0.01, 0.99, 981)
    peaks = [grid[np.argmax(tractive_efficiency(grid, k, c))] for k in (50.0, 80.0, 200.0)]
    assert 0.05 < peaks[2] < peaks[1] < peaks[0] < 0.2


@pytest.mark.parametrize("s", [0.0, -0.1, 1.0, 1.5])
def test_tractive_efficiency_rejects_slip_outside_open_unit_interval(s):
    with pytest.raises(ValueError, match="slip"):
        tractive_efficiency(s, 50.0)


@pytest.mark.parametrize("fn", [net_traction, gross_traction, motion_resistance, net_traction_with_derivatives])
@pytest.mark.parametrize("k", [0.0, -50.0, float("nan"), float("inf"), "sand", [50.0, -1.0]])
def test_bad_soil_strength_raises_naming_it(fn, k):
    with pytest.raises(ValueError, match="soil_strength"):
        fn(0.2, k)


@pytest.mark.parametrize("s", [float("nan"), float("inf"), "x", [0.1, float("nan")]])
def test_bad_slip_raises_naming_it(s):
    with pytest.raises(ValueError, match="slip"):
        net_traction(s, 50.0)


def test_shape_mismatch_raises_naming_both():
    with pytest.raises(ValueError, match="slip.*soil_strength.*broadcast"):
        net_traction(np.zeros(3), np.full(4, 50.0))
