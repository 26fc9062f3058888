"""``soilocp accuracy --robustness`` on a tiny case, and the band / confidently-wrong scores it
adds to soilocp.analysis.evaluation.  No accuracy thresholds on the estimator here: the table is the
measurement."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from soilocp.cli.main import main
from soilocp.commands.robustness_table import COLUMNS
from soilocp.analysis.evaluation import evaluate_records, results_as_json
from soilocp.analysis.robustness import run_variant, summarize


def _truth(seq, k, stamp):
    return {"vehicle_id": "r", "seq": seq, "stamp": stamp, "soil_strength": k, "soil_class": "x",
            "mu_T": 0.5, "S_T": 0.2, "S_E": 0.1}


def _est(seq, k, std, status="ok"):
    return {"vehicle_id": "r", "seq": seq, "soil_strength": k, "soil_strength_std": std, "status": status,
            "soil_class": "x", "mu_T": 0.5, "S_T": 0.2, "S_E": 0.1}


def test_band_coverage_and_confident_wrong_count_only_settled_samples():
    truth = [_truth(i, 100.0, float(i)) for i in range(7)]
    est = [
        _est(0, 500.0, 1.0),  # before the 2 s settle: ignored
        _est(1, 500.0, 1.0),  # ignored
        _est(2, 110.0, 10.0),  # inside 2 std
        _est(3, 125.0, 10.0),  # outside, 25 % off: not "confidently wrong"
        _est(4, 140.0, 10.0),  # outside, 40 % off with status ok: confidently wrong
        _est(5, 140.0, 10.0, status="uncertain"),  # flagged
        _est(6, None, None, status="no_estimate"),
    ]
    (seg,) = evaluate_records(truth, est)
    assert seg.settled_samples == 5 and seg.band_samples == 4
    assert seg.band_coverage == pytest.approx(1 / 4)
    assert seg.confident_wrong == 1
    assert seg.std_rel_median == pytest.approx((10.0 / 125 + 10.0 / 140) / 2)  # median of std/K
    assert len(seg.std_rel) == 4 and "std_rel" not in results_as_json([seg])[0]  # pooled by --robustness only


def test_the_band_is_the_one_the_record_serves_where_it_serves_one():
    truth = [_truth(i, 100.0, float(i)) for i in range(5)]
    est = [_est(i, 20.0, 30.0) for i in range(2)]  # before the settle
    # a wide belief low in K: K + 2 std = 80 misses the truth, the served ln-K band [2.7, 148] holds it
    est += [dict(_est(i, 20.0, 30.0), soil_strength_low=20.0 * 0.135, soil_strength_high=20.0 * 7.39) for i in (2, 3)]
    est += [_est(4, 20.0, 30.0)]  # a record without a served band: K +- 2 std
    (seg,) = evaluate_records(truth, est)
    assert seg.band_samples == 3 and seg.band_coverage == pytest.approx(2 / 3)


def test_cruise_is_not_identifiable_and_the_row_says_so():
    run = run_variant("cruise", 0, duration=4.0)
    (row,) = summarize([run])
    assert row["identifiable"] == "no"
    assert sum(run.statuses.values()) == run.samples == 400
    assert row["status_shares"].get("no_estimate", 0.0) + row["status_shares"].get("holding", 0.0) > 0.5
    assert row["pass"] == (row["confident_wrong_share"] <= 0.05)


def test_robustness_command_prints_one_row_per_variant(tmp_path):
    out = tmp_path / "rob.json"
    res = CliRunner().invoke(
        main,
        ["accuracy", "--robustness", "--variant", "nominal", "--variant", "epoch-stamps", "--duration", "5",
         "--jobs", "1", "--json", str(out)],
    )
    assert res.exit_code in (0, 1), res.output
    for col in COLUMNS:
        assert col in res.output
    assert "nominal" in res.output and "epoch-stamps" in res.output
    data = json.loads(out.read_text())
    assert [r["variant"] for r in data["variants"]] == ["nominal", "epoch-stamps"]
    for r in data["variants"]:
        assert r["samples"] == 500 and r["identifiable"] == "yes"
        assert r["pass"] == (not r["missed"])
        # the verdict is exit-coded: any missed variant makes the command fail
    assert (res.exit_code == 1) == any(not r["pass"] for r in data["variants"])


def test_robustness_options_are_checked():
    r = CliRunner().invoke(main, ["accuracy", "--robustness", "--variant", "bogus"])
    assert r.exit_code == 2 and "rear-mirror" in r.output
    r = CliRunner().invoke(main, ["accuracy", "--seeds", "2"])
    assert r.exit_code == 2 and "--robustness" in r.output


def test_seeds_pool_into_one_row_per_variant():
    from soilocp.analysis.robustness import run_robustness

    runs = run_robustness(["cruise"], seeds=(0, 1), duration=1.0, jobs=1)
    assert [(r.variant, r.seed) for r in runs] == [("cruise", 0), ("cruise", 1)]
    (row,) = summarize(runs)
    assert row["seeds"] == [0, 1] and row["samples"] == 200
    assert sum(row["status_shares"].values()) == pytest.approx(1.0)


def test_markdown_table_for_the_readme():
    res = CliRunner().invoke(main, ["accuracy", "--robustness", "--variant", "cruise", "--duration", "1", "--markdown",
                                    "--jobs", "1"])
    lines = [ln for ln in res.output.splitlines() if ln.startswith("|")]
    assert len(lines) == 3 and lines[1] == "|" + "---|" * len(COLUMNS)
    assert all(ln.replace("\\|", "").count("|") == len(COLUMNS) + 1 for ln in lines)
    assert lines[2].startswith("| cruise | no |")


def test_convergence_is_judged_while_every_wheel_is_on_the_segment_soil():
    # 100 -> 200 at t = 5; the front wheels (2, 3) reach the 200 soil at t = 4.8, the estimate follows them
    truth, est = [], []
    for i in range(100):
        t = i * 0.1
        k = 100.0 if t < 5.0 else 200.0
        front = 100.0 if t < 4.8 else 200.0
        rec = _truth(i, k, t)
        rec["wheel_soil_strength"] = (k, front, front, k)
        truth.append(rec)
        k_est = 100.0 if t < 4.8 else (150.0 if t < 5.5 else 200.0)
        est.append(_est(i, k_est if t >= 0.3 else 300.0, 5.0))
    first, second = evaluate_records(truth, est)
    assert first.convergence_s == pytest.approx(0.3)  # not "never": 4.8..5 s is the next soil's
    assert second.convergence_s == pytest.approx(0.5)
    # without per-wheel truth the whole segment is judged: the tail leaves the band
    for rec in truth:
        del rec["wheel_soil_strength"]
    assert evaluate_records(truth, est)[0].convergence_s is None


def test_a_config_file_sets_the_estimator_the_variants_are_judged_with(tmp_path):
    """--config is the estimator's (soilocp estimate --config): a torque constant taken as known
    (gross_scale_sigma 0) narrows the band on the same drive; a bad key is a usage error naming it."""
    known = tmp_path / "known.json"
    known.write_text(json.dumps({"soil": {"gross_scale_sigma": 0.0}}))
    out_default, out_known = tmp_path / "default.json", tmp_path / "known-out.json"
    runner = CliRunner()
    for extra, out in (([], out_default), (["--config", str(known)], out_known)):
        res = runner.invoke(main, ["accuracy", "--robustness", "--variant", "nominal", "--duration", "8", "--jobs", "1",
                                   "--json", str(out), *extra])
        assert res.exit_code in (0, 1), res.output
    assert f"config {known}" in res.output  # the title names the settings judged
    (default_row,), (known_row,) = (json.loads(p.read_text())["variants"] for p in (out_default, out_known))
    assert known_row["std_rel_median"] < default_row["std_rel_median"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"soil": {"gross_scale": 0.0}}))
    res = runner.invoke(main, ["accuracy", "--robustness", "--variant", "cruise", "--config", str(bad)])
    assert res.exit_code == 2 and "soil.gross_scale" in res.output


def test_an_ok_record_is_judged_against_the_nearest_soil_under_its_wheels():
    """The last b/V s of a segment: the front wheels are on the next soil.  A K that reads it is not
    confidently wrong; a K between the two soils, more than 30 % from both, still is."""
    truth = [_truth(i, 200.0, float(i)) for i in range(6)]
    for rec in truth[4:]:
        rec["wheel_soil_strength"] = (200.0, 50.0, 50.0, 200.0)  # front wheels on sand
    est = [_est(i, 200.0, 10.0) for i in range(4)] + [_est(4, 55.0, 5.0), _est(5, 120.0, 10.0)]
    (seg,) = evaluate_records(truth, est)
    assert seg.confident_wrong == 1  # 120: 40 % from 200, 140 % from 50; 55 reads the front wheels' sand
    for rec in truth:  # without per-wheel truth: the soil under the CoM, both count
        rec.pop("wheel_soil_strength", None)
    assert evaluate_records(truth, est)[0].confident_wrong == 2


def test_judged_from_moves_k_and_ocp_scores_but_not_the_ok_count_or_the_band():
    """A drive whose first seconds cannot give K (the accelerate/brake rows' opening swing): K's median,
    p90 and the OCP errors judge from ``judged_from`` on; an ``ok`` record 40 % off before it still counts."""
    truth = [_truth(i, 100.0, float(i)) for i in range(10)]
    est = ([_est(i, None, None, status="no_estimate") for i in range(2, 4)] + [_est(4, 140.0, 10.0)]
           + [_est(i, 101.0, 5.0) for i in range(5, 10)])
    (whole,) = evaluate_records(truth, est)
    (late,) = evaluate_records(truth, est, judged_from=5.0)
    assert whole.k_p90_rel is None and whole.k_median_rel == pytest.approx(0.01)  # 2 misses of 8: p90 is one
    assert late.k_p90_rel == pytest.approx(0.01) and late.k_median_rel == pytest.approx(0.01)
    assert whole.confident_wrong == late.confident_wrong == 1
    assert (whole.band_samples, whole.coverage) == (late.band_samples, late.coverage) == (6, 0.75)
    assert "judged from 4 s" in CliRunner().invoke(
        main, ["accuracy", "--robustness", "--variant", "reverse-braking", "--duration", "6", "--jobs", "1"]).output


def test_a_record_serves_k_with_its_band_in_ln_k_and_the_truth_of_a_noisy_cruise_lies_in_it():
    """GNSS-grade speed at constant speed reads as slip: the K served is wide, its band (Gaussian in ln K, so
    far from symmetric about K) holds the truth, and a record without K serves no band."""
    from soilocp.estimation.estimate import estimate_lines
    from soilocp.estimation.pipeline import PipelineConfig
    from soilocp.sim.variants import get_variant

    v, cfg = get_variant("gnss-cruise"), PipelineConfig()
    pairs = list(v.simulate(1, duration=20.0, nominal=cfg.vehicle, constants=cfg.constants))
    truth = {t.seq: t.soil_strength for _, t in pairs}
    recs = list(estimate_lines([s.model_dump_json() for s, _ in pairs],
                               cfg.model_copy(update={"vehicle": v.known_vehicle(cfg.vehicle)})))
    served = [r for r in recs if r["soil_strength"] is not None]
    assert served and all(r["soil_strength_low"] is None and r["soil_strength_high"] is None
                          for r in recs if r["soil_strength"] is None)
    for r in served:
        k, lo, hi = r["soil_strength"], r["soil_strength_low"], r["soil_strength_high"]
        assert lo < k < hi and lo * hi == pytest.approx(k * k, rel=1e-9)
    inside = [r["soil_strength_low"] <= truth[r["seq"]] <= r["soil_strength_high"] for r in served]
    linear = [abs(r["soil_strength"] - truth[r["seq"]]) <= 2 * r["soil_strength_std"] for r in served]
    assert sum(inside) >= 0.9 * len(served) > sum(linear), (sum(inside), sum(linear), len(served))
