"""Calibration (paper §2.2): recover known constants from synthetic testbed data generated from the
model with seeded noise at the testbed's slips 0.1 .. 0.6; the scale degeneracy and its anchor;
the S_E line (eq. 10) through eq. 9's peaks, and its fallback; CSV input and its errors."""

from __future__ import annotations

import numpy as np
import pytest

from soilocp.analysis.calibration import PARAMETER_BOUNDS, efficiency_peak, fit_constants, fit_efficiency_line
from soilocp.analysis.testbed import TESTBED_SLIPS, build_testbed, read_testbed_csv, synthetic_testbed, write_testbed_csv
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants, load_constants, save_constants
from soilocp.model.ocp import max_traction, optimal_slip_efficiency, optimal_slip_traction
from soilocp.model.traction import gross_traction, net_traction, tractive_efficiency

SOILS = {"sand": 50.0, "gravel": 80.0, "grass": 200.0}
# "truth" deliberately away from the paper's constants (the start values), C4 = 0.04 so that a
# drawbar-only fit (which cannot see C4) still has the right C4
TRUTH = ModelConstants(C1=1.2, C2=0.012, C3=6.5, C4=0.04, C5=-4.0, C6=3.5)


def _truth_value(truth: ModelConstants, name: str) -> float:
    return getattr(truth, name) if name.startswith("C") else SOILS[name[2:-1]]


@pytest.mark.parametrize("with_gross", [False, True])
def test_noise_free_data_recovers_constants_exactly(with_gross):
    truth = TRUTH.model_copy(update={"C4": 0.06}) if with_gross else TRUTH
    data = synthetic_testbed(truth, SOILS, noise=0.0, with_gross=with_gross)
    res = fit_constants(data)
    assert res.rms < 1e-9
    for p in res.parameters:
        assert p.value == pytest.approx(_truth_value(truth, p.name), rel=1e-6), p.name
    assert res.parameter("C4").status == ("fitted" if with_gross else "fixed")
    assert res.parameter("K[sand]").status == "anchor"
    assert res.anchors == {"sand": 50.0}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noisy_testbed_recovers_constants_within_standard_errors(seed):
    data = synthetic_testbed(TRUTH, SOILS, slips=TESTBED_SLIPS, repeats=5, noise=0.01, seed=seed, with_gross=True)
    res = fit_constants(data)
    assert res.rms == pytest.approx(0.01, rel=0.25)  # the residual is the noise
    assert res.condition < 1e4
    for p in res.parameters:
        true = _truth_value(TRUTH, p.name)
        if p.std_error is None:
            assert p.value == true
            continue
        assert 0 < p.std_error < 0.5 * abs(true), p.name
        assert abs(p.value - true) < 4 * p.std_error, (p.name, p.value, true, p.std_error)
        assert abs(p.value - true) / abs(true) < 0.2, p.name
    # the quantities the robot uses: the OCPs of each calibrated soil
    for name, k in SOILS.items():
        k_fit = res.constants.soils[name]
        assert optimal_slip_traction(k_fit, res.constants) == pytest.approx(optimal_slip_traction(k, TRUTH), abs=0.01)
        assert max_traction(k_fit, res.constants) == pytest.approx(max_traction(k, TRUTH), abs=0.01)


def test_flat_ridge_stops_at_the_bound_and_is_reported():
    # seed 3, drawbar only: the noise favours C1 -> inf, C2 -> 0 (C1 (1 - e^{-C2 K}) ~ C1 C2 K);
    # the fit must stop at C1's physical bound, fast, and say the value is not an estimate
    data = synthetic_testbed(TRUTH, SOILS, noise=0.01, seed=3)
    res = fit_constants(data)
    c1 = res.parameter("C1")
    assert c1.status == "at bound" and c1.value == pytest.approx(PARAMETER_BOUNDS["C1"][1])
    assert any("C1 ended at the search bound" in n and "not estimates" in n for n in res.notes)
    # the same testbed with gross traction (wheel torque) determines C1
    res = fit_constants(synthetic_testbed(TRUTH, SOILS, noise=0.01, seed=3, with_gross=True))
    assert res.parameter("C1").status == "fitted"
    assert res.parameter("C1").value == pytest.approx(TRUTH.C1, rel=0.1)


def test_drawbar_only_fit_keeps_c4_and_says_so():
    data = synthetic_testbed(TRUTH, SOILS, noise=0.01, seed=4)
    res = fit_constants(data, initial=DEFAULT_CONSTANTS.model_copy(update={"C4": 0.07}))
    assert res.parameter("C4").status == "fixed" and res.parameter("C4").value == 0.07
    assert any("C4 cancels" in n for n in res.notes)
    assert res.n_free == 5 + 2  # C1 C2 C3 C5 C6, K gravel, K grass


