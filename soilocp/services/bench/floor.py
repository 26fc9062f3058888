"""``soilocp bench --floor``: the floor of the live rows, measured in one run next to the real pipeline.

The live rows of ``soilocp bench`` (one vehicle at 100 Hz and 1 kHz, the control loop, the
vehicles x 100 Hz ladder) are measured three times, with the same code (``measure_latency``,
``control_loop_latency``, ``measure_scale`` of :mod:`soilocp.services.bench.measure`), the same rates, drives,
statistics and ladder, on rigs of the same process graph and keys:

* ``real``: the deployed services (``Rig.standard`` / ``Rig.batched`` / ``control_rig``);
* ``messages``: every stage a relay of :mod:`soilocp.services.bench.relay` at the messages level (the
  services' message handling: parse, join, store, serialise a real-sized output; no estimation);
* ``zenoh``: every stage a relay at the zenoh level (payload bytes forwarded by the worker);
* ``bare``: every stage a bare zenoh-python process (:mod:`soilocp.services.bench.bare`: a callback that
  republishes a message of the row's output size, on Zenoh's own thread; none of our runtime).

So ``bare`` is the true floor of processes + hops on this machine (what any Python process over
Zenoh costs), ``zenoh - bare`` what our runtime adds (queue hand-off, worker thread, health,
liveliness), ``messages - zenoh`` what the message handling adds and ``real - messages`` what the
estimation adds.  Every live row is also given as a ratio to ``bare`` (CPU per sample summed over
the router and the stages, p50, p99).  ``--links peer`` (repeatable with ``client``) measures the
variants with the services as Zenoh peers that link to each other directly (``bare@peer``...),
in the same run, alternating with the client ones; their ratios are to the client ``bare``.  A full run is three
times the bench's live part (~14 min on 2 cores, twice the whole bench), hence an option of its own
rather than part of the bench or of its ``--quick``.  ``python -m soilocp.services.bench.floor`` is the same command.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

import click

from soilocp.services.bench.measure import (LADDER, RIGS, TARGETS, clone_payloads, ladder_up_to, live_drives,
                                            live_durations, measure_latency, measure_scale, payloads)
from soilocp.services.bench.report import console as bench_console
from soilocp.services.bench.report import fmt, machine_info, write_report

VARIANTS = ("bare", "zenoh", "messages", "real")
LINKS = ("client", "peer")
PIPELINE_ROWS = {"standard": None, "batched": ("gateway", "batch")}  # None: every row of the graph


def relay_rig(pipeline: str, level: str, templates: Path, controller: bool = False):
    """``make_rig(vehicle_ids)`` of the relay pipeline: the graph of ``pipeline`` (+ the controller),
    every process ``python -m soilocp.services.bench.relay NAME --level LEVEL``."""
    from soilocp.services.bench.live import Rig
    from soilocp.services.stages.graph import PIPELINE_SERVICES

    names = list(PIPELINE_ROWS[pipeline] or PIPELINE_SERVICES) + (["controller"] if controller else [])

    def make_rig(vehicle_ids):
        return Rig(list(vehicle_ids), [(n, "soilocp.services.bench.relay", [n, "--level", level, "--templates", str(templates)])
                                       for n in names])

    return make_rig


def bare_rig(pipeline: str, templates: Path, controller: bool = False):
    """``make_rig(vehicle_ids)`` of the bare relay pipeline: the graph of ``pipeline`` (+ the controller),
    every process ``python -m soilocp.services.bench.bare`` with the row's keys and recorded output."""
    from soilocp.services.bench.live import Rig

    names = list(PIPELINE_ROWS[pipeline] or _pipeline_services()) + (["controller"] if controller else [])
    services = [(n, "soilocp.services.bench.bare", bare_args(n, templates)) for n in names]

    def make_rig(vehicle_ids):
        return Rig(list(vehicle_ids), services)

    return make_rig


def _pipeline_services():
    from soilocp.services.stages.graph import PIPELINE_SERVICES

    return PIPELINE_SERVICES


_VID = "VIDXPLACEHOLDER"  # a valid id, replaced by the bare relay's {vid} placeholder


