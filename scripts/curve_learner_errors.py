"""How well the wheel-curve learner places the peak, on simulated drives whose true curve is known.

Each variant of ``soilocp accuracy --robustness`` runs with a vehicle whose curve is unchecked (the built-in
rover's file without ``traction_curve``), so the learner serves its own OCPs wherever the drive shows a peak.
For every record whose OCPs are learnt, the error of S_T and mu_T against the true curve's peak is set against
the band the record claims: the table says how far off the learnt peak is (median, p90, max) and how often the
truth lies within 2 sigma, for all learnt records and for those served as ``ok``.

    .venv/bin/python scripts/curve_learner_errors.py [--variant NAME ...] [--seeds N] [--jobs 2]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from soilocp.estimation.estimate import estimate_lines
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.variants import get_variant, list_variants

#: the drives on which a peak can be shown: traction tests of per-wheel robots (no cruise, turn, stall or descent)
DEFAULT_VARIANTS = [v.name for v in list_variants() if v.mode != "cruise" and v.scenario.mode != "cruise"
                    and "skid" not in v.name and v.draft is None and v.curve_shown]


def run(args) -> tuple[str, int, np.ndarray]:
    """(variant, seed, rows of (S_T error, S_T std, mu_T error, mu_T std, ok)) for the learnt records."""
    name, seed = args
    v = get_variant(name)
    nominal = DEFAULT_VEHICLE.model_copy(update={"traction_curve": None})
    cfg = PipelineConfig(vehicle=nominal)
    pairs = list(v.simulate(seed, nominal=cfg.vehicle, constants=cfg.constants))
    cfg = cfg.model_copy(update={"vehicle": v.known_vehicle(cfg.vehicle).model_copy(update={"traction_curve": None})})
    truth = {(t.vehicle_id, t.seq): t for _, t in pairs}
    rows = []
    for r in estimate_lines([s.model_dump_json() for s, _ in pairs], cfg):
        if r["curve"] != "learnt":
            continue
        t = truth[(r["vehicle_id"], r["seq"])]
        if any(abs(w - t.soil_strength) > 1e-9 * t.soil_strength for w in t.wheel_soil_strength):
            continue  # the wheels straddle two soils: either soil's peak is right
        rows.append((r["S_T"] - t.S_T, r["S_T_std"], r["mu_T"] - t.mu_T, r["mu_T_std"], r["status"] == "ok"))
    return name, seed, np.array(rows, dtype=float).reshape(-1, 5)


def describe(label: str, rows: np.ndarray) -> str:
    if not len(rows):
        return f"{label:28s} no learnt records"
    s_err, s_std, m_err, m_std = (np.abs(rows[:, 0]), rows[:, 1], np.abs(rows[:, 2]), rows[:, 3])
    q = lambda a: " / ".join(f"{x:.3f}" for x in np.quantile(a, [0.5, 0.9, 1.0]))  # noqa: E731
    return (f"{label:28s} {len(rows):6d}  S_T {q(s_err)}  in 2 sigma {np.mean(s_err <= 2 * s_std):6.1%}   "
            f"mu_T {q(m_err)}  in 2 sigma {np.mean(m_err <= 2 * m_std):6.1%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", help="only these variants (default: the traction tests)")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    names = a.variant or DEFAULT_VARIANTS
    jobs = [(n, s) for n in names for s in range(a.seeds)]
    with ProcessPoolExecutor(a.jobs) as ex:
        results = list(ex.map(run, jobs))
    print(f"{'variant (learnt records)':28s} {'n':>6s}  |error| median / p90 / max, and the share within the claimed 2 sigma")
    everything, served = [], []
    for name in names:
        rows = np.vstack([r for n, _, r in results if n == name])
        everything.append(rows)
        served.append(rows[rows[:, 4] > 0])
        print(describe(name, rows))
    print(describe("all learnt", np.vstack(everything)))
    print(describe("served as ok", np.vstack(served)))


if __name__ == "__main__":
    main()
