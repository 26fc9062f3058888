"""The per-sample fast paths compute the same numbers as the checked, vectorised functions."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.normal_force import NormalForceSolver, normal_forces
from soilocp.traction import tractive_efficiency, tractive_efficiency_scalar
from soilocp.vehicle import DEFAULT_VEHICLE, VehicleParams


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-30, 30), min_size=3, max_size=3),
       st.floats(0.1, 1.0), st.floats(0.1, 1.0), st.floats(0.1, 1.0))
def test_normal_force_solver_equals_pseudo_inverse_solution(f, a, c, h):
    v = VehicleParams(a=a, b=0.5, c=c, d=0.3, h=h)
    assert np.allclose(NormalForceSolver(v)(f), normal_forces(v, f), rtol=1e-12, atol=1e-9)


def test_normal_force_solver_rejects_bad_input_by_name():
    solve = NormalForceSolver(DEFAULT_VEHICLE)
    with pytest.raises(ValueError, match="specific_force"):
        solve([0.0, np.nan, 9.8])
    with pytest.raises(ValueError, match="specific_force"):
        solve([0.0, 9.8])


@settings(max_examples=50, deadline=None)
@given(st.floats(0.005, 0.99), st.floats(5, 3000))
def test_scalar_tractive_efficiency_equals_eq9(s, k):
    assert tractive_efficiency_scalar(s, k) == pytest.approx(float(tractive_efficiency(s, k)), rel=1e-12, abs=1e-12)