def bare_args(name: str, templates: Path) -> list[str]:
    """The command line of the bare relay standing for row ``name`` (``batch``, ``controller`` too):
    its inputs, the one that triggers a put (the observer's later input), its output key and the file
    of its recorded output (none for the gateway: it forwards the sample's bytes)."""
    from soilocp.schemas import keys
    from soilocp.services.stages.graph import BATCHED_STAGES, BY_NAME

    def k(key_fn) -> str:
        return key_fn(_VID).replace(_VID, "{vid}")

    if name == "batch":
        subs, out, tokens, template = [k(keys.clean)], k(keys.ocp), [*BATCHED_STAGES, "ocp"], "ocp"
    elif name == "controller":
        subs, out, tokens, template = [k(keys.ocp)], k(keys.control_slip), ["controller"], "controller"
    else:
        spec = BY_NAME[name]
        subs, out, tokens = [k(i.key) for i in spec.inputs], k(spec.output), [name]
        template = None if name == "gateway" else name
    args = [a for key in subs for a in ("--sub", key)]
    if len(subs) > 1:  # the observer: its join completes on the later input, the forces
        args += ["--forward", subs[-1]]
    args += ["--pub", out]
    if template is not None:
        args += ["--template", str(templates.parent / f"bare-{template}.json")]
    for t in tokens:
        args += ["--token", keys.alive(_VID, t).replace(_VID, "{vid}")]
    return args


def write_bare_templates(recorded: dict[str, str], templates: Path) -> None:
    """One file per recorded row (and the controller's set-point) beside ``templates``, for the bare relays."""
    import time as _time

    from soilocp.schemas.messages import SlipSetpoint

    setpoint = SlipSetpoint(vehicle_id="bench", controller="ocp_traction", slip=(0.21, 0.22, 0.2, 0.19),
                            source="estimate", fallback=0.12, seq=1234, stamp=12.34, soil_strength=321.5,
                            ocp_age_s=0.004, stale_timeout_s=0.5, issued_at=_time.time())
    for name, text in {**recorded, "controller": setpoint.model_dump_json()}.items():
        (templates.parent / f"bare-{name}.json").write_text(text)


def split_label(label: str) -> tuple[str, str]:
    """``"real@peer"`` -> ``("real", "peer")``; ``"real"`` -> ``("real", "client")``."""
    v, _, links = label.partition("@")
    return v, links or "client"


def _with_links(make_rig, links: str):
    if links == "client":
        return make_rig

    def make(vehicle_ids):
        rig = make_rig(vehicle_ids)
        rig.links = links
        return rig

    return make


def _rig(pipeline: str, label: str, templates: Path):
    v, links = split_label(label)
    make = (RIGS[pipeline] if v == "real" else bare_rig(pipeline, templates) if v == "bare"
            else relay_rig(pipeline, v, templates))
    return _with_links(make, links)


def _control_rig(label: str, templates: Path):
    from soilocp.services.bench.control import control_rig

    v, links = split_label(label)
    make = (control_rig if v == "real" else bare_rig("standard", templates, controller=True) if v == "bare"
            else relay_rig("standard", v, templates, controller=True))
    return _with_links(make, links)


