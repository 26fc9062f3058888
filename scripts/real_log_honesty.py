#!/usr/bin/env python3
"""Count the estimator's statuses on the shared real logs in the conditions eq. 1 and the
longitudinal traction law do not describe (docs/robustness.md, "Honest on real logs").

The conditions are detected from the RAW sensor fields of each sample (ground speed V, each wheel's
rim speed R_w omega, the wheel-speed signs of the left and right sides, the yaw rate, the torque
column), never from the estimator's own flags, so the check can fail:

* ``reversing_with_spin``: the robot travels backwards (V < -0.02 m/s, or |V| <= 0.02 m/s with both
  sides' rims turning backwards faster than 0.05 m/s) and a wheel turns backwards faster than the
  ground under it by more than 0.1 m/s;
* ``skid_turn``: the two sides' rims turn in opposite directions (each faster than 0.05 m/s), or the
  robot yaws (|yaw rate| > 0.1 rad/s) about a point within its track (|V| < |yaw rate| x half-track);
* ``slip_beyond_1``: a wheel whose eq. 1 slip (floor 0.05 m/s) from the raw speeds exceeds 1 in
  magnitude (rim and ground under it moving in opposite directions);
* ``stall``: |V| < 0.1 m/s while a torque is applied (|T| above a tenth of the log's 95th percentile
  of |T|, on any wheel);
* ``stopped_unpowered``: the body moves (|V| > 0.15 m/s) while a wheel stands (|R_w omega| < 0.02 m/s)
  under no torque (|T| at most a tenth of that percentile).

Every count of ``ok`` records in a condition must be 0: the script exits with status 1 otherwise.
Logs without a ground speed (BorealTC) cannot show the conditions that need V; their skid turns
are still detected from the wheel signs and the yaw rate.

Run:  .venv/bin/python scripts/real_log_honesty.py [--data ../shared/data/real] [--seconds 0:30]
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from soilocp.estimation.estimate import estimate_lines  # noqa: E402
from soilocp.estimation.pipeline import PipelineConfig, load_pipeline_config  # noqa: E402
from soilocp.model.slip import DEFAULT_FLOOR  # noqa: E402
from soilocp.model.vehicle import VehicleParams  # noqa: E402

CONDITIONS = ("reversing_with_spin", "skid_turn", "slip_beyond_1", "stall", "stopped_unpowered")
STATUSES = ("ok", "uncertain", "holding", "no_estimate", "not_observable", "model_mismatch")
WARTHOG_LOGS = ("warthog_grass", "warthog_grass_20240718", "warthog_asphalt_20240925")
BOREAL_RUNS = ("ASPHALT_00", "FLOORING_01", "ICE_02", "SANDY_LOAM_01", "SNOW_00")

V_STILL = 0.02  # m/s: |V| below this is no travel of its own
RIM_TURNING = 0.05  # m/s: a rim turning
SPIN_EXCESS = 0.1  # m/s: a wheel faster than the ground under it by this much spins
YAW_TURNING = 0.1  # rad/s
V_STALL = 0.1  # m/s
V_MOVING = 0.15  # m/s (eq. 1's deadband: the body clearly moves)
RIM_STOPPED = 0.02  # m/s
TORQUE_SHARE = 0.1  # of the log's 95th percentile of |T|: "a torque is applied"


def default_data() -> Path:
    for p in (ROOT.parent / "shared" / "data" / "real", Path("/work/shared/data/real")):
        if p.is_dir():
            return p
    return ROOT.parent / "shared" / "data" / "real"


def conditions(sample: dict, vehicle: VehicleParams, torque_small: float) -> set[str]:
    """The conditions (names of CONDITIONS) one raw sensor sample (a sensor-log dict) is in."""
    out: set[str] = set()
    rim = np.asarray(sample["wheel_speed"], dtype=float) * vehicle.wheel_radius
    torque = np.abs(np.asarray(sample["wheel_torque"], dtype=float))
    yaw = float(sample["yaw_rate"])
    left, right = rim[:2].mean(), rim[2:].mean()
    half_track = 0.5 * (vehicle.c + vehicle.d)
    if left * right < 0 and min(abs(left), abs(right)) > RIM_TURNING:
        out.add("skid_turn")
    v = sample.get("ground_speed")
    if v is None:
        return out
    v = float(v)
    if abs(yaw) > YAW_TURNING and abs(v) < abs(yaw) * half_track:
        out.add("skid_turn")
    v_wheel = v - yaw * np.asarray(vehicle.wheel_y, dtype=float)
    backwards = v < -V_STILL or (abs(v) <= V_STILL and left < -RIM_TURNING and right < -RIM_TURNING)
    if backwards and ((v_wheel - rim) > SPIN_EXCESS).any():
        out.add("reversing_with_spin")
    slip = (rim - v_wheel) / np.maximum(np.maximum(np.abs(rim), np.abs(v_wheel)), DEFAULT_FLOOR)
    if (np.abs(slip) > 1.0).any():
        out.add("slip_beyond_1")
    if abs(v) < V_STALL and (torque > torque_small).any():
        out.add("stall")
    if abs(v) > V_MOVING and ((np.abs(rim) < RIM_STOPPED) & (torque <= torque_small)).any():
        out.add("stopped_unpowered")
    return out


def torque_threshold(samples: list[dict]) -> float:
    t = np.abs(np.array([s["wheel_torque"] for s in samples], dtype=float))
    p95 = float(np.percentile(t, 95)) if t.size else 0.0
    return TORQUE_SHARE * p95 if p95 > 0 else math.inf


def count(samples: list[dict], config: PipelineConfig, counts: dict | None = None) -> dict:
    """{condition or "all": {status: n}} over one log's samples (dicts), estimated with ``config``."""
    counts = counts if counts is not None else {}
    small = torque_threshold(samples)
    recs = estimate_lines((json.dumps(s) for s in samples), config)
    for s, rec in zip(samples, recs):
        if rec["seq"] != s["seq"]:
            raise RuntimeError(f"record seq {rec['seq']} for sample {s['seq']}: a sample was dropped")
        for cond in ("all", *sorted(conditions(s, config.vehicle, small))):
            row = counts.setdefault(cond, collections.Counter())
            row[rec["status"]] += 1
    return counts