def test_scale_degeneracy_is_exact_and_the_anchor_sets_the_scale():
    lam = 2.5
    scaled = TRUTH.model_copy(update={"C2": TRUTH.C2 / lam, "C5": TRUTH.C5 * lam, "C6": TRUTH.C6 * np.sqrt(lam)})
    s = np.linspace(-1, 1, 201)
    for k in SOILS.values():
        np.testing.assert_allclose(net_traction(s, lam * k, scaled), net_traction(s, k, TRUTH), atol=1e-12)
        np.testing.assert_allclose(gross_traction(s, lam * k, scaled), gross_traction(s, k, TRUTH), atol=1e-12)
        assert optimal_slip_traction(lam * k, scaled) == pytest.approx(optimal_slip_traction(k, TRUTH), rel=1e-12)
    # so anchoring sand at 125 instead of 50 scales every fitted K by 2.5 and fits the same curves
    data = synthetic_testbed(TRUTH, SOILS, noise=0.0, with_gross=True)
    a = fit_constants(data, anchor=("sand", 50.0))
    b = fit_constants(data, anchor=("sand", 125.0))
    assert b.constants.soils["grass"] == pytest.approx(lam * a.constants.soils["grass"], rel=1e-6)
    assert b.constants.C2 == pytest.approx(a.constants.C2 / lam, rel=1e-6)
    assert b.rms < 1e-9 and b.parameter("K[sand]").status == "anchor"
    assert any("common scale" in n and "sand=125" in n for n in b.notes)


def test_fixed_k_and_default_anchor_without_sand():
    data = synthetic_testbed(TRUTH, {"gravel": 80.0, "grass": 200.0, "clay": 150.0}, noise=0.0, with_gross=True)
    res = fit_constants(data)  # no sand: first data soil with a reference K (gravel) anchors
    assert res.anchors == {"gravel": 80.0}
    assert res.constants.soils["clay"] == pytest.approx(150.0, rel=1e-6)
    res = fit_constants(data, fixed_k={"gravel": 80.0, "grass": 200.0})
    assert {p.name: p.status for p in res.parameters}["K[grass]"] == "fixed"
    assert res.parameter("K[clay]").value == pytest.approx(150.0, rel=1e-6)
    # unfitted reference soils are kept and reported
    assert res.constants.soils["sand"] == 50.0
    assert any("kept from the initial constants" in n for n in res.notes)


def test_efficiency_line_refitted_when_the_model_has_interior_peaks():
    truth = TRUTH.model_copy(update={"C5": 5.0})  # positive C5: eq. 9 has peaks near S = 0.1
    expected = fit_efficiency_line(SOILS, truth)
    assert expected.fitted and all(0.05 < p < 0.25 for p in expected.peaks.values())
    data = synthetic_testbed(truth, SOILS, noise=0.005, seed=7, with_gross=True)
    res = fit_constants(data)
    assert res.efficiency.fitted
    for k in (50.0, 80.0, 120.0, 200.0):
        assert optimal_slip_efficiency(k, res.constants) == pytest.approx(optimal_slip_efficiency(k, truth.model_copy(update={"alpha": expected.alpha, "beta": expected.beta})), abs=0.01)
    # each fitted S_E peak is the numerical argmax of eq. 9 on a fine grid
    grid = np.linspace(0.01, 0.99, 98_001)
    for name, sp in res.efficiency.peaks.items():
        k = res.constants.soils[name]
        assert sp == pytest.approx(grid[np.argmax(tractive_efficiency(grid, k, res.constants))], abs=1e-4)


def test_efficiency_line_falls_back_without_interior_peaks():
    # paper-like constants (C5 < 0): TE > 1 near S = 0 for sand and gravel (docs/method.md §5)
    data = synthetic_testbed(TRUTH, SOILS, noise=0.005, seed=8, with_gross=True)
    init = DEFAULT_CONSTANTS.model_copy(update={"alpha": 600.0, "beta": -5000.0})
    res = fit_constants(data, initial=init)
    eff = res.efficiency
    assert not eff.fitted and (eff.alpha, eff.beta) == (600.0, -5000.0)
    assert (res.constants.alpha, res.constants.beta) == (600.0, -5000.0)
    assert eff.peaks["sand"] is None and "smallest slip" in eff.reasons["sand"]
    # grass alone has a peak: "some soils without a peak" is enough to keep alpha, beta
    assert eff.peaks["grass"] is not None and "sand" in eff.message and "grass" not in eff.message
    assert "not fitted" in eff.message and "§5" in eff.message


def test_efficiency_peak_paper_constants():
    assert efficiency_peak(50.0, DEFAULT_CONSTANTS)[0] is None
    sp, why = efficiency_peak(200.0, DEFAULT_CONSTANTS)
    assert why == "" and 0.01 < sp < 0.1
    with pytest.raises(ValueError, match="soil_strength"):
        efficiency_peak(-1.0, DEFAULT_CONSTANTS)