def run_floor(quick: bool = False, pipelines: Optional[list[str]] = None, ladder: Optional[list[int]] = None,
              variants: Optional[list[str]] = None, log=print, links: Optional[list[str]] = None,
              control: bool = True) -> dict[str, Any]:
    """Every live row for every pipeline and variant (each variant once per ``links`` mode, the peer
    ones labelled ``VARIANT@peer``); the report (a JSON-able dict).  ``control``: the control-loop row."""
    from soilocp.services.bench.control import control_loop_latency
    from soilocp.services.bench.relay import record_templates
    from soilocp.services.bench.stages import cpu_share

    t_start = time.monotonic()
    pipelines = list(pipelines or ["standard", "batched"])
    variants = list(variants or VARIANTS)
    if "bare" not in variants:
        variants.insert(0, "bare")  # the baseline of every ratio
    links = list(links or ["client"])
    variants = [v if ln == "client" else f"{v}@{ln}" for v in variants for ln in links]
    ladder = list(ladder or ((1, 2) if quick else LADDER))
    d_100, d_1k, d_scale = live_durations(quick)
    report: dict[str, Any] = {"kind": "floor", "quick": quick, "machine": machine_info(), "targets": TARGETS,
                              "pipelines": pipelines, "variants": variants,
                              "command": "soilocp bench --floor" + (" --quick" if quick else "")}
    report["machine"]["cpu_share_start"] = cpu_share()["share"]
    s100, s1k = live_drives(quick, log)
    p100, p1k = payloads(s100), payloads(s1k)
    work = Path(tempfile.mkdtemp(prefix="soilocp-floor-"))
    try:  # the relays read their recorded outputs from here; removed when the rows are done
        templates = work / "templates.json"
        recorded = record_templates(s100)
        templates.write_text(json.dumps(recorded))
        write_bare_templates(recorded, templates)
        report["message_bytes"] = {"raw sample": len(p100[len(p100) // 2][1]),
                                   **{name: len(text) for name, text in recorded.items()}}

        # variants one after the other within each row, so that they see the same machine
        report["latency"] = []
        for pipe in pipelines:
            for v in variants:
                for row in measure_latency(_rig(pipe, v, templates), f"{pipe}/{v}", p100, p1k, d_100, d_1k, quick, log):
                    report["latency"].append({**row, "pipeline": pipe, "variant": v})
        report["control_loop"] = {}
        for v in (variants if control else []):
            log(f"bench: control loop latency, {v}")
            try:
                report["control_loop"][v] = control_loop_latency(clone_payloads(p100, "bench", "bench"), 100.0, d_100,
                                                                 make_rig=_control_rig(v, templates))
            except RuntimeError as exc:
                report["control_loop"][v] = {"error": str(exc)}
        report["scale"] = {pipe: {v: measure_scale(_rig(pipe, v, templates), f"{pipe}/{v}", p100, ladder, d_scale, quick,
                                                   log) for v in variants} for pipe in pipelines}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report["machine"]["load_end"] = list(os.getloadavg())
    report["machine"]["cpu_share_end"] = cpu_share()["share"]
    report["elapsed_s"] = time.monotonic() - t_start
    report["targets_met"] = targets_met(report)
    report["ratios"] = ratios_to_bare(report)
    return report


def cpu_us_per_sample_of(row: Optional[dict[str, Any]]) -> Optional[float]:
    """CPU µs per sample of one latency row, summed over the router and the stages."""
    if not row or not row.get("processes"):
        return None
    return cpu_per_sample_us(row["processes"], row["rate_hz"] * row.get("vehicles", 1))


def ratios_to_bare(report: dict[str, Any]) -> dict[str, dict[str, dict[str, Optional[float]]]]:
    """Per pipeline and variant, each live row's figures over the bare relay's in the same run:
    ``{pipe: {variant: {"100hz_cpu": x, "100hz_p50": x, ..., "control_p99": x}}}`` (None: a figure missing)."""

    def ratio(a: Optional[float], b: Optional[float]) -> Optional[float]:
        if a is None or b is None or not b or not math.isfinite(a) or not math.isfinite(b):
            return None
        return a / b

    lat = {(r["pipeline"], r["variant"], r["rate_hz"]): r for r in report["latency"]}
    out: dict[str, dict[str, dict[str, Optional[float]]]] = {}
    for pipe in report["pipelines"]:
        for v in report["variants"]:
            got = out.setdefault(pipe, {}).setdefault(v, {})
            for rate, tag in ((100.0, "100hz"), (1000.0, "1khz")):
                row, base = lat.get((pipe, v, rate)), lat.get((pipe, "bare", rate))
                got[f"{tag}_cpu"] = ratio(cpu_us_per_sample_of(row), cpu_us_per_sample_of(base))
                for q in ("p50", "p99"):
                    got[f"{tag}_{q}"] = ratio(row and row["result"].get(q), base and base["result"].get(q))
            if pipe == "standard":
                cl, cb = report.get("control_loop", {}).get(v, {}), report.get("control_loop", {}).get("bare", {})
                for q in ("p50", "p99"):
                    got[f"control_{q}"] = ratio(cl.get(q), cb.get(q))
    return out


def targets_met(report: dict[str, Any]) -> dict[str, dict[str, bool]]:
    """Per pipeline and variant: which of the live targets the run meets."""
    out: dict[str, dict[str, bool]] = {}
    for row in report["latency"]:
        r, key = row["result"], f"{row['pipeline']}/{row['variant']}"
        met = out.setdefault(key, {})
        if row["rate_hz"] == 100.0:
            met["p99_100hz"] = r["p99"] <= TARGETS["p99_ms_100hz"]
        else:
            met["1khz"] = r["drops"] == 0 and r["rejections"] == 0 and r["p99"] <= TARGETS["p99_ms_1khz"]
    for pipe, by_variant in report["scale"].items():
        need = 20 if pipe == "standard" else TARGETS["vehicles_100hz"]  # >= 20 / >= 100 vehicles at 100 Hz
        for v, sc in by_variant.items():
            out.setdefault(f"{pipe}/{v}", {})["vehicles"] = sc["max_vehicles"] >= need
    for v, cl in report.get("control_loop", {}).items():
        out.setdefault(f"standard/{v}", {})["control_p99"] = "error" not in cl and cl["p99"] <= TARGETS["p99_ms_100hz"]
    return out


# ----------------------------------------------------------------------------------------------
# output
# ----------------------------------------------------------------------------------------------
def _top_step(sc: dict[str, Any]) -> Optional[dict[str, Any]]:
    """The ladder's largest count measured without a drop (else its first step)."""
    good = [s for s in sc.get("steps", []) if s.get("carried")]
    return good[-1] if good else next((s for s in sc.get("steps", []) if "result" in s), None)


def cpu_per_sample_us(procs: dict[str, Any], rate_hz: float = 1000.0) -> Optional[float]:
    """CPU µs per sample of the pipeline's processes (router + stages; not the bench nor the echo), from a
    one-vehicle row's CPU %: what the graph costs per sample, whatever the machine's load does to latency."""
    from soilocp.services.bench.compare import NOT_PIPELINE

    vals = [p.get("cpu_percent") for n, p in procs.items() if n not in NOT_PIPELINE]
    if not vals or any(v is None for v in vals):
        return None
    return sum(vals) / 100.0 / rate_hz * 1e6


def _cpu(procs: Optional[dict[str, Any]]) -> str:
    if not procs:
        return "-"
    return " ".join(f"{n}={fmt(p.get('cpu_percent'), '.0f')}" for n, p in procs.items() if n != "echo")


def render_floor(report: dict[str, Any], console) -> None:
    from rich.table import Table

    m = report["machine"]
    console.print(f"{report['command']} — {m['nproc']} CPU(s), {m['cpu_model']}, load {fmt(m['load_start'][0])} "
                  f"-> {fmt(m.get('load_end', [float('nan')])[0])}; a busy thread got {fmt(m.get('cpu_share_start'))} "
                  f"of a core at the start, {fmt(m.get('cpu_share_end'))} at the end")
    console.print("message sizes, bytes: " + ", ".join(f"{k} {v}" for k, v in report.get("message_bytes", {}).items()))
    lat = {(r["pipeline"], r["variant"], r["rate_hz"]): r for r in report["latency"]}
    for pipe in report["pipelines"]:
        t = Table(title=f"floor of the live rows, {pipe} pipeline: real services vs relays (messages: parse + "
                        "serialise, no math; zenoh: bytes forwarded), ms", title_justify="left")
        cols = ["variant", "100 Hz p50", "p99", "ping p99", "CPU µs/sample", "1 kHz p50", "p99", "drops", "CPU µs/sample",
                "vehicles passing", "no drop", "ladder p99 at that count"]
        if pipe == "standard":
            cols += ["control p50", "control p99"]
        for c in cols:
            t.add_column(c, justify="left" if c == "variant" else "right", no_wrap=True)
        for v in report["variants"]:
            a, b = lat.get((pipe, v, 100.0)), lat.get((pipe, v, 1000.0))
            ra = a["result"] if a else {}
            rb = b["result"] if b else {}
            sc = report["scale"][pipe].get(v, {"steps": [], "max_vehicles": "-", "max_vehicles_no_drop": "-"})
            top = _top_step(sc)
            cells = [v, fmt(ra.get("p50")), fmt(ra.get("p99")), fmt(a["baseline"]["p99"]) if a else "-",
                     fmt(cpu_us_per_sample_of(a), ".0f"), fmt(rb.get("p50")), fmt(rb.get("p99")), str(rb.get("drops", "-")),
                     fmt(cpu_per_sample_us(b["processes"]) if b else None, ".0f"), str(sc["max_vehicles"]),
                     str(sc["max_vehicles_no_drop"]),
                     f"{fmt(top['result']['p99'])} ({top['vehicles']})" if top and "result" in top else "-"]
            if pipe == "standard":
                cl = report["control_loop"].get(v, {})
                cells += ["-", "-"] if "error" in cl or not cl else [fmt(cl["p50"]), fmt(cl["p99"])]
            t.add_row(*cells)
        console.print(t)
        rt = report.get("ratios", {}).get(pipe)
        if rt:
            t = Table(title=f"every live row over the bare zenoh-python relay of the same run, {pipe} pipeline "
                            "(CPU: µs per sample summed over router and stages; x = times the bare relay's)",
                      title_justify="left")
            keys_ = [k for k in ("100hz_cpu", "100hz_p50", "100hz_p99", "1khz_cpu", "1khz_p50", "1khz_p99",
                                 "control_p50", "control_p99") if any(k in r for r in rt.values())]
            t.add_column("variant", no_wrap=True)
            for k in keys_:
                t.add_column(k.replace("100hz_", "100 Hz ").replace("1khz_", "1 kHz ").replace("control_", "control "),
                             justify="right", no_wrap=True)
            for v, r in rt.items():
                t.add_row(v, *[fmt(r.get(k)) + ("x" if r.get(k) is not None else "") for k in keys_])
            console.print(t)
        t = Table(title=f"CPU % of one core per process, {pipe} pipeline (1 kHz: % x 10 = µs per sample; "
                        "CPU µs/sample above: their sum over router and stages)",
                  title_justify="left")
        for c in ("variant", "row", "CPU % per process"):
            t.add_column(c, no_wrap=c != "CPU % per process")
        for v in report["variants"]:
            for rate in (100.0, 1000.0):
                row = lat.get((pipe, v, rate))
                t.add_row(v, f"1 vehicle, {rate:.0f} Hz", _cpu(row and row["processes"]))
            top = _top_step(report["scale"][pipe].get(v, {"steps": []}))
            if top and "result" in top:
                t.add_row(v, f"{top['vehicles']} vehicles x 100 Hz", _cpu(top["processes"]))
        console.print(t)
    tm = report.get("targets_met", {})
    console.print("targets met: " + "; ".join(
        f"{k}: " + ", ".join(f"{n}={'yes' if ok else 'NO'}" for n, ok in met.items()) for k, met in tm.items()))
    console.print(f"floor run took {fmt(report.get('elapsed_s'), '.0f')} s")


def floor_command(quick: bool, json_out: Optional[str], pipelines: list[str], ladder: Optional[list[int]],
                  variants: Optional[list[str]], console, links: Optional[list[str]] = None,
                  control: bool = True) -> dict[str, Any]:
    """``soilocp bench --floor``: run, print the tables, write the JSON."""
    report = run_floor(quick, pipelines or None, ladder, variants, log=lambda msg: console.print(msg, style="dim"),
                       links=links or None, control=control)
    render_floor(report, console)
    if json_out:
        write_report(report, json_out, console)
    return report


@click.command("floor")
@click.option("--quick", is_flag=True, help="Short rows, ladder 1-2 vehicles.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write the report as JSON here.")
@click.option("--pipeline", "pipelines", multiple=True, type=click.Choice(["standard", "batched"]))
@click.option("--variant", "variants", multiple=True, type=click.Choice(VARIANTS),
              help="Variants to measure (default: all; bare, the baseline of the ratios, always).")
@click.option("--links", "links", multiple=True, type=click.Choice(LINKS),
              help="client (default): every process a client of the router; peer: the services link to each other "
                   "directly.  Repeat for both, alternating in the same run.")
@click.option("--no-control", is_flag=True, help="Skip the control-loop row.")
@click.option("--max-vehicles", type=int, help="Stop the ladder at this many vehicles.")
@click.option("--report", "saved", type=click.Path(dir_okay=False, exists=True), help="Render a saved report.")
def floor_cmd(quick, json_out, pipelines, variants, links, no_control, max_vehicles, saved) -> None:
    """The floor of the live rows: the real pipeline next to its relays (no math; no messages)."""
    console = bench_console()
    if saved:
        render_floor(json.loads(Path(saved).read_text()), console)
        return
    floor_command(quick, json_out, list(pipelines), ladder_up_to(quick, max_vehicles), list(variants) or None, console, list(links) or None,
                  control=not no_control)


if __name__ == "__main__":
    floor_cmd(prog_name="python -m soilocp.services.bench.floor")
