"""Normal forces, eqs. 16-25 (docs/method.md §2-3): zero-warp least-squares solution from the measured
specific force.  Checked against rigid-body statics derived here independently of the library:

    sum F_i = m f_z,   sum x_i F_i = -h m f_x,   sum y_i F_i = -h m f_y,   F1 - F2 + F3 - F4 = 0

(moments about the CoM of the contact forces acting at height -h; wheels 1 LR, 2 LF, 3 RF, 4 RR).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.model.normal_force import STANDARD_GRAVITY, gravity_from_attitude, normal_forces, static_normal_forces
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams
from reference_physics import load_vector, system_matrix  # the numpy reference, independent of the product

G = STANDARD_GRAVITY
V = DEFAULT_VEHICLE
WARP = np.array([1.0, -1.0, 1.0, -1.0])


def statics(v: VehicleParams, f) -> np.ndarray:
    """Independent zero-warp rigid-body solution (see module docstring)."""
    x = np.array([-v.a, v.b, v.b, -v.a])
    y = np.array([v.c, v.c, -v.d, -v.d])
    M = np.vstack([np.ones(4), x, y, WARP])
    fx, fy, fz = f
    rhs = np.array([v.mass * fz, -v.h * v.mass * fx, -v.h * v.mass * fy, 0.0])
    return np.linalg.solve(M, rhs)


def test_matrix_is_rank_3_with_warp_null_vector():
    A = system_matrix(V)
    assert np.linalg.matrix_rank(A) == 3  # docs/method.md §2: eq. 25's inverse does not exist
    np.testing.assert_allclose(A @ WARP, 0.0, atol=1e-12)


def test_static_split_at_rest():
    F = normal_forces(V, [0.0, 0.0, G])
    m = V.mass
    rear, front = F[0] + F[3], F[1] + F[2]
    left, right = F[0] + F[1], F[2] + F[3]
    assert rear == pytest.approx(m * G * V.b / (V.a + V.b))
    assert front == pytest.approx(m * G * V.a / (V.a + V.b))
    assert left == pytest.approx(m * G * V.d / (V.c + V.d))
    assert right == pytest.approx(m * G * V.c / (V.c + V.d))
    assert F.sum() == pytest.approx(m * G)
    assert np.all(F > 0)


def test_asymmetric_static_split():
    v = VehicleParams(mass=100.0, a=0.4, b=0.2, c=0.3, d=0.1, h=0.25)
    F = normal_forces(v, [0.0, 0.0, G])
    np.testing.assert_allclose(F, statics(v, (0.0, 0.0, G)), rtol=1e-12)
    assert F[0] + F[3] == pytest.approx(100 * G * 0.2 / 0.6)  # CoM nearer the front: front carries more
    assert F[2] + F[3] == pytest.approx(100 * G * 0.3 / 0.4)  # CoM nearer the right wheels


def test_climbing_slope_loads_the_rear_and_total_is_m_g_cos():
    pitch = -math.radians(15)  # REP-103: nose up = negative pitch
    f = gravity_from_attitude(0.0, pitch)
    assert f[0] > 0  # at rest on a climb f_x = -g sin(pitch) > 0
    F = static_normal_forces(V, 0.0, pitch)
    flat = static_normal_forces(V)
    assert F[0] + F[3] > flat[0] + flat[3]
    assert F.sum() == pytest.approx(V.mass * G * math.cos(pitch))
    np.testing.assert_allclose(F, statics(V, f), rtol=1e-12)


def test_side_slope_loads_the_downhill_side():
    roll = math.radians(10)  # left side up
    F = static_normal_forces(V, roll, 0.0)
    assert F[2] + F[3] > F[0] + F[1]  # right (downhill) wheels carry more
    left = F[0] + F[1]
    f = gravity_from_attitude(roll, 0.0)
    assert left == pytest.approx(V.mass * (V.d * f[2] - V.h * f[1]) / (V.c + V.d))


def test_forward_acceleration_transfers_load_to_the_rear():
    accel = 2.0
    F = normal_forces(V, [accel, 0.0, G])
    flat = normal_forces(V, [0.0, 0.0, G])
    transfer = V.mass * accel * V.h / (V.a + V.b)
    assert (F[0] + F[3]) - (flat[0] + flat[3]) == pytest.approx(transfer)
    assert (F[1] + F[2]) - (flat[1] + flat[2]) == pytest.approx(-transfer)
    # braking moves it forward
    Fb = normal_forces(V, [-accel, 0.0, G])
    assert Fb[1] + Fb[2] > flat[1] + flat[2]


def test_lift_off_is_reported_not_clipped():
    F = normal_forces(V, [0.0, 30.0, G])  # violent lateral force: left wheels lift
    assert F[0] < 0 and F[1] < 0
    assert F.sum() == pytest.approx(V.mass * G)


def test_time_series_shape():
    f = np.array([[0.0, 0.0, G], [1.0, 0.5, G], [-1.0, 0.0, 9.0]])
    F = normal_forces(V, f)
    assert F.shape == (3, 4)
    np.testing.assert_allclose(F[1], normal_forces(V, f[1]))
    np.testing.assert_allclose(F.sum(axis=1), V.mass * f[:, 2])


lengths = st.floats(0.05, 2.0)


@settings(max_examples=300, deadline=None)
@given(
    st.builds(VehicleParams, mass=st.floats(1.0, 2000.0), a=lengths, b=lengths, c=lengths, d=lengths, h=st.floats(0.01, 2.0)),
    st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(0.0, 30.0)),
)
def test_properties_for_random_geometry_and_specific_force(v, f):
    F = normal_forces(v, f)
    A, B = system_matrix(v), load_vector(v, f)
    scale = v.mass * (abs(f[0]) + abs(f[1]) + abs(f[2]) + 1.0) * (v.a + v.b + v.c + v.d + v.h)
    np.testing.assert_allclose(A @ F, B, atol=1e-9 * scale)  # eqs. 21-24 hold exactly
    assert F.sum() == pytest.approx(v.mass * f[2], abs=1e-9 * scale)  # vertical balance
    assert F[0] + F[2] == pytest.approx(F[1] + F[3], abs=1e-9 * scale)  # zero warp
    np.testing.assert_allclose(F, statics(v, f), atol=1e-9 * scale)
    assert np.dot(B, WARP) == pytest.approx(0.0, abs=1e-9 * scale)  # B orthogonal to the null vector


@pytest.mark.parametrize("field", ["a", "b", "c", "d", "h", "mass"])
@pytest.mark.parametrize("value", [0.0, -0.3, float("nan"), float("inf")])
def test_bad_geometry_rejected_by_vehicle_params(field, value):
    with pytest.raises(ValueError, match=field):
        VehicleParams(**{field: value})


@pytest.mark.parametrize("field", ["a", "b", "c", "d", "h"])
@pytest.mark.parametrize("value", [0.0, -0.3, float("nan")])
def test_bad_geometry_rejected_by_solver(field, value):
    # an unvalidated object (model_construct skips pydantic) must still not give silent garbage
    v = VehicleParams.model_construct(**(V.model_dump() | {field: value}))
    with pytest.raises(ValueError, match=f"geometry {field}"):
        normal_forces(v, [0.0, 0.0, G])


@pytest.mark.parametrize("f", [[0.0, G], [0.0, 0.0, G, 1.0], np.zeros((3, 2)), 9.81])
def test_wrong_specific_force_shape(f):
    with pytest.raises(ValueError, match="specific_force"):
        normal_forces(V, f)


@pytest.mark.parametrize("f", [[float("nan"), 0.0, G], [0.0, float("inf"), G], "up"])
def test_non_finite_specific_force(f):
    with pytest.raises(ValueError, match="specific_force"):
        normal_forces(V, f)


@pytest.mark.parametrize(("roll", "pitch", "name"), [(float("nan"), 0.0, "roll"), (0.0, float("inf"), "pitch")])
def test_bad_attitude(roll, pitch, name):
    with pytest.raises(ValueError, match=name):
        gravity_from_attitude(roll, pitch)


@settings(max_examples=500, deadline=None)
@given(
    st.builds(VehicleParams, mass=st.floats(0.5, 5000.0), a=st.floats(0.01, 5.0), b=st.floats(0.01, 5.0),
              c=st.floats(0.01, 5.0), d=st.floats(0.01, 5.0), h=st.floats(0.01, 3.0)),
)
def test_closed_form_map_equals_numpys_pseudo_inverse(v):
    """The core computes M = C (A^+)^T from A's Hadamard eigenvectors (closed form, no SVD).  It equals
    M by numpy's LAPACK pseudo-inverse (as the product computed M before) within LAPACK's own error,
    which grows with A's condition on its range, (L + W) / min(L, W): 64 ulp of each row's largest
    entry times it (measured: ≤ 28; the rover's rows: ≤ 4 ulp, the core's test).  And it is exact to
    its rounding: M A = C and M (1, -1, 1, -1)^T = 0 (what defines C A^+, C's rows being orthogonal
    to the warp mode) hold in exact rational arithmetic within a few ulp (docs/method.md §2)."""
    from fractions import Fraction

    from soilocp.model.normal_force_map import core_solver

    want = load_vector(v, np.eye(3)) @ np.linalg.pinv(system_matrix(v)).T  # row i: f = e_i
    got = core_solver(v).map
    L, W = v.a + v.b, v.c + v.d
    big = np.abs(want).max(axis=1, keepdims=True)
    assert np.all(np.abs(got - want) <= 64 * (L + W) / min(L, W) * np.spacing(big))
    # exact: A and C of the float inputs, M as the core rounded it
    Lq, Wq = Fraction(v.a) + Fraction(v.b), Fraction(v.c) + Fraction(v.d)
    A = [[0, Lq, Lq + Wq, Wq], [Lq, 0, Wq, Lq + Wq], [Lq + Wq, Wq, 0, Lq], [Wq, Lq + Wq, Lq, 0]]
    a, b, c, d, h, m = (Fraction(x) for x in (v.a, v.b, v.c, v.d, v.h, v.mass))
    C = [[-m * h, m * h, m * h, -m * h], [m * h, m * h, -m * h, -m * h], [m * (a + c), m * (b + c), m * (b + d), m * (a + d)]]
    for i in range(3):
        Mi = [Fraction(x) for x in got[i]]
        scale = max(abs(x) for x in Mi) * (Lq + Wq)
        for j in range(4):
            resid = sum(Mi[k] * A[k][j] for k in range(4)) - C[i][j]
            assert abs(resid) <= 8 * np.finfo(float).eps * scale, (i, j, float(resid), float(scale))
        assert abs(Mi[0] - Mi[1] + Mi[2] - Mi[3]) <= 8 * np.finfo(float).eps * max(abs(x) for x in Mi)


def test_the_derivation_of_the_closed_form():
    """The derivation the core's closed form rests on (docs/method.md §2), checked apart from the core:
    A^+ = h0 h0^T / (8 (L + W)) - h2 h2^T / (8 W) - h3 h3^T / (8 L) (A's Hadamard eigenvectors;
    (1, -1, 1, -1) spans its null space), in numpy, against numpy's pinv."""
    rng = np.random.default_rng(28)
    h0, h2, h3 = np.ones(4), np.array([1.0, 1.0, -1.0, -1.0]), np.array([1.0, -1.0, -1.0, 1.0])
    for _ in range(200):
        a, b, c, d = rng.uniform(0.01, 3.0, 4)
        v = VehicleParams(a=a, b=b, c=c, d=d)
        L, W = a + b, c + d
        closed = np.outer(h0, h0) / (8 * (L + W)) - np.outer(h2, h2) / (8 * W) - np.outer(h3, h3) / (8 * L)
        pinv = np.linalg.pinv(system_matrix(v))
        np.testing.assert_allclose(closed, pinv, rtol=0, atol=1e-13 * np.abs(pinv).max())


