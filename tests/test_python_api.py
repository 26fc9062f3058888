"""soilocp.estimate: dicts, DataFrames and paths in, the CLI's records out; missing values as missing."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import pytest

import soilocp
from soilocp.api import SamplesRejectedWarning, VehicleMismatchWarning
from soilocp.estimation.estimate import estimate_lines
from soilocp.estimation.pipeline import PipelineConfig


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("api")
    subprocess.run([sys.executable, "-m", "soilocp.cli", "simulate", "--scenario", "sand", "--duration", "8",
                    "--out", str(d / "s.jsonl"), "--truth", str(d / "t.jsonl")], check=True, capture_output=True)
    return d / "s.jsonl"


def test_dicts_and_path_give_the_cli_records(log):
    lines = log.read_text().splitlines()
    want = list(estimate_lines(lines, PipelineConfig()))
    assert soilocp.estimate([json.loads(x) for x in lines]) == want
    assert soilocp.estimate(str(log)) == want
    assert soilocp.estimate(log) == want


def test_dataframe_with_missing_ground_speed_is_estimated_not_rejected(log):
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame([json.loads(x) for x in log.read_text().splitlines()])
    df.loc[::4, "ground_speed"] = float("nan")  # what a DataFrame makes of a missing value
    df["seq"] = df["seq"].astype(float)  # and of an integer column that had a gap once
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = soilocp.estimate(df)
    assert isinstance(out, pd.DataFrame) and len(out) == len(df)
    missing = out.iloc[::4]
    assert (missing["reason_code"] == "not_identifiable").all() and missing["soil_strength"].isna().all()
    assert (out["confirmed"] == (out["status"] == "ok")).all() and out["confirmed"].any()
    assert isinstance(soilocp.estimate(df, as_frame=False), list)


def test_rejections_warn_and_all_rejected_raises(log):
    rows = [json.loads(x) for x in log.read_text().splitlines()[:200]]
    rows[5]["wheel_speed"] = [1.0, float("nan"), 1.0, 1.0]
    with pytest.warns(SamplesRejectedWarning, match=r"1 of 200 samples rejected \(non_finite 1\); the first, sample 5"):
        out = soilocp.estimate(rows)
    assert len(out) == 199
    with pytest.raises(ValueError, match="every sample was rejected"):
        soilocp.estimate([{"seq": 0}])
    with pytest.raises(ValueError, match="no sample given"):
        soilocp.estimate([])
    with pytest.raises(TypeError, match="a list of dicts"):
        soilocp.estimate(3)


def test_vehicle_as_a_dict_typos_and_mismatch(log):
    rows = [json.loads(x) for x in log.read_text().splitlines()]
    with pytest.raises(ValueError, match="did you mean 'wheel_radius'"):
        soilocp.estimate(rows, vehicle={"wheel_radiu": 0.3})
    for r in rows:
        r["wheel_speed"] = [w / 2 for w in r["wheel_speed"]]
    with pytest.warns(VehicleMismatchWarning, match="wheel radius is about"):
        soilocp.estimate(rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        soilocp.estimate(rows, vehicle={"wheel_radius": 0.3})


def test_import_soilocp_stays_lean():
    out = subprocess.run([sys.executable, "-c", "import sys, soilocp; print('numpy' in sys.modules)"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