def test_constants_file_round_trip(tmp_path):
    data = synthetic_testbed(TRUTH, SOILS, noise=0.01, seed=5, with_gross=True)
    res = fit_constants(data)
    path = tmp_path / "constants.json"
    save_constants(res.constants, path)
    loaded = load_constants(path)
    assert loaded == res.constants
    assert set(SOILS) <= set(loaded.soils)
    assert loaded.C3 == res.parameter("C3").value


# ------------------------------------------------------------------------------------ CSV
def test_csv_round_trip(tmp_path):
    data = synthetic_testbed(TRUTH, SOILS, noise=0.01, seed=6, with_gross=True)
    path = tmp_path / "testbed.csv"
    write_testbed_csv(data, path)
    back = read_testbed_csv(path)
    assert back.soil == data.soil and back.soils == ["sand", "gravel", "grass"]
    np.testing.assert_allclose(back.mu, data.mu, rtol=1e-5)
    np.testing.assert_allclose(back.gross, data.gross, rtol=1e-5)


def test_csv_force_columns(tmp_path):
    path = tmp_path / "forces.csv"
    path.write_text(
        "soil,slip,drawbar_pull,normal_load,gross_force,comment\n"
        "sand,0.1,50,200,60,first\n"
        "\n"
        "sand,0.2,70,200,85,\n"
    )
    d = read_testbed_csv(path)
    np.testing.assert_allclose(d.mu, [0.25, 0.35])
    np.testing.assert_allclose(d.gross, [0.3, 0.425])
    assert d.soil == ("sand", "sand")


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("soil,slip\nsand,0.1\n", r"line 1: missing column\(s\) \['mu'\]"),
        ("soil,slip,mu\nsand,0.1,0.3\nsand,abc,0.3\n", r"line 3, column 'slip': 'abc' is not a number"),
        ("soil,slip,mu\nsand,0.1,nan\n", r"line 2, column 'mu': 'nan' is not a finite number"),
        ("soil,slip,mu\nsand,0.1,\n", r"line 2, column 'mu': missing value"),
        ("soil,slip,mu\n,0.1,0.3\n", r"line 2, column 'soil': empty soil label"),
        ("soil,slip,mu\nsand,1.5,0.3\n", r"line 2, column 'slip': 1.5 is outside \[-1, 1\]"),
        ("soil,slip,drawbar_pull,normal_load\nsand,0.1,5,0\n", r"line 2, column 'normal_load': 0.0 must be > 0"),
        ("soil,slip,drawbar_pull\nsand,0.1,5\n", r"missing column\(s\) \['normal_load'\]"),
        ("soil,slip,mu,drawbar_pull\nsand,0.1,0.3,5\n", r"either 'mu' or 'drawbar_pull'"),
        ("soil,slip,mu\nsand,0.1,0.3,9\n", r"line 2: more fields"),
        ("", r"empty file"),
        ("soil,slip,mu\n", r"no data rows"),
    ],
)
def test_bad_csv_names_line_and_column(tmp_path, text, pattern):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=pattern):
        read_testbed_csv(path)


def test_missing_csv_file(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        read_testbed_csv(tmp_path / "nope.csv")


# -------------------------------------------------------------------------- ill-posed fits
def test_single_soil_is_rejected():
    data = synthetic_testbed(TRUTH, {"sand": 50.0}, noise=0.0)
    with pytest.raises(ValueError, match="at least two soils"):
        fit_constants(data)


def test_too_few_slips_per_soil_is_rejected():
    data = synthetic_testbed(TRUTH, SOILS, slips=(0.2, 0.4), noise=0.0)
    with pytest.raises(ValueError, match="distinct slip"):
        fit_constants(data)


def test_anchor_must_be_in_the_data_and_positive():
    data = synthetic_testbed(TRUTH, SOILS, noise=0.0)
    with pytest.raises(ValueError, match="not in the data"):
        fit_constants(data, anchor=("clay", 100.0))
    with pytest.raises(ValueError, match="anchor K"):
        fit_constants(data, anchor=("sand", -5.0))
    unknown = synthetic_testbed(TRUTH, {"x": 50.0, "y": 90.0}, noise=0.0)
    with pytest.raises(ValueError, match="anchor"):
        fit_constants(unknown)


def test_array_input_validation():
    with pytest.raises(ValueError, match="equal lengths"):
        build_testbed([0.1, 0.2], [0.3], ["sand", "sand"])
    with pytest.raises(ValueError, match="slip"):
        build_testbed([0.1, float("nan")], [0.3, 0.4], ["sand", "sand"])
    with pytest.raises(ValueError, match="slip must be in"):
        build_testbed([0.1, 2.0], [0.3, 0.4], ["sand", "sand"])
    with pytest.raises(ValueError, match="noise"):
        synthetic_testbed(TRUTH, SOILS, noise=float("nan"))
    with pytest.raises(ValueError, match="soils"):
        synthetic_testbed(TRUTH, {"sand": -1.0})
