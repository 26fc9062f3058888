"""Where the truth lies against the K a record serves: in K ± 2 std read as a linear band, and in the band the
record serves, 2 sigma in ln K (``soil_strength_low`` .. ``soil_strength_high``, the robustness table's ``2-std
cov``).

The two agree where the band is narrow; where it is wide the belief is skewed and the linear band can miss a
truth that the ln-K band holds.  Also counts the served K that are narrow (std/K < 0.5) yet more than 30 %
off with the truth outside K ± 2 std: the confidently wrong numbers.

    .venv/bin/python scripts/band_coverage.py --variant gnss-cruise --seeds 4
"""

from __future__ import annotations

import argparse

import numpy as np

from soilocp.estimation.estimate import estimate_lines
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.sim.variants import get_variant


def coverage(name: str, seed: int) -> str:
    v = get_variant(name)
    cfg = PipelineConfig()
    pairs = list(v.simulate(seed, nominal=cfg.vehicle, constants=cfg.constants))
    cfg = cfg.model_copy(update={"vehicle": v.known_vehicle(cfg.vehicle)})
    truth = {(t.vehicle_id, t.seq): t.soil_strength for _, t in pairs}
    rows = [(r["soil_strength"], r["soil_strength_std"], r["soil_strength_low"], r["soil_strength_high"],
             truth[(r["vehicle_id"], r["seq"])])
            for r in estimate_lines([s.model_dump_json() for s, _ in pairs], cfg)
            if r["soil_strength"] is not None and r["soil_strength_std"] is not None]
    if not rows:
        return f"{name} seed {seed}: no record serves K"
    k, sd, low, high, kt = np.array(rows, dtype=float).T
    linear = np.abs(k - kt) <= 2 * sd
    in_ln = (low <= kt) & (kt <= high)
    narrow = sd / k < 0.5
    wrong = narrow & (np.abs(k / kt - 1) > 0.3) & ~linear
    return (f"{name} seed {seed}: {k.size} records with K; truth in K ± 2 std {linear.mean():.1%}, in the served "
            f"ln-K 2-sigma band {in_ln.mean():.1%}; std/K median {np.median(sd / k):.2f}, narrow (< 0.5) {narrow.sum()}, "
            f"confidently wrong {wrong.sum()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", required=True, help="a variant of soilocp accuracy --robustness")
    ap.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1")
    args = ap.parse_args()
    for name in args.variant:
        for seed in range(args.seeds):
            print(coverage(name, seed))


if __name__ == "__main__":
    main()
