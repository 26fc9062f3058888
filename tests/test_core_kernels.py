"""The compiled core (soilocp/_core) against the plain numpy reference of tests/reference_physics.py
(the product's numpy kernels before the port): the traction law with its derivatives (eqs. 2-6,
docs/method.md §8, §11), tractive efficiency (eq. 9), the OCPs (eqs. 7, 8, 10) and the zero-warp
normal forces (eqs. 16-25), on random inputs, through the product's own functions.

Agreement is 1e-12 relative.  The core's exp/expm1/log (libm) and numpy's SIMD ones may differ in
the last bit, so a value that is a difference of larger terms (net traction near its zero, a
derivative near a sign change) gets an absolute allowance of 1e-12 times the size of its terms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import reference_physics as ref
from soilocp import _core
from soilocp.model import ocp as ocp_mod
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.normal_force import NormalForceSolver, normal_forces
from soilocp.model.traction import (
    curve_unchecked,
    gross_traction_with_derivatives,
    motion_resistance,
    net_traction_with_derivatives,
    tractive_efficiency,
)
from soilocp.model.vehicle import VehicleParams

REL = 1e-12

constants = st.builds(
    ModelConstants,
    C1=st.floats(0.5, 2.0), C2=st.floats(0.002, 0.05), C3=st.floats(2.0, 12.0), C4=st.floats(-0.1, 0.1),
    C5=st.floats(-10.0, 10.0), C6=st.floats(1.0, 8.0), alpha=st.floats(100.0, 1000.0),
    beta=st.floats(-8000.0, -1000.0), bridge_slip=st.sampled_from([0.0, 0.001, 0.005, 0.02]),
)
slips = st.one_of(st.floats(-1.0, 1.0), st.floats(-0.03, 0.03), st.sampled_from([0.0, 0.005, -0.005, 0.02]))
soil_strengths = st.floats(1.0, 5000.0)


def _close(got, want, scale) -> None:
    assert np.shape(got) == np.shape(want)
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    err = np.abs(got - want)[~np.isnan(want)]
    allowed = (REL * (np.abs(want) + np.abs(np.broadcast_to(scale, got.shape))))[~np.isnan(want)]
    assert (err <= allowed).all(), f"core {got}, reference {want}: error {err} > {allowed}"


def _terms(s, k, c: ModelConstants) -> np.ndarray:
    """The size of the terms a coefficient is made of (for the absolute allowance)."""
    return c.C1 + abs(c.C4) + abs(c.C5) / k + c.C6 * np.abs(s) / np.sqrt(k)


@settings(max_examples=300, deadline=None)
@given(st.lists(slips, min_size=1, max_size=8), soil_strengths, constants)
def test_traction_curves_and_derivatives_equal_the_reference(s, k, c):
    s = np.array(s)
    scale = _terms(s, k, c)
    for kind, fn in (("net", net_traction_with_derivatives), ("gross", gross_traction_with_derivatives)):
        got, want = fn(s, k, c), ref.curve(kind, s, k, c)
        _close(got[0], want[0], scale)
        _close(got[1], want[1], scale * c.C3 + c.C6 / np.sqrt(k) * 1e3)  # d/dS: slopes up to C3, 1/bridge
        _close(got[2], want[2], scale / k)  # d/dK
    _close(motion_resistance(s, k, c), ref.curve("resistance", s, k, c)[0], scale)


@settings(max_examples=200, deadline=None)
@given(st.floats(1e-4, 0.999), soil_strengths, constants)
def test_tractive_efficiency_equals_the_reference(s, k, c):
    g = ref.curve("gross", s, k, c)[0]
    _close(tractive_efficiency(s, k, c), ref.tractive_efficiency(s, k, c), _terms(s, k, c) / abs(g))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(soil_strengths, st.just(float("nan"))), min_size=1, max_size=12), constants)
def test_ocp_bank_equals_the_reference(ks, c):
    ks = np.array(ks)
    got = ocp_mod.ocp_arrays(ks, c)
    have = ~np.isnan(ks)
    for name in ("mu_T", "S_T", "S_E", "te_at_S_E"):
        assert np.isnan(got[name][~have]).all()
    if have.any():
        want = ref.ocp(ks[have], c)
        for name in ("mu_T", "S_T", "S_E"):
            _close(got[name][have], want[name], _terms(want["S_T"], ks[have], c))
        te = got["te_at_S_E"][have]
        assert np.array_equal(np.isnan(te), np.isnan(want["te_at_S_E"]))
        _close(te[~np.isnan(te)], want["te_at_S_E"][~np.isnan(te)], 1.0)


lengths = st.floats(0.05, 2.0)


@settings(max_examples=300, deadline=None)
@given(
    st.builds(VehicleParams, mass=st.floats(1.0, 2000.0), a=lengths, b=lengths, c=lengths, d=lengths, h=st.floats(0.01, 2.0)),
    st.lists(st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(-5.0, 40.0)), min_size=1, max_size=6),
)
def test_normal_forces_equal_the_pseudo_inverse_reference(v, fs):
    """The core's product with the prepared matrix against the reference's A^+ B (numpy's SVD
    pseudo-inverse applied to the load vector); the allowance is relative to the size of the load
    vector's terms (a lifted wheel's force can be near 0), and at least 1e-9 N: a load vector of
    subnormal numbers (below 1e-308) rounds differently in each and gives no force at all."""
    f = np.array(fs)
    want = ref.normal_forces(v, f)
    scale = v.mass * np.abs(f).sum(axis=1, keepdims=True) * (v.a + v.b + v.c + v.d + v.h) / min(v.a + v.b, v.c + v.d)
    scale = scale * 10 + 1e-9 / REL  # _close allows REL x scale: at least 1e-9 N
    _close(normal_forces(v, f), want, scale)
    _close(NormalForceSolver(v)(f[0]), want[0], scale[0])


def test_normal_forces_of_a_subnormal_load_are_no_force():
    """The case that the allowance's floor is for (found by the property test above)."""
    v = VehicleParams(mass=1.0, a=0.05, b=0.05, c=0.05, d=0.05, h=2.0)
    f = np.array([[5e-324, 5e-324, 5e-324]])
    assert np.abs(normal_forces(v, f)).max() < 1e-300 and np.abs(ref.normal_forces(v, f)).max() < 1e-300


