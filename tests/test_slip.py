"""Slip ratio, eq. 1, with the deadband and denominator floor of docs/method.md §6 and §10."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.model.slip import DEFAULT_DEADBAND, DEFAULT_FLOOR, slip_ratio

R = 0.15


def test_driving_slip_eq1():
    # rim 1.0 m/s, ground 0.8 m/s: S = (1.0 - 0.8) / 1.0
    out = slip_ratio(1.0 / R, 0.8, R)
    assert float(out.slip) == pytest.approx(0.2)
    assert bool(out.informative)


def test_braking_slip_is_negative():
    # rim 0.8 m/s, ground 1.0 m/s: S = (0.8 - 1.0) / 1.0
    out = slip_ratio(0.8 / R, 1.0, R)
    assert float(out.slip) == pytest.approx(-0.2)


def test_pure_spin_and_locked_wheel_are_plus_minus_one():
    assert float(slip_ratio(5.0, 0.0, R).slip) == pytest.approx(1.0)  # wheel spins, vehicle stands
    assert float(slip_ratio(0.0, 1.0, R).slip) == pytest.approx(-1.0)  # locked wheel sliding


def test_standstill_is_finite_zero_and_not_informative():
    out = slip_ratio(np.zeros(4), 0.0, R)
    assert np.all(out.slip == 0.0)
    assert not np.any(out.informative)


def test_floor_bounds_the_slip_at_crawling_speed():
    # both speeds far below the floor: the denominator is the floor, so the slip stays small
    out = slip_ratio(0.002 / R, 0.001, R)
    assert float(out.slip) == pytest.approx((0.002 - 0.001) / DEFAULT_FLOOR)
    assert not bool(out.informative)


def test_deadband_flags_low_speed_only():
    wheel = np.array([0.10, 0.14, 0.16, 1.0]) / R
    out = slip_ratio(wheel, np.array([0.10, 0.14, 0.16, 1.0]) * 0.9, R)
    np.testing.assert_array_equal(out.informative, [False, False, True, True])
    np.testing.assert_allclose(out.slip, 0.1)
    # a custom deadband
    out = slip_ratio(wheel, 0.0, R, deadband=0.05)
    assert np.all(out.informative)
    assert DEFAULT_DEADBAND > 0


def test_four_wheels_and_time_series_broadcast():
    w = np.array([[6.0, 6.5, 7.0, 5.5], [6.0, 6.0, 6.0, 6.0]])
    v = np.array([[0.9], [0.9]])
    out = slip_ratio(w, v, R)
    assert out.slip.shape == (2, 4) and out.informative.shape == (2, 4)
    assert out.slip[1, 0] == pytest.approx((0.9 - 0.9) / 0.9)
    assert out.slip[0, 2] == pytest.approx((7.0 * R - 0.9) / (7.0 * R))


@settings(max_examples=300, deadline=None)
@given(st.floats(-50, 50), st.floats(-5, 5))
def test_slip_bounded_and_signed(omega, v):
    s = float(slip_ratio(omega, v, R).slip)
    assert np.isfinite(s)
    assert -2.0 - 1e-12 <= s <= 2.0 + 1e-12  # |rim - v| <= 2 max(|rim|, |v|)
    if v > 0 and omega * R >= 0:
        assert -1.0 - 1e-12 <= s <= 1.0 + 1e-12  # forward motion: eq. 1's range
        assert np.sign(s) == np.sign(omega * R - v) or s == 0


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"wheel_speed": float("nan"), "ground_speed": 1.0, "wheel_radius": R}, "wheel_speed"),
        ({"wheel_speed": [1.0, float("inf")], "ground_speed": 1.0, "wheel_radius": R}, "wheel_speed"),
        ({"wheel_speed": 1.0, "ground_speed": float("nan"), "wheel_radius": R}, "ground_speed"),
        ({"wheel_speed": 1.0, "ground_speed": 1.0, "wheel_radius": 0.0}, "wheel_radius"),
        ({"wheel_speed": 1.0, "ground_speed": 1.0, "wheel_radius": -0.1}, "wheel_radius"),
        ({"wheel_speed": 1.0, "ground_speed": 1.0, "wheel_radius": float("nan")}, "wheel_radius"),
        ({"wheel_speed": np.ones(4), "ground_speed": np.ones(3), "wheel_radius": R}, "wheel_speed"),
        ({"wheel_speed": 1.0, "ground_speed": 1.0, "wheel_radius": R, "deadband": -1.0}, "deadband"),
        ({"wheel_speed": 1.0, "ground_speed": 1.0, "wheel_radius": R, "floor": 0.0}, "floor"),
    ],
)
def test_bad_input_raises_value_error_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        slip_ratio(**kwargs)
