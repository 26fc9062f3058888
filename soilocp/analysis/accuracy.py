"""The accuracy evaluation: simulate -> estimate -> evaluate on every scenario, in both
controller modes, with and without motion-resistance compensation, against the targets.

``soilocp accuracy`` prints the table quoted in the README.  It runs the same code as the
commands (simulate's generator, estimate's line processor, evaluate's scorer), in-process.
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Optional

from soilocp.estimation.estimate import EstimateSummary, estimate_lines
from soilocp.analysis.evaluation import TARGETS, SegmentResult, evaluate_records
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.sim.simulator import simulate

DEFAULT_SCENARIOS = ("sand", "gravel", "grass", "firm", "sandy-slope", "mixed")


def estimate_and_score(pairs, cfg: PipelineConfig, settle: float = TARGETS["settle_s"], reason_names: str = "",
                       judged_from: float = 0.0, ocp_after: float = 0.0):
    """The offline chain on simulated ``(SensorSample, TruthRecord)`` pairs, scored against their
    truth: (samples, estimates per second, per-segment results, the estimate summary).  One path
    for ``soilocp accuracy`` and its ``--robustness`` variants."""
    lines, truth = [], []
    for sample, tr in pairs:
        lines.append(sample.model_dump_json())
        truth.append(tr.model_dump())
    summary = EstimateSummary()
    t0 = time.perf_counter()
    estimates = list(estimate_lines(lines, cfg, summary=summary))
    rate = len(estimates) / max(time.perf_counter() - t0, 1e-9)
    return len(lines), rate, evaluate_records(truth, estimates, settle, reason_names, judged_from, ocp_after), summary


@dataclass
class RunResult:
    scenario: str
    mode: str
    compensation: bool
    samples: int
    estimate_rate: float  # samples/s of the estimate step
    segments: list[SegmentResult]
    statuses: dict

    def worst(self) -> dict:
        segs = self.segments

        def mx(vals):
            vals = [v for v in vals if v is not None]
            return max(vals) if vals else None

        missing = lambda vals: any(v is None for v in vals)  # noqa: E731
        k_med = [s.k_median_rel for s in segs]
        k_p90 = [s.k_p90_rel for s in segs]
        # convergence is judged after abrupt changes (segments after the first); the first
        # segment's number includes the start from standstill and is reported separately
        conv_changes = [s.convergence_s for s in segs[1:]]
        ocp = [s.mu_T_median_abs for s in segs] + [s.S_T_median_abs for s in segs] + [s.S_E_median_abs for s in segs]
        cls = [s.class_accuracy for s in segs]
        return {
            "coverage": min(s.coverage for s in segs),
            "k_median_rel": None if missing(k_med) else mx(k_med),
            "k_p90_rel": None if missing(k_p90) else mx(k_p90),
            "initial_convergence_s": segs[0].convergence_s,
            "change_convergence_s": (None if missing(conv_changes) else mx(conv_changes)) if conv_changes else None,
            "ocp_median_abs": None if missing(ocp) else mx(ocp),
            "class_accuracy": None if missing(cls) else min(cls),
        }

    def passes(self) -> bool:
        w = self.worst()
        t = TARGETS
        ok = (
            w["k_median_rel"] is not None and w["k_median_rel"] <= t["k_median_rel"]
            and w["k_p90_rel"] is not None and w["k_p90_rel"] <= t["k_p90_rel"]
            and w["ocp_median_abs"] is not None and w["ocp_median_abs"] <= t["ocp_median_abs"]
            and w["class_accuracy"] is not None and w["class_accuracy"] >= t["class_accuracy"]
        )
        if len(self.segments) > 1:
            ok = ok and w["change_convergence_s"] is not None and w["change_convergence_s"] <= t["convergence_s"]
        return ok


def run_one(scenario: str, mode: str, compensation: bool, seed: int = 0, duration: Optional[float] = None,
            config: Optional[PipelineConfig] = None) -> RunResult:
    cfg = config or PipelineConfig()
    if not compensation:
        cfg = cfg.model_copy(update={"observer": cfg.observer.model_copy(update={"structure": "none"})})
    pairs = simulate(scenario, duration=duration, seed=seed, mode=mode, vehicle=cfg.vehicle, constants=cfg.constants)
    n, rate, segs, summary = estimate_and_score(pairs, cfg)
    return RunResult(scenario, mode, compensation, n, rate, segs, summary.statuses)


def _run_args(args):
    return run_one(*args)


def run_matrix(scenarios=DEFAULT_SCENARIOS, modes=("excitation", "cruise"), compensation=(True, False),
               seed: int = 0, duration: Optional[float] = None, jobs: int = 2,
               config: Optional[PipelineConfig] = None) -> list[RunResult]:
    """``config`` (None = the defaults) is the estimator's; its vehicle and constants are also the
    simulated robot's and soil's, e.g. a skid steer (``drive: per_side``, docs/maps/skid-steer-rover.json)."""
    cfg = config or PipelineConfig()
    jobs_list = [(s, m, c, seed, duration, cfg) for s in scenarios for m in modes for c in compensation]
    if jobs <= 1:
        return [run_one(*a) for a in jobs_list]
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(_run_args, jobs_list))


def results_json(results: list[RunResult]) -> str:
    out = []
    for r in results:
        out.append({
            "scenario": r.scenario, "mode": r.mode, "compensation": r.compensation, "samples": r.samples,
            "estimate_rate": r.estimate_rate, "statuses": r.statuses, "worst": r.worst(), "pass": r.passes(),
            "segments": [{"soil": s.soil_class, "K": s.soil_strength, "k_median_rel": s.k_median_rel,
                          "k_p90_rel": s.k_p90_rel, "convergence_s": s.convergence_s,
                          "class_accuracy": s.class_accuracy, "coverage": s.coverage} for s in r.segments],
        })
    return json.dumps({"targets": TARGETS, "runs": out}, indent=2)
