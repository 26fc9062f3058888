"""Where a learnt peak's error comes from: the learner, the slips or the traction it is fed.

The wheel-curve learner (``soilocp._core.CurveBank``) is run four times over the same drive on the same
wheels and samples: on the estimator's (slip, net traction) pairs, as the OCP service runs it; on the
simulator's true slips with the estimator's traction; on the estimator's slips with the true traction; and on
both true.  For each soil it prints the p90 and median of the learnt S_T's error against the true curve's peak,
from 5 s after the soil begins, and the mean error of the driven (front) wheels' net traction in slip bins, signed
on the driving branch: a traction that reads high as the slip grows tilts the fitted curve and moves a flat
peak late.

    .venv/bin/python scripts/curve_error_sources.py --variant tyre-slow --seeds 4
    .venv/bin/python scripts/curve_error_sources.py --variant tyre-slow --config c.json   # another estimator
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from soilocp import _core
from soilocp.estimation.config import PipelineConfig
from soilocp.estimation.estimate import estimate_lines
from soilocp.estimation.settings_model import core_values
from soilocp.sim.variants import get_variant

#: the pairs the learner is fed: (slips, traction), each the estimator's or the simulator's
SOURCES = {"estimated": ("est", "est"), "true slip": ("true", "est"), "true traction": ("est", "true"),
           "both true": ("true", "true")}
#: judged from this long after a soil begins (one sweep cycle or more after the settle)
JUDGED_AFTER_S = 5.0


def run(name: str, seed: int, config: dict) -> str:
    v = get_variant(name)
    cfg = PipelineConfig.model_validate(config)
    pairs = list(v.simulate(seed, nominal=cfg.vehicle, constants=cfg.constants))
    cfg = cfg.model_copy(update={"vehicle": v.known_vehicle(cfg.vehicle)})
    truth = {t.seq: t for _, t in pairs}
    begins: dict[int, float] = {}
    for _, t in pairs:
        begins.setdefault(t.segment, t.stamp)
    recs = list(estimate_lines([s.model_dump_json() for s, _ in pairs], cfg, full=True))
    out = []
    for label, (slips, traction) in SOURCES.items():
        bank = _core.CurveBank(1, core_values(cfg.curve, "curve"), cfg.soil.gross_scale_sigma)
        errs: dict[int, list[float]] = {}
        for r in recs:
            t = truth[r["seq"]]
            used = tuple(bool(i and d) for i, d in zip(r["informative"], r["mu_determined"]))
            s = tuple(t.slip) if slips == "true" else tuple(r["slip"])
            mu = tuple(t.mu) if traction == "true" else tuple(r["mu"])
            fit = bank.step(0, r["stamp"], s, mu, used, r["ground_speed_latency"])
            if fit is not None and fit.shown and t.stamp - begins[t.segment] > JUDGED_AFTER_S:
                errs.setdefault(t.segment, []).append(fit.s_t - t.S_T)
        out.append(f"  {label:>13}: " + ("; ".join(
            f"soil {k} S_T p90 {np.quantile(np.abs(e), 0.9):.3f} median {np.median(e):+.3f}"
            for k, e in sorted(errs.items())) or "no peak shown"))
    rows = [(abs(truth[r["seq"]].slip[i]), np.sign(truth[r["seq"]].slip[i]) * (r["mu"][i] - truth[r["seq"]].mu[i]))
            for r in recs for i in (1, 2)
            if r["informative"][i] and r["mu_determined"][i] and r["mu"][i] is not None]
    a = np.array(rows).reshape(-1, 2)
    bins = []
    for lo in np.arange(0.1, 0.7, 0.1):
        m = (a[:, 0] >= lo) & (a[:, 0] < lo + 0.1)
        if m.any():
            bins.append(f"{lo:.1f}-{lo + 0.1:.1f} {a[m, 1].mean():+.3f}")
    out.append("  front wheels' traction error by |S|: " + (", ".join(bins) or "no informative pair"))
    return f"{name} seed {seed}:\n" + "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", required=True, help="a variant of soilocp accuracy --robustness")
    ap.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1")
    ap.add_argument("--config", help="an estimator configuration (JSON), as soilocp accuracy --config takes")
    args = ap.parse_args()
    config = json.loads(open(args.config).read()) if args.config else {}
    for name in args.variant:
        for seed in range(args.seeds):
            print(run(name, seed, config), flush=True)


if __name__ == "__main__":
    main()