def window(samples: Iterable[dict], seconds: tuple[float, float] | None) -> list[dict]:
    samples = list(samples)
    if seconds is None or not samples:
        return samples
    t0 = samples[0]["stamp"]
    return [s for s in samples if seconds[0] <= s["stamp"] - t0 < seconds[1]]


def warthog(data: Path, seconds=None) -> Iterator[tuple[str, list[dict], PipelineConfig]]:
    d = data / "warthog"
    guess = json.loads((d / "vehicle-guess.json").read_text())
    cfg = PipelineConfig(vehicle=VehicleParams(**guess, drive="per_side"))
    for name in WARTHOG_LOGS:
        lines = (d / f"{name}.jsonl").read_text().splitlines()
        yield name, window((json.loads(x) for x in lines if x.strip()), seconds), cfg


def borealtc(data: Path, seconds=None) -> Iterator[tuple[str, list[dict], PipelineConfig]]:
    from soilocp.ingest import load_map
    from soilocp.ingest.csv_import import import_csv

    d = data / "borealtc"
    tmap = load_map(ROOT / "docs" / "maps" / "borealtc-husky.yaml")
    cfg = load_pipeline_config(vehicle=ROOT / "docs" / "maps" / "husky-vehicle-guess.json")
    with tempfile.TemporaryDirectory() as tmp:
        for run in BOREAL_RUNS:
            terrain, n = run.rsplit("_", 1)
            out = Path(tmp) / f"{run}.jsonl"
            import_csv({"imu": d / f"{terrain}_imu_{n}.csv", "wheels": d / f"{terrain}_pro_{n}.csv"}, tmap, out)
            yield f"husky_{run}", window((json.loads(x) for x in out.read_text().splitlines() if x.strip()), seconds), cfg


def table(counts: dict) -> str:
    head = "| condition | " + " | ".join(STATUSES) + " |"
    rows = [head, "|" + "---|" * (len(STATUSES) + 1)]
    for cond in ("all", *CONDITIONS):
        row = counts.get(cond, {})
        rows.append(f"| {cond} | " + " | ".join(str(row.get(s, 0)) for s in STATUSES) + " |")
    return "\n".join(rows)


def failures(counts: dict) -> dict[str, int]:
    """{condition: ok records in it} where that count is not 0."""
    return {c: counts[c]["ok"] for c in CONDITIONS if c in counts and counts[c].get("ok", 0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=default_data(), help="the shared real-log directory")
    ap.add_argument("--seconds", help="only this window of each log, START:END seconds from its first stamp")
    ap.add_argument("--only", choices=("warthog", "borealtc"), help="one data set only")
    ap.add_argument("--log", action="append", help="only this log (e.g. warthog_asphalt_20240925, husky_SNOW_00)")
    ap.add_argument("--json", type=Path, help="also write the counts (per log and in total) here")
    args = ap.parse_args(argv)
    seconds = tuple(float(x) for x in args.seconds.split(":")) if args.seconds else None
    if not args.data.is_dir():
        print(f"no real-log directory at {args.data}", file=sys.stderr)
        return 2
    total: dict = {}
    per_log: dict = {}
    sources = [] if args.only == "borealtc" else [warthog(args.data, seconds)]
    if args.only != "warthog":
        sources.append(borealtc(args.data, seconds))
    for source in sources:
        for name, samples, cfg in source:
            if args.log and name not in args.log:
                continue
            per_log[name] = count(samples, cfg)
            for cond, row in per_log[name].items():
                total.setdefault(cond, collections.Counter()).update(row)
            print(f"## {name} ({len(samples)} samples)\n\n{table(per_log[name])}\n")
    print(f"## all logs\n\n{table(total)}\n")
    bad = failures(total)
    if args.json:
        args.json.write_text(json.dumps({"total": total, "logs": per_log, "failures": bad}, indent=1))
    if bad:
        print(f"FAIL: ok records in conditions eq. 1 does not describe: {bad}")
        return 1
    print("PASS: no ok record in any condition")
    return 0


if __name__ == "__main__":
    sys.exit(main())
