#!/usr/bin/env python3
"""Skid turns on the simulated skid steer: K's error and the statuses by how the robot turns
(docs/robustness.md, "Skid turns").  The numbers behind the decision to say ``not_observable``
(reason ``skid_turn``) while the vehicle turns about a point within its track.

Drives (skid-steer rover, docs/maps/skid-steer-rover.json, grass K = 200, excitation): S-turns of
growing yaw-rate amplitude at 1.0 and 0.3 m/s.  Each record is binned by the TRUE kinematics: the
instantaneous centre of rotation inside the track (|V| < |yaw rate| x half-track, the inner wheels'
ground reverses) or outside it, and the lateral sliding of the wheels, tan(alpha) = |yaw rate| x
max(a, b) / |V|.

Run:  .venv/bin/python scripts/skid_turn_measure.py [--duration 20]
      .venv/bin/python scripts/skid_turn_measure.py --warthog ../shared/data/real   (the real logs, by turn)
"""

from __future__ import annotations

import argparse
import collections
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from soilocp.estimation.estimate import estimate_lines  # noqa: E402
from soilocp.estimation.pipeline import PipelineConfig  # noqa: E402
from soilocp.model.vehicle import load_vehicle  # noqa: E402
from soilocp.sim.controller import ControllerParams  # noqa: E402
from soilocp.sim.scenarios import get_scenario  # noqa: E402
from soilocp.sim.simulator import simulate  # noqa: E402

DRIVES = {  # name: (speed m/s, S-turn yaw-rate amplitude rad/s, period s)
    "arcs-1.0-0.6": (1.0, 0.6, 8.0),
    "arcs-1.0-1.2": (1.0, 1.2, 8.0),
    "tight-0.3-1.5": (0.3, 1.5, 8.0),
}
BINS = ((0.0, 0.1), (0.1, 0.3), (0.3, 1.0), (1.0, math.inf))


def run(name: str, duration: float, seed: int = 0):
    speed, rate, period = DRIVES[name]
    vehicle = load_vehicle(ROOT / "docs" / "maps" / "skid-steer-rover.json")
    scen = get_scenario("grass").with_overrides(speed=speed)
    pairs = list(simulate(scen, duration=duration, seed=seed, vehicle=vehicle,
                          controller=ControllerParams(s_turn_rate=rate, s_turn_period=period)))
    recs = list(estimate_lines((s.model_dump_json() for s, _ in pairs), PipelineConfig(vehicle=vehicle)))
    half_track = 0.5 * (vehicle.c + vehicle.d)
    x_max = max(vehicle.a, vehicle.b)
    rows = collections.defaultdict(list)
    for (_, tr), rec in zip(pairs, recs):
        if tr.stamp < 3.0:  # the start from rest
            continue
        v, r = abs(tr.ground_speed), abs(tr.yaw_rate)
        inside = v < r * half_track
        tan_a = r * x_max / max(v, 1e-3)
        b = next(i for i, (lo, hi) in enumerate(BINS) if lo <= tan_a < hi)
        rows[("inside" if inside else "outside", b)].append((rec, tr.soil_strength))
    return rows


def summarize(rows) -> list[str]:
    out = ["| ICR | tan(alpha) | records | with K | K median error | K p90 error | ok | ok > 30 % off | statuses |",
           "|---|---|---|---|---|---|---|---|---|"]
    for key in sorted(rows):
        recs = rows[key]
        err = np.array([abs(r["soil_strength"] / k - 1.0) for r, k in recs if r["soil_strength"] is not None])
        ok = [abs(r["soil_strength"] / k - 1.0) for r, k in recs if r["status"] == "ok"]
        lo, hi = BINS[key[1]]
        st = collections.Counter(r["status"] for r, _ in recs)
        out.append(f"| {key[0]} | {lo:g}-{hi:g} | {len(recs)} | {err.size} | "
                   f"{100 * np.median(err):.1f} % | {100 * np.percentile(err, 90):.1f} % | " if err.size else
                   f"| {key[0]} | {lo:g}-{hi:g} | {len(recs)} | 0 | - | - | ")
        out[-1] += f"{len(ok)} | {sum(e > 0.3 for e in ok)} | {dict(st)} |"
    return out


def warthog_turns(data: Path) -> list[str]:
    """The Warthog logs' records by how the robot turns (raw sensor fields, as scripts/real_log_honesty.py):
    about a point within the track (its skid_turn condition), on an arc (|yaw rate| > 0.1 rad/s, the centre
    outside the track), or straight; statuses, and K's median and spread where one is reported."""
    import real_log_honesty as rl

    by = collections.defaultdict(list)
    for _, samples, cfg in rl.warthog(data):
        recs = list(estimate_lines((__import__("json").dumps(x) for x in samples), cfg))
        small = rl.torque_threshold(samples)
        for x, rec in zip(samples, recs):
            if "skid_turn" in rl.conditions(x, cfg.vehicle, small):
                kind = "in place (centre within the track)"
            elif abs(x["yaw_rate"]) > rl.YAW_TURNING:
                kind = "arc"
            else:
                kind = "straight"
            by[kind].append(rec)
    out = ["| turn | records | model_mismatch | with K | K median | K p10-p90 | statuses |", "|---|---|---|---|---|---|---|"]
    for kind, recs in by.items():
        ks = np.array([r["soil_strength"] for r in recs if r["soil_strength"] is not None])
        st = collections.Counter(r["status"] for r in recs)
        mm = st.get("model_mismatch", 0) / len(recs)
        kk = (f"{np.median(ks):.0f} | {np.percentile(ks, 10):.0f}-{np.percentile(ks, 90):.0f}" if ks.size else "- | -")
        out.append(f"| {kind} | {len(recs)} | {100 * mm:.1f} % | {ks.size} | {kk} | {dict(st)} |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--drive", action="append", choices=list(DRIVES))
    ap.add_argument("--warthog", type=Path, help="instead: the Warthog logs in this real-log directory, by turn")
    args = ap.parse_args(argv)
    if args.warthog:
        print("\n".join(warthog_turns(args.warthog)))
        return 0
    for name in args.drive or list(DRIVES):
        print(f"## {name}\n")
        print("\n".join(summarize(run(name, args.duration))) + "\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
