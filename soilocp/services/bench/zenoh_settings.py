"""``python -m soilocp.services.bench.zenoh_settings [--runs 3] [--json OUT]``: the standard pipeline
(router + 5 services) under each Zenoh setting, to choose the default with numbers.

Each setting starts a fresh :class:`~soilocp.services.bench.live.Rig` (router, the five services, the echo
of the ping-pong) and measures, in that one run, one vehicle at 100 Hz and one at 1 kHz: sample ->
OCP latency p50 / p99, drops, and the Zenoh floor of the same minute (``ping_pong`` through the same
router at the same rate: 6 hops = 3 round trips).  The settings:

* ``client``: every service a client of the router (the default until this measurement);
* ``client-express``: the same, the pipeline publishers ``express`` (each message sent at once,
  never batched with others);
* ``client-nobatch``: the same, batching off on every link (``transport/link/tx/queue/batching``,
  router and services);
* ``peer``: the services peers that listen on an ephemeral loopback port, so that the services of
  one compute unit link directly (the router only introduces them);
* ``peer-express``: peer links and express publishers.

The runs go round-robin (setting 1..5, then again), so that a change of the machine's load falls on
every setting alike; the load average is recorded before each setting's run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from typing import Any

SETTINGS: dict[str, dict[str, Any]] = {
    "client": {"links": "client", "env": {}},
    "client-express": {"links": "client", "env": {"SOILOCP_EXPRESS": "true"}},
    "client-nobatch": {"links": "client", "env": {"SOILOCP_BATCHING": "false"}},
    "peer": {"links": "peer", "env": {}},
    "peer-express": {"links": "peer", "env": {"SOILOCP_EXPRESS": "true"}},
}
HOPS = 6  # raw, clean, normal_forces, observer, soil, ocp: the standard pipeline's critical path


def run_setting(name: str, p100, p1k, d100: float, d1k: float, log=print) -> dict[str, Any]:
    """One fresh rig under setting ``name``: 100 Hz then 1 kHz, each with its floor."""
    from soilocp.services.bench.live import Rig, drive, open_client, ping_pong
    from soilocp.services.bench.measure import clone_payloads

    spec = SETTINGS[name]
    rig = Rig.standard(["lat100", "lat1k"])
    rig.links, rig.env = spec["links"], dict(spec["env"])
    out: dict[str, Any] = {"setting": name, "load_before": list(os.getloadavg())}
    try:
        rig.start()
        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 120.0)
            for rate, dur, vid, pl in ((100.0, d100, "lat100", p100), (1000.0, d1k, "lat1k", p1k)):
                base = ping_pong(session, rate, 3.0 if rate == 100.0 else 2.0)
                res = drive(session, {vid: clone_payloads(pl, "bench", vid)}, rate, dur)
                key = "100hz" if rate == 100.0 else "1khz"
                out[key] = {"p50": res["p50"], "p99": res["p99"], "max": res["max"], "sent": res["sent"],
                            "drops": res["drops"], "floor_p50": HOPS / 2 * base["p50"], "ping_p99": base["p99"]}
                log(f"  {name:15s} {key:5s} p50 {res['p50']:7.2f} p99 {res['p99']:7.2f} ms, drops {res['drops']}, "
                    f"floor {HOPS / 2 * base['p50']:.2f} ms")
    finally:
        rig.stop()
    out["load_after"] = list(os.getloadavg())
    return out


def summary(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per setting and rate: the median over the runs of p50, p99, floor, and all drops."""
    out: dict[str, dict[str, Any]] = {}
    for name in SETTINGS:
        rows = [r for r in results if r["setting"] == name and "100hz" in r]
        if not rows:
            continue
        out[name] = {}
        for key in ("100hz", "1khz"):
            vals = [r[key] for r in rows if key in r]
            out[name][key] = {
                "runs": len(vals),
                "p50": [v["p50"] for v in vals], "p99": [v["p99"] for v in vals],
                "floor_p50": [v["floor_p50"] for v in vals], "drops": [v["drops"] for v in vals],
                "p50_median": statistics.median(v["p50"] for v in vals),
                "p99_median": statistics.median(v["p99"] for v in vals),
                "floor_median": statistics.median(v["floor_p50"] for v in vals),
            }
        out[name]["load_1min"] = [r["load_before"][0] for r in rows]
    return out


def render(summ: dict[str, dict[str, Any]]) -> str:
    lines = ["| setting | 100 Hz p50 / p99 (floor), ms | 1 kHz p50 / p99 (floor), ms, drops | load (1 min) |",
             "|---|---|---|---|"]
    for name, s in summ.items():
        def cell(key: str, drops: bool = False) -> str:
            c = s[key]
            runs = "; ".join(f"{a:.2f} / {b:.2f} ({f:.2f})" + (f", {d}" if drops else "")
                             for a, b, f, d in zip(c["p50"], c["p99"], c["floor_p50"], c["drops"]))
            return f"{runs} — median {c['p50_median']:.2f} / {c['p99_median']:.2f} ({c['floor_median']:.2f})"
        lines.append(f"| {name} | {cell('100hz')} | {cell('1khz', True)} | "
                     f"{', '.join(f'{x:.1f}' for x in s['load_1min'])} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.zenoh_settings", description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated, of: " + ", ".join(SETTINGS))
    ap.add_argument("--duration", type=float, default=20.0, help="s at 100 Hz per run")
    ap.add_argument("--duration-1k", type=float, default=5.0, help="s at 1 kHz per run")
    ap.add_argument("--json", dest="json_out")
    args = ap.parse_args()
    names = [n.strip() for n in args.settings.split(",") if n.strip()]
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        ap.error(f"--settings: unknown {unknown}; known: {', '.join(SETTINGS)}")

    from soilocp.services.bench.measure import payloads
    from soilocp.services.bench.stages import simulate_drive

    p100 = payloads(simulate_drive("bench", args.duration + 1.0))
    p1k = payloads(simulate_drive("bench", args.duration_1k + 1.0, rate=1000.0))
    results: list[dict[str, Any]] = []
    t0 = time.monotonic()
    for run in range(args.runs):
        for name in names:
            print(f"run {run + 1}/{args.runs}, {name} (load {os.getloadavg()[0]:.1f})", flush=True)
            try:
                results.append({"run": run + 1, **run_setting(name, p100, p1k, args.duration, args.duration_1k)})
            except RuntimeError as exc:
                results.append({"run": run + 1, "setting": name, "error": str(exc)})
                print(f"  {name}: {exc}", flush=True)
            if args.json_out:
                with open(args.json_out, "w") as fh:
                    json.dump({"results": results, "cpu_count": os.cpu_count()}, fh, indent=1)
    summ = summary(results)
    print(render(summ))
    print(f"took {time.monotonic() - t0:.0f} s; load at end {os.getloadavg()}")
    if args.json_out:
        with open(args.json_out, "w") as fh:
            json.dump({"results": results, "summary": summ, "cpu_count": os.cpu_count()}, fh, indent=1)


if __name__ == "__main__":
    main()
