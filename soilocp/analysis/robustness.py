"""The robustness evaluation (``soilocp accuracy --robustness``): every variant of
:mod:`soilocp.sim.variants` through simulate -> estimate -> evaluate, judged against the targets.

The estimator runs exactly as a user runs it: :func:`soilocp.estimation.estimate.estimate_lines` with the
default :class:`PipelineConfig` (NOMINAL vehicle), on the sensor lines the variant produced.  The
scoring is :func:`soilocp.analysis.evaluation.evaluate_records` per terrain segment; a row aggregates a
variant's segments (and seeds): the WORST segment for the K errors, the convergence after a
terrain change and the OCP errors (as ``soilocp accuracy`` does); the drive's pooled settled
samples for the 2-std band coverage, the median std/K (K ~ 300 saturates, §9: its band is
rightly wider than the drive's) and the confidently wrong share; all samples for the status
shares.  Over seeds, the worst.

Verdicts:

* every row: no confidently wrong number, i.e. NO settled record with status ``ok`` and K more
  than 30 % off (the column ``ok>30%`` counts them, worst seed);
* identifiable (``yes``): K median <= 10 %, p90 <= 25 %, back within +-15 % in < 2 s after every
  terrain change, >= 90 % of truths within +-2 std, median std/K <= 0.15 (no inflated band),
  median |mu_T|, |S_T|, |S_E| errors <= 0.02;
* ``limited`` (a scale error the data of this drive cannot separate from K) and not identifiable
  (``no``) are judged by their band and their reason, NOT by the K error: >= 90 % of truths within
  +-2 std wherever K is served with a band (a ``no`` row that serves none passes this), and where
  the variant names what limits K (``Variant.reason_names``, e.g. the torque scale), at least half
  of the settled flagged records that serve K name it.
"""

from __future__ import annotations

import json
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from soilocp.analysis.accuracy import RunResult, estimate_and_score
from soilocp.analysis.evaluation import TARGETS, UNFLAGGED_ERROR_REL, UNFLAGGED_OCP_ERROR, SegmentResult
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.sim.variants import get_variant, list_variants

#: Targets of the robustness table; the K and OCP numbers are soilocp.analysis.evaluation's.
ROBUSTNESS_TARGETS = {
    "k_median_rel": TARGETS["k_median_rel"],
    "k_p90_rel": TARGETS["k_p90_rel"],
    "convergence_s": 2.0,
    "convergence_band": TARGETS["convergence_band"],
    "band_coverage": 0.90,
    "std_rel_median": 0.15,
    "ocp_median_abs": TARGETS["ocp_median_abs"],
    "unflagged_error_rel": UNFLAGGED_ERROR_REL,
    # another tyre (Variant.tyre): the OCPs against the true curve's peak once a sweep has shown it
    "tyre_mu_T_p90_abs": 0.05,
    "tyre_S_T_p90_abs": 0.03,
    "unflagged_ocp_error": UNFLAGGED_OCP_ERROR,
    "ok_ocp_off_count": 0,
    "confident_wrong_share": 0.05,  # the share rule, superseded by the count (kept in the JSON)
    "confident_wrong_count": 0,
    "reason_named_share": 0.5,
    "settle_s": TARGETS["settle_s"],
}

#: Statuses whose share the table shows (counted by their string: the estimator's Literal grows).
SHOWN_STATUSES = ("no_estimate", "not_observable", "model_mismatch")


@dataclass
class VariantRun:
    """One variant, one seed: the per-segment scores and the status counts of every sample."""

    variant: str
    seed: int
    samples: int
    estimate_rate: float
    segments: list[SegmentResult]
    statuses: dict[str, int]
    rejected: int


def run_variant(name: str, seed: int = 0, duration: Optional[float] = None,
                config: Optional[PipelineConfig] = None) -> VariantRun:
    """simulate (the variant) -> estimate -> evaluate, in this process.  ``config`` (None = the
    defaults) is the estimator's; the variant changes the true vehicle relative to its vehicle."""
    variant = get_variant(name)
    cfg = config or PipelineConfig()
    pairs = variant.simulate(seed, duration=duration, nominal=cfg.vehicle, constants=cfg.constants)
    if variant.robot:  # the robot's own vehicle file (a skid steer): the estimator knows it
        cfg = cfg.model_copy(update={"vehicle": variant.known_vehicle(cfg.vehicle)})
    n, rate, segs, summary = estimate_and_score(pairs, cfg, ROBUSTNESS_TARGETS["settle_s"], variant.reason_names,
                                                variant.judged_from, variant.ocp_after)
    return VariantRun(name, seed, n, rate, segs, dict(summary.statuses), len(summary.rejected))


