"""``soilocp bench [--quick] [--json OUT]``: latency, throughput and scale of the live pipeline.

1. stages: µs per sample of each stage, in process, on a real simulated drive, and the offline
   replay rate of ``soilocp.estimation.estimate.estimate_lines`` (:mod:`soilocp.services.bench.stages`);
2. latency: sample -> OCP over Zenoh through the deployed processes (router in between) at
   100 Hz and 1 kHz for one vehicle, with drops and rejections (:mod:`soilocp.services.bench.live`);
3. scale: the most vehicles x 100 Hz with p99 < 10 ms and no drop, stepping the count until the
   first failure, with CPU and memory per process;
4. every live figure next to a baseline measured in the same run, on the same router, at the same
   rate: a bare Zenoh ping-pong (put -> router -> echo -> router), the physical floor.  In the
   standard pipeline a sample crosses six client -> router -> client hops on its critical path
   (raw, clean, normal_forces, observer, soil, ocp), i.e. three ping-pong round trips; in the
   batched one three (raw, clean, ocp): ``floor`` = hops / 2 x the ping-pong figure.
5. control loop: sample -> slip set-point, through the pipeline and the controller service
   (:mod:`soilocp.services.bench.control`; the bench plays the closed-loop vehicle).

Nothing here changes the services; the ``batched`` pipeline replaces normal-force, observer,
soil-strength and OCP by :mod:`soilocp.services.stages.batch` (one process stepping every vehicle with
numpy).  Wall-clock figures depend on how much CPU the machine leaves us: the report says how
much of a core a busy thread got at the start and at the end, and the stage costs are also
given in thread CPU time, which does not depend on the load.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any, Optional

import click

from soilocp.services.bench.measure import (LADDER, RIGS, TARGETS, clone_payloads, ladder_up_to, live_drives,
                                            live_durations, measure_latency, measure_scale, payloads)
from soilocp.services.bench.report import console as bench_console
from soilocp.services.bench.report import fmt, json_safe, machine_info, write_report

HOPS = {"standard": 6, "batched": 3}  # client -> router -> client hops on a sample's critical path


def batch_available() -> bool:
    try:
        import soilocp.services.stages.batch  # noqa: F401
        import soilocp.estimation.batch  # noqa: F401
    except ImportError:
        return False
    return True


def run_bench(quick: bool = False, pipelines: Optional[list[str]] = None, ladder: Optional[list[int]] = None,
              log=print) -> dict[str, Any]:
    """Run every part and return the report (a JSON-able dict)."""
    from soilocp.services.bench.stages import batch_costs, cpu_share, replay_rate, simulate_drive, stage_costs

    t_start = time.monotonic()
    if pipelines is None:
        pipelines = ["standard", "batched"] if batch_available() else ["standard"]
    ladder = list(ladder or ((1, 2) if quick else LADDER))
    d_stage = 3.0 if quick else 30.0
    d_100, d_1k, d_scale = live_durations(quick)
    report: dict[str, Any] = {"quick": quick, "machine": machine_info(), "targets": TARGETS,
                              "command": "soilocp bench" + (" --quick" if quick else "")}

    report["machine"]["cpu_share_start"] = cpu_share()["share"]
    # 1. stages in process
    log(f"bench: simulating a {d_stage:.0f} s drive (mixed) for the stage costs")
    drive_samples = simulate_drive("bench", d_stage)
    report["stages"] = stage_costs(drive_samples)
    report["replay"] = replay_rate(drive_samples)
    if batch_available():
        counts = (1, 10) if quick else (1, 10, 50, 200)
        report["batch_stages"] = batch_costs(drive_samples, counts, steps=100 if quick else 300)

    s100, s1k = live_drives(quick, log)
    p100, p1k = payloads(s100), payloads(s1k)

    # 2 + 4. latency of one vehicle, with the ping-pong baseline, per pipeline
    report["latency"] = []
    for pipe in pipelines:
        report["latency"] += measure_latency(RIGS[pipe], pipe, p100, p1k, d_100, d_1k, quick, log)

    # 5. control loop: sample -> slip set-point (pipeline + controller service), 100 Hz
    from soilocp.services.bench.control import control_loop_latency

    log("bench: control loop latency (controller service, ocp_traction)")
    try:
        report["control_loop"] = control_loop_latency(clone_payloads(p100, "bench", "bench"), 100.0, d_100)
    except RuntimeError as exc:
        report["control_loop"] = {"error": str(exc)}

    # 3 + 4. scale: vehicles x 100 Hz until the first failure
    report["scale"] = {pipe: measure_scale(RIGS[pipe], pipe, p100, ladder, d_scale, quick, log) for pipe in pipelines}
    report["machine"]["load_end"] = list(os.getloadavg())
    report["machine"]["cpu_share_end"] = cpu_share()["share"]
    report["elapsed_s"] = time.monotonic() - t_start
    report["verdict"] = verdict(report)
    return report


def verdict(report: dict[str, Any]) -> dict[str, Any]:
    """Which targets were met, per pipeline."""
    from soilocp.services.bench.compare import pipeline_rss_mib

    out: dict[str, Any] = {"chain_cpu_per_sample": report["stages"]["total"].get("cpu_p50", math.inf)
                           <= TARGETS["chain_cpu_us"],
                           "replay_x_real_time": report["replay"]["x_real_time"] >= TARGETS["replay_x"]}
    for row in report["latency"]:
        r = row["result"]
        p = row["pipeline"]
        if row["rate_hz"] == 100.0:
            out[f"{p}_p50_100hz"] = r["p50"] < TARGETS["p50_ms_100hz"]
            out[f"{p}_p99_100hz"] = r["p99"] < TARGETS["p99_ms_100hz"]
            rss = pipeline_rss_mib(row.get("processes") or {})
            out[f"{p}_rss_total"] = rss is not None and rss <= TARGETS["rss_mib_total"]
        else:
            out[f"{p}_1khz_no_drops"] = r["drops"] == 0 and r["rejections"] == 0
            out[f"{p}_1khz_p99"] = out[f"{p}_1khz_no_drops"] and r["p99"] < TARGETS["p99_ms_1khz"]
    for p, sc in report["scale"].items():
        out[f"{p}_vehicles_100hz"] = sc["max_vehicles"] >= TARGETS["vehicles_100hz"]
    return out


def render(report: dict[str, Any], console) -> None:
    from rich.table import Table

    m = report["machine"]
    console.print(f"{report['command']} — {m['nproc']} CPU(s), {m['cpu_model']}, load {fmt(m['load_start'][0])} "
                  f"-> {fmt(m.get('load_end', [float('nan')])[0])}, python {m['python']}, zenoh {m['zenoh']}")
    console.print(f"share of a core a busy thread of the bench got: {fmt(m.get('cpu_share_start'))} at the start, "
                  f"{fmt(m.get('cpu_share_end'))} at the end (1.00 = idle machine; wall-clock figures scale with it, "
                  "CPU figures do not)")

    t = Table(title="1. stage cost in process, µs per sample (real simulated drive): wall clock and thread CPU time",
              title_justify="left")
    for c in ("stage", "wall median", "wall p99", "CPU median", "CPU p99", "n"):
        t.add_column(c, justify="left" if c == "stage" else "right")
    for name, st in report["stages"].items():
        t.add_row(name, fmt(st["p50"], ".0f"), fmt(st["p99"], ".0f"), fmt(st.get("cpu_p50"), ".0f"),
                  fmt(st.get("cpu_p99"), ".0f"), str(st["n"]))
    console.print(t)
    rp = report["replay"]
    console.print(f"offline replay (estimate_lines): {rp['samples']} samples in {fmt(rp['seconds'])} s = "
                  f"{fmt(rp['samples_per_s'], '.0f')} samples/s = {fmt(rp['x_real_time'], '.1f')}x real time at 100 Hz "
                  f"(per CPU second: {fmt(rp.get('samples_per_cpu_s'), '.0f')} samples = "
                  f"{fmt(rp.get('x_real_time_cpu'), '.1f')}x real time)")
    if "batch_stages" in report:
        t = Table(title="batched observer + soil + OCP (soilocp.estimation.batch), µs per vehicle-sample: the whole "
                  "step, and its estimation math alone (normal forces + the one chain call)", title_justify="left")
        for c in ("vehicles stepped together", "wall median", "wall p99", "CPU median", "CPU p99", "math CPU median",
                  "math CPU p99"):
            t.add_column(c, justify="right")
        for n, st in report["batch_stages"].items():
            t.add_row(n, fmt(st["p50"], ".0f"), fmt(st["p99"], ".0f"), fmt(st.get("cpu_p50"), ".0f"),
                      fmt(st.get("cpu_p99"), ".0f"), fmt(st.get("math_cpu_p50"), ".1f"), fmt(st.get("math_cpu_p99"), ".1f"))
        console.print(t)

    t = Table(title="2. sample -> OCP latency over Zenoh, ms (baseline: ping-pong through the same router)",
              title_justify="left")
    for c in ("pipeline", "rate", "p50", "p90", "p99", "max", "sent", "drops", "rej", "ping p50", "ping p99",
              "floor p50"):
        t.add_column(c, justify="left" if c == "pipeline" else "right", no_wrap=True)
    for row in report["latency"]:
        r, b = row["result"], row["baseline"]
        t.add_row(row["pipeline"], f"{row['rate_hz']:.0f} Hz", fmt(r["p50"]), fmt(r["p90"]), fmt(r["p99"]), fmt(r["max"]),
                  str(r["sent"]), str(r["drops"]), str(r["rejections"]), fmt(b["p50"]), fmt(b["p99"]),
                  fmt(HOPS[row["pipeline"]] / 2 * b["p50"]))
    console.print(t)

    from soilocp.services.bench.compare import NOT_PIPELINE, pipeline_rss_mib

    for row in report["latency"]:  # memory of the processes, one vehicle at 100 Hz
        if row["rate_hz"] != 100.0 or not row.get("processes"):
            continue
        pr = row["processes"]
        each = " ".join(f"{n}={fmt(v.get('rss_mib'), '.0f')}/{fmt(v.get('pss_mib'), '.0f')}" for n, v in pr.items()
                        if n not in NOT_PIPELINE)
        console.print(f"memory, {row['pipeline']} pipeline, MiB RSS/PSS per process: {each}; in all RSS "
                      f"{fmt(pipeline_rss_mib(pr), '.0f')} (target <= {TARGETS['rss_mib_total']:.0f}), PSS "
                      f"{fmt(pipeline_rss_mib(pr, 'pss_mib'), '.0f')} (shared pages counted once)")

    cl = report.get("control_loop")
    if cl:
        console.print("5. control loop, sample -> slip set-point (pipeline + controller service, 100 Hz), ms: "
                      + (cl["error"] if "error" in cl else
                         f"p50 {fmt(cl['p50'])}, p90 {fmt(cl['p90'])}, p99 {fmt(cl['p99'])}, max {fmt(cl['max'])}; "
                         f"{cl['sent']} sent, {cl['drops']} without a set-point ({cl['hops']} hops)"))

    for pipe, sc in report["scale"].items():
        t = Table(title=f"3. scale, {pipe} pipeline: vehicles x 100 Hz (pass: p99 < {TARGETS['scale_p99_ms']:.0f} ms, "
                        f"no drop) — max {sc['max_vehicles']} passing, {sc.get('max_vehicles_no_drop', '-')} without a drop",
                  title_justify="left")
        for c in ("vehicles", "ok", "msg/s", "p50", "p99", "max", "drops", "rej", "ping p50", "ping p99", "CPU % per process",
                  "RSS MiB total"):
            t.add_column(c, justify="right", no_wrap=c != "CPU % per process")
        for st in sc["steps"]:
            if "result" not in st:
                t.add_row(str(st["vehicles"]), "no", *["-"] * 8, st.get("error", "")[:60], "-")
                continue
            r, b, pr = st["result"], st["baseline"], st["processes"]
            cpu = " ".join(f"{n}={fmt(v['cpu_percent'], '.0f')}" for n, v in pr.items() if n != "echo")
            rss = sum(v["rss_mib"] or 0.0 for n, v in pr.items() if n not in ("echo", "bench"))
            t.add_row(str(st["vehicles"]), "yes" if st["ok"] else "NO", fmt(r["offered_per_s"], ".0f"), fmt(r["p50"]),
                      fmt(r["p99"]), fmt(r["max"]), str(r["drops"]), str(r["rejections"]), fmt(b["p50"]), fmt(b["p99"]), cpu,
                      fmt(rss, ".0f"))
        console.print(t)
    v = report["verdict"]
    console.print("targets: " + ", ".join(f"{k}={'met' if ok else 'NOT met'}" for k, ok in v.items()))
    console.print(f"bench took {fmt(report['elapsed_s'], '.0f')} s")


@click.command("bench")
@click.option("--quick", is_flag=True, help="Short runs, scale ladder 1-2 vehicles (under 2 minutes).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write the report as JSON here.")
@click.option("--pipeline", "pipelines", multiple=True, type=click.Choice(["standard", "batched"]),
              help="Which live pipeline(s) to measure (default: both when the batched one is installed).")
@click.option("--max-vehicles", type=int, help="Stop the scale ladder at this many vehicles.")
@click.option("--compare", "compare_to", type=click.Path(dir_okay=False),
              help="A baseline report (--json of an earlier run): print each figure's before/after ratio.")
@click.option("--report", "saved", type=click.Path(dir_okay=False),
              help="Do not run: render this saved report (with --compare, compare it to the baseline).")
@click.option("--map", "map_row", is_flag=True,
              help="Only the fleet soil map's row: updates/s one map service sustains, query p99 of a 1 km² box.")
@click.option("--floor", "floor", is_flag=True,
              help="Only the live rows, each for the real pipeline, for its relays without the math (messages) "
                   "and without the messages (zenoh), and for bare zenoh-python relays (bare, the true floor), "
                   "each row also as a ratio to bare (services/bench/floor.py).")
@click.option("--links", "links", multiple=True, type=click.Choice(["client", "peer"]),
              help="With --floor: client (default) and/or peer links between the services, alternating in one run.")
@click.option("--soak", "soak_s", type=click.FloatRange(min=1.0),
              help="Only the soak: one vehicle through the live pipeline for this many seconds; RSS growth per "
                   "process, p99 of the first vs the last tenth, drops, observer resets (services/bench/soak.py).")
@click.option("--soak-rate", type=click.FloatRange(min=1.0, max=2000.0), default=100.0, show_default=True,
              help="With --soak: samples per second.")
def bench(quick: bool, json_out: Optional[str], pipelines: tuple[str, ...], max_vehicles: Optional[int],
          compare_to: Optional[str], saved: Optional[str], map_row: bool = False, floor: bool = False,
          links: tuple[str, ...] = (), soak_s: Optional[float] = None, soak_rate: float = 100.0) -> None:
    """Latency, throughput and scale of the live pipeline, and the cost of each stage."""
    if soak_s is not None:  # hours of driving (services/bench/soak.py)
        from soilocp.services.bench.soak import render_soak, soak_command

        console = bench_console()
        if saved:
            render_soak(json.loads(Path(saved).read_text()), console)
            return
        soak_command(soak_s, soak_rate, json_out, console)
        return

    if floor:  # the live rows next to their relay pipelines (services/bench/floor.py)
        from soilocp.services.bench.floor import floor_command, render_floor

        if compare_to or map_row:
            raise click.UsageError("--floor compares the real pipeline with its relays in one run: it takes neither "
                                   "--compare nor --map (run those without --floor)")

        console = bench_console()
        if saved:
            render_floor(json.loads(Path(saved).read_text()), console)
            return
        floor_command(quick, json_out, list(pipelines), ladder_up_to(quick, max_vehicles), None, console,
                      list(links) or None)
        return

    if map_row:  # the map's own section (services/bench/map.py)
        from soilocp.services.bench.map import render_map, run_map_bench

        console = bench_console()
        row = {"machine": machine_info(), "map": run_map_bench(quick, log=lambda m: console.print(m, style="dim"))}
        render_map(row["map"], console)
        if json_out:
            write_report(row, json_out)
        return

    from soilocp.services.bench.compare import compare, load_report, render_compare

    console = bench_console()
    try:  # a bad baseline fails before minutes of measuring, naming the file
        base = load_report(compare_to) if compare_to else None
        report = load_report(saved) if saved else None
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--compare" if compare_to and not saved else "--report")
    if report is not None:  # a saved run: its tables, or only its comparison with the baseline
        if base is not None:
            render_compare(compare(base, report), console, compare_to)
        else:
            render(report, console)
        return
    if max_vehicles is not None and max_vehicles < 1:
        raise click.BadParameter(f"{max_vehicles!r}: must be >= 1", param_hint="--max-vehicles")
    report = run_bench(quick, list(pipelines) or None, ladder_up_to(quick, max_vehicles), log=lambda m: console.print(m, style="dim"))
    render(report, console)
    if base is not None:
        report["compare"] = {"baseline": str(compare_to), "rows": compare(base, json_safe(report))}
        render_compare(report["compare"]["rows"], console, compare_to)
    if json_out:
        write_report(report, json_out, console)


COMMANDS = [bench]


def main() -> None:  # ``python -m soilocp.services.bench.run``: the same command without the soilocp entry point
    bench(prog_name="python -m soilocp.services.bench.run")


if __name__ == "__main__":
    main()
