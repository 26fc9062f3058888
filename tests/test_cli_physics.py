"""`soilocp ocp`, `soilocp curves`, `soilocp calibrate`: output, files written, and clean errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from soilocp.analysis.testbed import synthetic_testbed, write_testbed_csv
from soilocp.cli.main import main
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants, load_constants, save_constants
from soilocp.analysis.curves import FIGURE_FILES

KEYS = {"soil_strength", "mu_T", "S_T", "S_E"}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run(*args: str):
    return CliRunner().invoke(main, list(args))


# -------------------------------------------------------------------------------------- ocp
def test_ocp_json_single_k_has_exactly_the_four_keys():
    r = run("ocp", "--soil-strength", "50", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert set(out) == KEYS
    assert out["soil_strength"] == 50.0
    assert (round(out["S_T"], 4), round(out["mu_T"], 4), round(out["S_E"], 4)) == (0.2626, 0.3828, 0.1197)


def test_ocp_several_k_json_list():
    r = run("ocp", "-k", "80", "--soil-strength", "200", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert [o["soil_strength"] for o in out] == [80.0, 200.0]
    assert all(set(o) == KEYS for o in out)
    assert round(out[1]["mu_T"], 4) == 0.9754


def test_ocp_table_human_and_json():
    r = run("ocp", "--table")
    assert r.exit_code == 0, r.output
    for text in ("sand", "gravel", "EST", "grass", "0.3828", "0.4060", "0.0911"):
        assert text in r.output
    r = run("ocp", "--table", "--json")
    out = json.loads(r.output)
    assert [o["soil_strength"] for o in out] == sorted(DEFAULT_CONSTANTS.soils.values())


def test_ocp_uses_the_constants_file(tmp_path):
    path = tmp_path / "c.json"
    save_constants(ModelConstants(C3=6.0, alpha=500.0, beta=-4000.0), path)
    default = json.loads(run("ocp", "-k", "80", "--json").output)
    custom = json.loads(run("ocp", "-k", "80", "--json", "--constants", str(path)).output)
    assert custom["S_T"] != pytest.approx(default["S_T"])
    assert custom["S_E"] == pytest.approx((80 - 500) / -4000)


@pytest.mark.parametrize("k", ["0", "-50", "nan", "inf", "abc", "1e-320"])
def test_ocp_bad_k_is_a_usage_error(k):
    r = run("ocp", "--soil-strength", k)
    assert r.exit_code == 2
    assert "--soil-strength" in r.output or "'-k'" in r.output
    assert "Traceback" not in r.output
    assert not isinstance(r.exception, ValueError)


def test_ocp_needs_k_or_table():
    r = run("ocp")
    assert r.exit_code == 2 and "--table" in r.output


@pytest.mark.parametrize("content", ["{not json", '{"C1": -1}', '{"bogus": 1}'])
def test_ocp_bad_constants_file(tmp_path, content):
    path = tmp_path / "c.json"
    path.write_text(content)
    r = run("ocp", "-k", "50", "--constants", str(path))
    assert r.exit_code == 2 and "--constants" in r.output and "Traceback" not in r.output


def test_ocp_bad_k_in_a_real_process_exits_cleanly():
    p = subprocess.run(
        [sys.executable, "-m", "soilocp.cli", "ocp", "--soil-strength", "nan"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2
    assert "Traceback" not in p.stderr and "--soil-strength" in p.stderr


# ----------------------------------------------------------------------------------- curves
def test_curves_writes_three_pngs(tmp_path):
    out = tmp_path / "figs"
    r = run("curves", "--out", str(out))
    assert r.exit_code == 0, r.output
    for name in FIGURE_FILES.values():
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 20_000, name
        assert name in r.output


def test_curves_unknown_soil_is_a_usage_error(tmp_path):
    r = run("curves", "--out", str(tmp_path), "--soil", "moon-dust")
    assert r.exit_code == 2 and "moon-dust" in r.output and "Traceback" not in r.output


# -------------------------------------------------------------------------------- calibrate
@pytest.fixture
def testbed_csv(tmp_path) -> Path:
    truth = ModelConstants(C1=1.2, C2=0.012, C3=6.5, C5=-4.0, C6=3.5)
    path = tmp_path / "testbed.csv"
    write_testbed_csv(synthetic_testbed(truth, {"sand": 50.0, "gravel": 80.0, "grass": 200.0}, seed=1), path)
    return path


def test_calibrate_prints_table_and_writes_loadable_constants(tmp_path, testbed_csv):
    out = tmp_path / "constants.json"
    r = run("calibrate", str(testbed_csv), "--out", str(out))
    assert r.exit_code == 0, r.output
    c = load_constants(out)
    assert c.C3 == pytest.approx(6.5, rel=0.1)
    assert c.soils["grass"] == pytest.approx(200.0, rel=0.25)
    for text in ("± std error", "K[gravel]", "anchor", "common scale", "sand=50", "C4 cancels", "S_E line not fitted", "wrote"):
        assert text in r.output, text
    # the rest of the system reads it
    r = run("ocp", "-k", "80", "--json", "--constants", str(out))
    assert r.exit_code == 0 and set(json.loads(r.output)) == KEYS


def test_calibrate_anchor_option_rescales_k(tmp_path, testbed_csv):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert run("calibrate", str(testbed_csv), "--out", str(a)).exit_code == 0
    r = run("calibrate", str(testbed_csv), "--out", str(b), "--anchor", "sand=100")
    assert r.exit_code == 0, r.output
    assert load_constants(b).soils["grass"] == pytest.approx(2 * load_constants(a).soils["grass"], rel=1e-4)


def test_calibrate_bad_csv_names_line_and_column(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("soil,slip,mu\nsand,0.1,0.3\ngravel,0.2,oops\n")
    r = run("calibrate", str(bad), "--out", str(tmp_path / "c.json"))
    assert r.exit_code == 2
    assert "line 3, column 'mu'" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("anchor", ["sand", "sand=-1", "=50", "sand=nan"])
def test_calibrate_bad_anchor(tmp_path, testbed_csv, anchor):
    r = run("calibrate", str(testbed_csv), "--out", str(tmp_path / "c.json"), "--anchor", anchor)
    assert r.exit_code == 2 and "--anchor" in r.output


def test_calibrate_ill_posed_data_is_a_usage_error(tmp_path):
    one = tmp_path / "one.csv"
    write_testbed_csv(synthetic_testbed(DEFAULT_CONSTANTS, {"sand": 50.0}), one)
    r = run("calibrate", str(one), "--out", str(tmp_path / "c.json"))
    assert r.exit_code == 2 and "at least two soils" in r.output