def test_bank_shapes_and_scalars():
    """Arrays in, arrays out: (N, 3) -> (N, 4); curves broadcast like numpy; a scalar gives a
    numpy float, as the numpy kernels did."""
    v = VehicleParams()
    assert normal_forces(v, np.zeros((5, 3)) + [0, 0, 9.8]).shape == (5, 4)
    assert normal_forces(v, np.zeros((2, 5, 3))).shape == (2, 5, 4)
    s, k = np.linspace(-0.5, 0.5, 6)[:, None], np.array([50.0, 80.0, 200.0])[None, :]
    val, d_s, d_k = curve_unchecked("gross", s, k, DEFAULT_CONSTANTS)
    assert val.shape == d_s.shape == d_k.shape == (6, 3)
    _close(val, ref.curve("gross", s, k, DEFAULT_CONSTANTS)[0], 1.0)
    mu = net_traction_with_derivatives(0.3, 50.0)[0]
    assert isinstance(mu, np.floating) and mu == pytest.approx(0.3802, abs=1e-4)


def test_core_refuses_what_the_checks_name():
    """The core raises on what it cannot evaluate; the Python edge words the message."""
    c = DEFAULT_CONSTANTS.kernel
    with pytest.raises(ValueError, match="broadcast"):
        _core.traction_value("net", np.zeros(3), np.full(4, 50.0), c)
    with pytest.raises(ValueError, match="kind"):
        _core.traction_value("drawbar", np.zeros(3), np.full(3, 50.0), c)
    with pytest.raises(ValueError, match=r"soil_strength\[1\]"):
        _core.ocp_bank(np.array([50.0, -1.0]), c)
    with pytest.raises(ValueError, match="soil_strength must be > 0"):
        ocp_mod.ocp_arrays(np.array([50.0, -1.0]))
    with pytest.raises(ValueError, match="model can evaluate"):
        ocp_mod.ocp_arrays(np.array([1e-320]))
    with pytest.raises(ValueError, match="geometry c must be a finite length > 0, got NaN"):
        _core.NormalForceSolver(0.27, 0.23, np.nan, 0.25, 0.3, 60.0)
    with pytest.raises(ValueError, match="mass must be finite and > 0, got -1"):
        _core.NormalForceSolver(0.27, 0.23, 0.25, 0.25, 0.3, -1.0)
    with pytest.raises(ValueError, match=r"specific_force must be finite, got \(1\.0, inf, 9\.8\)"):
        _core.NormalForceSolver(0.27, 0.23, 0.25, 0.25, 0.3, 60.0).solve_one(1.0, np.inf, 9.8)


def test_constants_kernel_follows_model_copy():
    """model_copy(update=...) copies private attributes without validation: the core's constants
    must still be those of the copy."""
    c = DEFAULT_CONSTANTS
    printed = c.model_copy(update={"bridge_slip": 0.0})
    assert c.kernel.__repr__() != printed.kernel.__repr__()
    assert net_traction_with_derivatives(0.001, 50.0, printed)[0] == pytest.approx(ref.curve("net", 0.001, 50.0, printed)[0], rel=REL)


def test_constants_equal_whether_or_not_their_kernel_was_built():
    """The kernel is a cache: constants read back from a file equal the ones whose kernel a stage built."""
    from soilocp.model.constants import ModelConstants

    built = ModelConstants(C3=5.2)
    assert built.kernel is not None
    fresh = ModelConstants.model_validate_json(built.model_dump_json())
    assert fresh == built and built == fresh
    assert fresh != built.model_copy(update={"C3": 5.3})
    assert built != "C3=5.2"


def test_the_core_imports_nothing_above_it():
    """The core is below the library that calls it: importing it loads no soilocp module but the
    package itself (and numpy only when an array crosses)."""
    import json
    import subprocess
    import sys

    code = "import sys, json, soilocp._core\nprint(json.dumps(sorted(m for m in sys.modules if m.startswith('soilocp'))))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == ["soilocp", "soilocp._core"]
