"""The per-sample fast paths compute the same numbers as the checked, vectorised functions."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.model.normal_force import NormalForceSolver, normal_forces
from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.model.traction import gross_traction, net_traction, tractive_efficiency
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams


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


@settings(max_examples=100, deadline=None)
@given(st.floats(0.001, 0.99), st.floats(5, 3000))
def test_value_only_curves_equal_the_curves_with_derivatives(s, k):
    """The value-only path (eq. 6; eq. 9 with eq. 3 evaluated once) equals the curves with their
    derivatives, inside and outside the zero-slip bridge."""
    from soilocp.model.traction import net_traction_with_derivatives

    sa, ka = np.array([s, -s]), np.array([k, k])
    np.testing.assert_array_equal(net_traction_with_derivatives(sa, ka, DEFAULT_CONSTANTS)[0], net_traction(sa, ka))
    te = float(net_traction(s, k) / gross_traction(s, k) * (1.0 - s))  # eq. 9 from eqs. 6 and 3
    assert float(tractive_efficiency(s, k)) == pytest.approx(te, rel=1e-12, abs=1e-12)


def test_ocp_stage_with_the_printed_model_on_very_firm_soil():
    """bridge_slip = 0 (eq. 6 as printed) and K above alpha (S_E clamped to 0): no TE, no error."""
    from soilocp.schemas.pipeline import SoilEstimate
    from soilocp.model.constants import ModelConstants
    from soilocp.estimation.pipeline import OcpStage, PipelineConfig

    stage = OcpStage(PipelineConfig(constants=ModelConstants(bridge_slip=0.0)))
    soil = SoilEstimate(vehicle_id="r1", seq=1, stamp=0.0, slip=(0.1,) * 4, informative=(True,) * 4,
                        soil_strength=1000.0, soil_strength_std=50.0, log_k_std=0.05, soil_class="firm",
                        soil_class_confidence=1.0, status="ok", last_update_stamp=0.0, mu=(0.5,) * 4)
    rec = stage.step(soil)
    assert rec.S_E == 0.0 and rec.te_at_S_E is None and rec.mu_T > 1.0


def test_ocp_arrays_with_missing_k_equal_each_k_alone():
    """The OCP kernel's fast path (every K present) and its masked path (some NaN) agree."""
    from soilocp.model.ocp import ocp_arrays

    ks = np.array([np.nan, 30.0, 150.0, np.nan, 900.0, 680.0])
    mixed = ocp_arrays(ks)
    for j, k in enumerate(ks):
        alone = ocp_arrays(np.array([k]))
        for name in ("mu_T", "S_T", "S_E", "te_at_S_E"):
            np.testing.assert_array_equal(mixed[name][j], alone[name][0])
    assert np.isnan(mixed["te_at_S_E"][4]) and np.isnan(mixed["mu_T"][0])
    assert all(np.isnan(v).all() for v in ocp_arrays(np.array([np.nan, np.nan])).values())
    with pytest.raises(ValueError, match="soil_strength"):
        ocp_arrays(np.array([np.nan, -3.0]))