def test_the_services_one_sample_call_equals_the_bank():
    """The normal-force service's numpy-free call (floats) and the bank's (arrays) are one map and one
    product: equal to the bit; a bad specific force is named with its value."""
    from soilocp.model.normal_force import NormalForceSolver
    from soilocp.model.normal_force_map import core_solver, solve_one

    rng = np.random.default_rng(5)
    v = VehicleParams(mass=100.0, a=0.4, b=0.2, c=0.3, d=0.1, h=0.25)
    fs = rng.normal(0.0, 5.0, (50, 3)) + [0.0, 0.0, G]
    bank = NormalForceSolver(v)(fs)
    for f, want in zip(fs, bank):
        assert solve_one(core_solver(v), tuple(f.tolist())) == tuple(want.tolist())
    for bad in [(float("nan"), 0.0, G), (0.0, 0.0), "up", (1.0, "x", G)]:
        with pytest.raises(ValueError, match=r"specific_force must be three finite numbers, got"):
            solve_one(core_solver(v), bad)
    with pytest.raises(ValueError, match=r"got \(nan, 0\.0, 9\.80665\)"):
        solve_one(core_solver(v), (float("nan"), 0.0, G))


def test_a_solver_pickles_to_the_same_map():
    """A stage travels to a worker process with its solver: the pickled solver (rebuilt from the
    geometry and mass) has the same map to the bit, and solves alike."""
    import pickle

    from soilocp.model.normal_force_map import core_solver

    v = VehicleParams(mass=100.0, a=0.4, b=0.2, c=0.3, d=0.1, h=0.25)
    s = core_solver(v)
    t = pickle.loads(pickle.dumps(s))
    assert np.array_equal(np.asarray(t.map), np.asarray(s.map))
    assert t.solve_one(0.3, -0.2, G) == s.solve_one(0.3, -0.2, G)
