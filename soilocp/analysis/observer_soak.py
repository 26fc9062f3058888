"""Soak test of the observer's covariance (the product's: the compiled core behind ObserverBank): many steps
under hostile conditions, checking that P stays symmetric positive definite.  ``python -m soilocp.analysis.observer_soak --steps 1000000``."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from soilocp.estimation.observer import ObserverConfig
from soilocp.estimation.observer_bank import ObserverBank, ObserverInputs
from soilocp.model.vehicle import DEFAULT_VEHICLE


def soak(steps: int, seed: int = 0, structure: str = "shared", check_every: int = 1000) -> dict:
    rng = np.random.default_rng(seed)
    bank = ObserverBank(DEFAULT_VEHICLE, ObserverConfig(structure=structure), 1)
    t = 0.0
    min_eig, max_asym, max_var = np.inf, 0.0, 0.0
    for k in range(steps):
        phase = (k // 2500) % 4
        t += rng.choice([0.001, 0.01, 0.02]) if phase else 0.01
        fz = rng.uniform(1.0, 400.0, 4) if phase == 1 else rng.uniform(100.0, 200.0, 4)
        torque = rng.uniform(-50, 50, 4) if phase == 2 else rng.normal(5, 1, 4)
        v = 0.0 if phase == 3 else 1.0 + rng.normal(0, 0.02)
        omega = np.full(4, v / 0.15) + rng.normal(0, 0.05, 4)
        fx, yaw, pitch = rng.normal(0.5, 0.3), rng.normal(0, 0.01), rng.normal(0, 0.05)
        bank.step(None, ObserverInputs(np.array([t]), np.array([fx]), np.array([yaw]), np.array([pitch]), omega[None],
                                       torque[None], np.array([v]), fz[None]))
        if k % check_every == 0 or k == steps - 1:
            P = bank.P[0]
            max_asym = max(max_asym, float(np.abs(P - P.T).max()))
            min_eig = min(min_eig, float(np.linalg.eigvalsh(P).min()))
            max_var = max(max_var, float(np.diag(P).max()))
    return {"steps": steps, "min_eigenvalue": min_eig, "max_asymmetry": max_asym, "max_variance": max_var}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--steps", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--structure", default="shared", choices=["shared", "per_wheel", "none"])
    a = ap.parse_args()
    t0 = time.perf_counter()
    res = soak(a.steps, a.seed, a.structure)
    res["seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(res))
    raise SystemExit(0 if res["min_eigenvalue"] > 0 and res["max_asymmetry"] == 0.0 else 1)


if __name__ == "__main__":
    main()
