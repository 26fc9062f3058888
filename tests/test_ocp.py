"""OCP models: S_T (eq. 7, sign corrected), mu_T (eq. 8), S_E (eq. 10) - the docs/method.md table,
S_T as the true argmax of eq. 6, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.ocp import (
    max_traction,
    ocp_from_soil_strength,
    optimal_slip_efficiency,
    optimal_slip_traction,
)
from soilocp.model.traction import net_traction

# docs/method.md, "Constants and reference values": K, S_T, mu_T, S_E
TABLE = [
    (50.0, 0.2626, 0.3828, 0.1197),
    (80.0, 0.3435, 0.5614, 0.1139),
    (120.0, 0.4060, 0.7501, 0.1063),
    (200.0, 0.4724, 0.9754, 0.0911),
]


@pytest.mark.parametrize(("k", "s_t", "mu_t", "s_e"), TABLE)
def test_method_notes_table_to_4_decimals(k, s_t, mu_t, s_e):
    o = ocp_from_soil_strength(k)
    assert round(o.S_T, 4) == s_t
    assert round(o.mu_T, 4) == mu_t
    assert round(o.S_E, 4) == s_e
    assert o.as_dict() == {"soil_strength": k, "mu_T": o.mu_T, "S_T": o.S_T, "S_E": o.S_E}


def test_sand_reference_values_from_the_paper():
    # paper's sandy-slope experiment: K ~ 50, mu_T ~ 0.4, S_T ~ 0.26, S_E ~ 0.12
    o = ocp_from_soil_strength(50.0)
    assert o.mu_T == pytest.approx(0.4, abs=0.02)
    assert o.S_T == pytest.approx(0.26, abs=0.005)
    assert o.S_E == pytest.approx(0.12, abs=0.005)


def test_printed_eq7_is_negative_and_corrected_is_its_mirror():
    c = DEFAULT_CONSTANTS
    for k, s_t, _, _ in TABLE:
        printed = math.log(c.C6 / (c.C1 * c.C3 * math.sqrt(k) * (1 - math.exp(-c.C2 * k)))) / c.C3
        assert printed < 0  # docs/method.md §1
        assert optimal_slip_traction(k) == pytest.approx(-printed, abs=1e-12)


@settings(max_examples=150, deadline=None)
@given(st.floats(15.0, 5000.0))
def test_s_t_is_the_argmax_of_eq6(k):
    s_t = optimal_slip_traction(k)
    assert s_t > 0
    # fine grid
    grid = np.linspace(0.0, 1.0, 100_001)
    mu = net_traction(grid, k)
    assert grid[np.argmax(mu)] == pytest.approx(s_t, abs=1e-3)
    # bounded scalar minimisation
    res = minimize_scalar(lambda s: -float(net_traction(s, k)), bounds=(0.01, 1.0), method="bounded", options={"xatol": 1e-8})
    assert res.x == pytest.approx(s_t, abs=1e-3)
    # mu_T (eq. 8) is the maximum of the curve
    assert max_traction(k) == pytest.approx(float(mu.max()), abs=1e-6)
    assert max_traction(k) >= float(mu.max()) - 1e-9


@settings(max_examples=100, deadline=None)
@given(st.floats(15.0, 5000.0), st.floats(-1.0, -0.01))
def test_braking_peak_mirrors_driving_peak(k, s):
    # odd symmetry: the braking optimum is -S_T with -mu_T
    assert net_traction(s, k) >= -max_traction(k) - 1e-12
    assert net_traction(-optimal_slip_traction(k), k) == pytest.approx(-max_traction(k), abs=1e-12)


def test_weak_soil_has_no_interior_peak():
    # argument of the corrected log < 1 below K ~ 13 with the paper's constants: peak at the origin
    assert optimal_slip_traction(5.0) == 0.0
    grid = np.linspace(0.005, 1.0, 2000)
    assert np.all(np.diff(net_traction(grid, 5.0)) < 0)
    # mu_T is then the value at the bridge end, which is the largest driving value
    assert max_traction(5.0) == pytest.approx(float(net_traction(0.005, 5.0)))


def test_s_t_grows_with_k_and_vectorises():
    k = np.array([20.0, 50.0, 80.0, 120.0, 200.0, 1000.0])
    s_t = optimal_slip_traction(k)
    assert s_t.shape == k.shape and np.all(np.diff(s_t) > 0)
    assert max_traction(k).shape == k.shape
    assert optimal_slip_efficiency(k).shape == k.shape


def test_s_e_is_eq10_line_and_clamped_at_zero():
    assert optimal_slip_efficiency(120.0) == pytest.approx((120.0 - 677.4) / -5242.9, rel=1e-12)
    assert optimal_slip_efficiency(677.4) == pytest.approx(0.0, abs=1e-12)
    assert optimal_slip_efficiency(2000.0) == 0.0
    c = ModelConstants(alpha=400.0, beta=-2000.0)
    assert optimal_slip_efficiency(100.0, c) == pytest.approx(0.15)


def test_ocp_follow_the_constants():
    c = ModelConstants(C3=6.0, C6=3.0)
    assert optimal_slip_traction(80.0, c) != pytest.approx(optimal_slip_traction(80.0))
    grid = np.linspace(0, 1, 100_001)
    assert grid[np.argmax(net_traction(grid, 80.0, c))] == pytest.approx(optimal_slip_traction(80.0, c), abs=1e-4)


@pytest.mark.parametrize("fn", [optimal_slip_traction, max_traction, optimal_slip_efficiency, ocp_from_soil_strength])
@pytest.mark.parametrize("k", [0.0, -1.0, float("nan"), float("inf"), float("-inf"), None, "fifty"])
def test_bad_k_raises_value_error_naming_soil_strength(fn, k):
    with pytest.raises(ValueError, match="soil_strength"):
        fn(k)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.01, 1e5), st.sampled_from([DEFAULT_CONSTANTS, ModelConstants(C5=5.0, bridge_slip=0.0)]))
def test_scalar_ocp_agrees_with_vectorised_functions(k, c):
    o = ocp_from_soil_strength(k, c)
    assert o.S_T == pytest.approx(float(optimal_slip_traction(k, c)), rel=1e-12, abs=1e-15)
    assert o.mu_T == pytest.approx(float(max_traction(k, c)), rel=1e-12, abs=1e-15)
    assert o.S_E == pytest.approx(float(optimal_slip_efficiency(k, c)), rel=1e-12, abs=1e-15)


def test_ocp_from_soil_strength_rejects_arrays():
    with pytest.raises(ValueError, match="soil_strength"):
        ocp_from_soil_strength([50.0, 80.0])


def test_tiny_k_gives_named_error_or_finite_ocps():
    try:
        o = ocp_from_soil_strength(1e-320)
    except ValueError as exc:
        assert "soil_strength" in str(exc)
    else:
        assert all(math.isfinite(v) for v in o.as_dict().values())