def _run_args(args) -> VariantRun:
    return run_variant(*args)


def run_robustness(variants: Sequence[str] | None = None, seeds: Sequence[int] = (0,), duration: Optional[float] = None,
                   jobs: int = 2, config: Optional[PipelineConfig] = None) -> list[VariantRun]:
    names = list(variants) if variants else [v.name for v in list_variants()]
    for n in names:
        get_variant(n)  # unknown names fail before any work starts
    jobs_list = [(n, s, duration, config) for n in names for s in seeds]
    if jobs <= 1:
        return [run_variant(*a) for a in jobs_list]
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(_run_args, jobs_list))


def _worst(vals, pick=max):
    """Worst over runs; None (a target that was never reached) wins."""
    if any(v is None for v in vals):
        return None
    return pick(vals) if vals else None


def _one_row(run: VariantRun) -> dict:
    segs = run.segments
    w = RunResult(run.variant, "", True, run.samples, run.estimate_rate, segs, run.statuses).worst()
    banded = sum(s.band_samples for s in segs)
    hits = sum((s.band_coverage or 0.0) * s.band_samples for s in segs)
    settled = sum(s.settled_samples for s in segs)
    std_rel = [q for s in segs for q in s.std_rel]
    total = max(sum(run.statuses.values()), 1)
    return {
        "k_median_rel": w["k_median_rel"],
        "k_p90_rel": w["k_p90_rel"],
        "band_coverage": hits / banded if banded else None,
        "std_rel_median": float(np.median(std_rel)) if std_rel else None,
        "change_convergence_s": w["change_convergence_s"],
        "terrain_changes": len(segs) - 1,
        "mu_T_err": _worst([s.mu_T_median_abs for s in segs]),
        "S_T_err": _worst([s.S_T_median_abs for s in segs]),
        "S_E_err": _worst([s.S_E_median_abs for s in segs]),
        "mu_T_p90": _worst([s.mu_T_p90_abs for s in segs]),
        "S_T_p90": _worst([s.S_T_p90_abs for s in segs]),
        "ok_ocp_off": sum(s.ok_ocp_off for s in segs),
        "confident_wrong_share": sum(s.confident_wrong for s in segs) / max(settled, 1),
        "confident_wrong": sum(s.confident_wrong for s in segs),
        "flagged": sum(s.flagged for s in segs),
        "reason_named_share": (sum(s.flagged_named for s in segs) / sum(s.flagged for s in segs)
                               if any(s.flagged for s in segs) else None),
        "status_shares": {k: v / total for k, v in run.statuses.items()},
    }


def _verdict(identifiable: str, row: dict, reason_names: str = "", tyre: bool = False,
             curve_shown: bool = True) -> tuple[bool, list[str]]:
    """The row's checks by the targets (module doc); ``tyre``: the true wheel is not the estimator's
    (Variant.tyre), so K is on that wheel's own scale (docs/method.md §14: a soil's K and the wheel's constants
    are not separable) and the row is judged by its OCPs against the true curve's peak instead of by K, where the
    drive shows that peak (``curve_shown``), by its honesty alone where it does not."""
    t = ROBUSTNESS_TARGETS

    def le(v, lim):
        return v is not None and v <= lim

    checks = {"okOCP": row["ok_ocp_off"] <= t["ok_ocp_off_count"]}
    if tyre:
        if curve_shown:
            checks["OCP p90"] = le(row["mu_T_p90"], t["tyre_mu_T_p90_abs"]) and le(row["S_T_p90"], t["tyre_S_T_p90_abs"])
        missed = [k for k, ok in checks.items() if not ok]
        return not missed, missed
    checks["ok>30%"] = row["confident_wrong"] <= t["confident_wrong_count"]
    if identifiable in ("yes", "limited"):
        checks["2std"] = row["band_coverage"] is not None and row["band_coverage"] >= t["band_coverage"]
    elif row["band_coverage"] is not None:  # "no": a band it serves must hold the truth all the same
        checks["2std"] = row["band_coverage"] >= t["band_coverage"]
    if reason_names and identifiable != "yes":
        checks["reason"] = row["reason_named_share"] is not None and row["reason_named_share"] >= t["reason_named_share"]
    if identifiable == "yes":
        ocp = [row["mu_T_err"], row["S_T_err"], row["S_E_err"]]
        checks.update({
            "K med": le(row["k_median_rel"], t["k_median_rel"]),
            "K p90": le(row["k_p90_rel"], t["k_p90_rel"]),
            "conv": row["terrain_changes"] == 0
            or (row["change_convergence_s"] is not None and row["change_convergence_s"] < t["convergence_s"]),
            "std/K": le(row["std_rel_median"], t["std_rel_median"]),
            "OCP": all(le(v, t["ocp_median_abs"]) for v in ocp),
        })
    missed = [k for k, ok in checks.items() if not ok]
    return not missed, missed


def summarize(runs: list[VariantRun]) -> list[dict]:
    """One row per variant (in the order first seen): worst over its seeds, mean status shares."""
    by_name: dict[str, list[VariantRun]] = {}
    for r in runs:
        by_name.setdefault(r.variant, []).append(r)
    rows = []
    for name, vruns in by_name.items():
        v = get_variant(name)
        per = [_one_row(r) for r in vruns]
        row = {
            "variant": name,
            "description": v.description,
            "identifiable": v.identifiable,
            "why_limited": v.why_limited,
            "judged_from": v.judged_from,  # s: K and the OCPs judged from here (Variant.judged_from)
            "seeds": [r.seed for r in vruns],
            "samples": sum(r.samples for r in vruns),
            "rejected": sum(r.rejected for r in vruns),
            "estimate_rate": min(r.estimate_rate for r in vruns),
        }
        for key in ("k_median_rel", "k_p90_rel", "std_rel_median", "change_convergence_s", "mu_T_err", "S_T_err", "S_E_err",
                    "confident_wrong_share", "confident_wrong", "mu_T_p90", "S_T_p90", "ok_ocp_off"):
            row[key] = _worst([p[key] for p in per])
        row["band_coverage"] = _worst([p["band_coverage"] for p in per], pick=min)
        row["reason_names"] = v.reason_names
        row["reason_named_share"] = _worst([p["reason_named_share"] for p in per], pick=min)
        row["terrain_changes"] = min(p["terrain_changes"] for p in per)
        names = sorted({k for p in per for k in p["status_shares"]})
        row["status_shares"] = {k: sum(p["status_shares"].get(k, 0.0) for p in per) / len(per) for k in names}
        row["tyre"] = v.tyre is not None
        row["curve_shown"] = v.curve_shown
        row["pass"], row["missed"] = _verdict(v.identifiable, row, v.reason_names, row["tyre"], v.curve_shown)
        rows.append(row)
    return rows


def rows_json(rows: list[dict], runs: list[VariantRun]) -> str:
    detail = [
        {"variant": r.variant, "seed": r.seed, "samples": r.samples, "statuses": r.statuses,
         "segments": [{"soil": s.soil_class, "K": s.soil_strength, "k_median_rel": s.k_median_rel,
                       "k_p90_rel": s.k_p90_rel, "convergence_s": s.convergence_s, "band_coverage": s.band_coverage,
                       "std_rel_median": s.std_rel_median, "confident_wrong": s.confident_wrong,
                       "mu_T_err": s.mu_T_median_abs, "S_T_err": s.S_T_median_abs, "S_E_err": s.S_E_median_abs,
                       "mu_T_p90": s.mu_T_p90_abs, "S_T_p90": s.S_T_p90_abs, "ok_ocp_off": s.ok_ocp_off,
                       "flagged": s.flagged, "flagged_named": s.flagged_named,
                       "statuses": s.statuses} for s in r.segments]}
        for r in runs
    ]
    return json.dumps({"targets": ROBUSTNESS_TARGETS, "variants": rows, "runs": detail}, indent=2)
