"""Offline commands: estimate (sensor log -> estimates), evaluate (against truth), plot."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from soilocp.commands.errors import BadInput
from rich.console import Console
from rich.table import Table


def _fmt(v, spec=".3f"):
    return "—" if v is None else format(v, spec)



def _numbers_table(title: str, columns: tuple[str, ...]) -> Table:
    t = Table(title=title)
    for col in columns:
        t.add_column(col, justify="right")
    return t

@click.command()
@click.argument("sensors", type=click.Path(exists=True))
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False),
              help="ESTIMATES.jsonl to write, or E.mcap (MCAP channels for Foxglove)")
@click.option("--map", "map_path", type=click.Path(exists=True, dir_okay=False),
              help="SENSORS is a ROS 2 bag: the map file of its topics (see soilocp import)")
@click.option("--vehicle", type=click.Path(exists=True, dir_okay=False), help="Vehicle parameters JSON")
@click.option("--torque-constant", "torque_constant", metavar="K|FILE.json",
              help="N m at the wheel per unit of the log's wheel_torque (e.g. a motor current's constant), or the "
                   "JSON of soilocp calibrate-torque --json; default 1 (the log holds torques in N m)")
@click.option("--constants", type=click.Path(exists=True, dir_okay=False), help="Model constants JSON (soilocp calibrate)")
@click.option("--config", type=click.Path(exists=True, dir_okay=False), help="Pipeline config JSON (observer, soil)")
@click.option("--no-compensation", is_flag=True, help="Observer without motion-resistance compensation (paper Figs. 11, 13)")
@click.option("--method", type=click.Choice(["bayes", "paper"]), default=None, help="Soil-strength estimator")
@click.option("--full", is_flag=True, help="Also write normal forces, gross traction, resistance, the filtered ground speed and its measured latency per record")
@click.option("--map-prior", "map_prior", metavar="STORE",
              help="Start each vehicle's soil belief from this fleet soil map's cells (a map store URL, e.g. "
                   "sqlite:PATH, as soilocp service map --store) on entering each, as the soil-strength service's "
                   "map_prior (docs/map.md)")
@click.option("--map-prior-min-count", "map_prior_min_count", type=click.IntRange(min=1), default=1, show_default=True,
              help="With --map-prior: a cell seen by fewer estimates is not trusted (the service's map_prior.min_count)")
def estimate(sensors, out, map_path, vehicle, torque_constant, constants, config, no_compensation, method, full,
             map_prior, map_prior_min_count):
    """Run the whole chain on a sensor log: validate -> normal forces -> observer -> slip + K -> OCPs.

    Writes one JSON record per valid input sample.  Invalid lines are reported on stderr with
    their line number and skipped.  Ends with the records per status and reason code, each with
    the next step that can bring it to ok.  Exits 1 when no record was written (an empty log, or
    every line rejected).
    """
    from soilocp.estimation.pipeline import load_pipeline_config
    from soilocp.commands.io import estimate_source

    try:
        cfg = load_pipeline_config(config, vehicle=vehicle, constants=constants, torque_constant=torque_constant)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if no_compensation:
        cfg = cfg.model_copy(update={"observer": cfg.observer.model_copy(update={"structure": "none"})})
    if method:
        soil = cfg.soil.model_copy(update={"method": method, **({"measurement": "net"} if method == "paper" else {})})
        cfg = cfg.model_copy(update={"soil": soil})
    prior = None if map_prior is None else _store_prior(map_prior, cfg, map_prior_min_count)
    t0 = time.perf_counter()
    summary = estimate_source(sensors, map_path, out, cfg, full=full, map_prior=prior)
    dt = time.perf_counter() - t0
    report_estimate(summary, sensors, out, dt, cfg, vehicle_given=vehicle is not None or _config_has_vehicle(config))


def _config_has_vehicle(config) -> bool:
    """The pipeline config file gives a vehicle (its ``vehicle`` key)."""
    if config is None:
        return False
    try:
        return "vehicle" in json.loads(Path(config).read_text(encoding="utf-8"))
    except (OSError, ValueError, TypeError):
        return False


def _store_prior(url: str, cfg, min_count: int):
    """``vehicle_id -> MapPrior`` over every cell of the map store ``url`` (read once, now), with the store's
    cells (their size, H3 resolution) and the vehicle of ``cfg``."""
    from soilocp.map.prior import MapPrior
    from soilocp.map.store import open_store

    try:
        st = open_store(url)
    except Exception as exc:
        raise BadInput(f"--map-prior {url}: cannot open the map store: {exc}") from None
    try:
        cells, cell_config = st.all_cells(time.time()), st.cell_config
    finally:
        st.close()
    return lambda _vid: MapPrior(cells, cell_config, vehicle=cfg.vehicle, min_count=min_count)


def report_estimate(summary, sensors: str, out: str, dt: float, cfg, *, vehicle_given: bool) -> None:
    """What ``soilocp estimate`` says at the end, on stderr: the counts, the records per status and reason
    code with the next steps, a warning when the data do not look like the vehicle; and exit 1 when no
    record was written (with the cause)."""
    from soilocp.estimation.next_steps import status_table, verdict
    from soilocp.estimation.vehicle_check import vehicle_warning

    err = Console(stderr=True, width=max(Console(stderr=True).width, 120))
    rate = summary.estimates / dt if dt > 0 else float("inf")
    click.echo(f"{summary.estimates} estimates from {summary.lines} lines ({len(summary.rejected)} rejected"
               f"{', by reason ' + str(summary.rejected_by_code()) if summary.rejected else ''}) "
               f"in {dt:.2f} s = {rate:.0f} samples/s -> {out}", err=True)
    for lineno, error in summary.stage_errors[:20]:
        click.echo(f"{sensors}:{lineno}: processing failed, that vehicle's chain restarted: {error}", err=True)
    if len(summary.stage_errors) > 20:
        click.echo(f"... {len(summary.stage_errors)} processing failures in all", err=True)
    if summary.estimates == 0:
        if not summary.rejected:
            raise click.ClickException(f"{sensors} holds no sensor sample ({summary.lines} lines, all blank): "
                                       f"nothing estimated, {out} is empty; the sensor log's format: docs/sensor-log.md")
        codes = ", ".join(f"{c} {n}" for c, n in sorted(summary.rejected_by_code().items(), key=lambda kv: -kv[1]))
        lineno, code, message = summary.rejected[0]
        raise click.ClickException(
            f"every sample of {sensors} was rejected ({len(summary.rejected)} lines: {codes}), so {out} is empty; "
            f"the first, line {lineno}: {code}: {message}. Fix the log to the sensor-log contract "
            "(docs/sensor-log.md) or import it with soilocp import")
    extras = []
    if summary.resets:
        extras.append("observer resets: " + ", ".join(f"{k} {v}" for k, v in sorted(summary.resets.items())))
    if summary.unusable:
        extras.append("wheel-samples out of the model: "
                      + ", ".join(f"{k} {v}" for k, v in sorted(summary.unusable.items())))
    if summary.rejected:
        extras.append("rejected lines: " + ", ".join(f"{c} {n}" for c, n in sorted(summary.rejected_by_code().items())))
    for line in extras:
        click.echo(line, err=True)
    err.print(status_table(summary.reasons))
    click.echo(verdict(summary.reasons), err=True)
    warning = vehicle_warning(summary.fit, cfg.vehicle, vehicle_given)
    if warning:  # last: the line a user reads first
        click.echo(warning, err=True)


@click.command()
@click.option("--truth", required=True, type=click.Path(exists=True, dir_okay=False), help="TRUTH.jsonl from soilocp simulate")
@click.argument("estimates", type=click.Path(exists=True, dir_okay=False))
@click.option("--settle", default=2.0, show_default=True, help="Seconds after each terrain change before errors count")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table")
@click.option("--check", is_flag=True, help="Exit 1 unless every target is met on every segment")
def evaluate(truth, estimates, settle, as_json, check):
    """Accuracy of ESTIMATES against simulator truth, per terrain segment, with the targets."""
    from soilocp.analysis.evaluation import TARGETS, evaluate_files, results_as_json

    try:
        results = evaluate_files(truth, estimates, settle)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    ok = all(all(r.passes().values()) for r in results)
    if as_json:
        click.echo(json.dumps({"targets": TARGETS, "segments": results_as_json(results), "all_pass": ok}, indent=2))
    else:
        t = _numbers_table(f"K and OCP accuracy vs truth (settle {settle:g} s)",
                           ("seg", "soil", "K true", "coverage", "K med err", "K p90 err", "conv (s)",
                            "|mu_T| err", "|S_T| err", "|S_E| err", "class acc", "pass"))
        for r in results:
            p = r.passes()
            t.add_row(
                str(r.index), r.soil_class, f"{r.soil_strength:g}", f"{r.coverage:.0%}",
                _fmt(r.k_median_rel, ".1%"), _fmt(r.k_p90_rel, ".1%"), _fmt(r.convergence_s, ".2f"),
                _fmt(r.mu_T_median_abs, ".4f"), _fmt(r.S_T_median_abs, ".4f"), _fmt(r.S_E_median_abs, ".4f"),
                _fmt(r.class_accuracy, ".0%"), "yes" if all(p.values()) else "no: " + ",".join(k for k, v in p.items() if not v),
            )
        Console(width=160).print(t)
        counts = {}
        for r in results:
            for k, v in r.statuses.items():
                counts[k] = counts.get(k, 0) + v
        click.echo(f"statuses: {counts}")
    if check and not ok:
        sys.exit(1)


@click.command()
@click.option("--truth", type=click.Path(exists=True, dir_okay=False), help="TRUTH.jsonl (optional)")
@click.option("--estimates", "estimates", required=True, multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="ESTIMATES.jsonl (repeat to compare, e.g. with/without compensation)")
@click.option("--label", "labels", multiple=True, help="Label for each --estimates")
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Directory for the PNGs")
def plot(truth, estimates, labels, out):
    """PNG time series like the paper's Figs. 8-18: normal forces, slip, mu, K, OCPs (estimate vs truth)."""
    from soilocp.analysis.timeseries_plots import plot_run

    if labels and len(labels) != len(estimates):
        raise click.UsageError("give one --label per --estimates")
    for path in ([truth] if truth else []) + list(estimates):
        _check_records(path)
    paths = plot_run(truth, list(estimates), list(labels) or None, Path(out))
    for p in paths:
        click.echo(str(p))


def _check_records(path: str) -> None:
    """BadInput unless ``path`` holds at least one JSON record (an empty file has nothing to plot)."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except ValueError as exc:
                raise BadInput(f"{path}:{lineno}: not a JSON record ({exc}): expected the JSON Lines of soilocp "
                               "estimate (or soilocp simulate --truth)") from None
            if not isinstance(rec, dict):
                raise BadInput(f"{path}:{lineno}: a JSON {type(rec).__name__}, not a record")
            return
    raise BadInput(f"{path} holds no record (empty file): nothing to plot; write it with soilocp estimate "
                   "(or soilocp simulate --truth)")


COMMANDS = [estimate, evaluate, plot]


@click.command()
@click.option("--scenario", "scenarios", multiple=True, help="Scenario(s); default: sand gravel grass firm sandy-slope mixed")
@click.option("--mode", "modes", multiple=True, type=click.Choice(["excitation", "cruise"]), help="Default: both")
@click.option("--compensation/--no-compensation", "compensation", default=None,
              help="Only with / without motion-resistance compensation (default: both)")
@click.option("--duration", type=float, help="Override every scenario's duration, s")
@click.option("--seed", default=0, show_default=True, help="Seed of the simulated sensor noise (with --seeds N, the first of N)")
@click.option("--jobs", default=2, show_default=True, help="Parallel processes")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write the full results as JSON")
@click.option("--robustness", is_flag=True, help="Instead: the variants the estimator was not tuned to (soilocp.sim.variants)")
@click.option("--seeds", default=1, show_default=True, help="--robustness: seeds per variant (seed, seed+1, ...)")
@click.option("--variant", "variants", multiple=True, help="--robustness: only these variant(s); default: all")
@click.option("--markdown", is_flag=True, help="--robustness: print the table as Markdown (for the README)")
@click.option("--vehicle", "vehicle_path", type=click.Path(exists=True, dir_okay=False),
              help="Vehicle JSON, simulated and estimated (e.g. docs/maps/skid-steer-rover.json); default: the built-in rover")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False),
              help="Pipeline config JSON (observer, soil; as soilocp estimate --config): judge your settings, e.g. "
                   "the torque constant's uncertainty after soilocp calibrate-torque; default: the defaults")
def accuracy(scenarios, modes, compensation, duration, seed, jobs, json_out, robustness, seeds, variants, markdown,
             vehicle_path, config_path):
    """Accuracy against simulator truth: every scenario x mode x compensation, worst segment per run.

    Excitation mode is judged against the targets; cruise mode shows what is identifiable without
    a traction test (on flat ground at cruise slip is ~0: the right answer is no estimate).

    With --robustness: one row per variant (other sample rates, epoch stamps, sensor scale errors,
    held channels, a different true vehicle, mirrored or other sweeps, S-turns) run through the
    nominal estimator.
    """
    config = None
    if vehicle_path or config_path:
        from soilocp.estimation.pipeline import load_pipeline_config

        try:
            config = load_pipeline_config(config_path, vehicle=vehicle_path)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
    drive = "".join(f"; {what} {path}" for what, path in (("vehicle", vehicle_path), ("config", config_path)) if path)
    if robustness:
        from soilocp.commands.robustness_table import run_and_print

        return run_and_print(variants, seed, seeds, duration, jobs, json_out, markdown, config, drive)
    if variants or seeds != 1 or markdown:
        raise click.UsageError("--variant, --seeds and --markdown need --robustness")
    from soilocp.analysis.accuracy import DEFAULT_SCENARIOS, results_json, run_matrix
    from soilocp.analysis.evaluation import TARGETS

    comp = (True, False) if compensation is None else (compensation,)
    t0 = time.perf_counter()
    results = run_matrix(scenarios or DEFAULT_SCENARIOS, modes or ("excitation", "cruise"), comp, seed, duration, jobs,
                         config)
    table = _numbers_table(f"Accuracy vs simulator truth (worst segment; settle {TARGETS['settle_s']:g} s; seed {seed}{drive})",
                           ("scenario", "mode", "MR comp.", "coverage", "K med err", "K p90 err", "conv. start",
                            "conv. change", "OCP med err", "class acc", "statuses", "targets"))
    for r in results:
        w = r.worst()
        verdict = ("met" if r.passes() else "missed") if r.mode == "excitation" else "n/a (cruise)"
        st = ", ".join(f"{k} {v / r.samples:.0%}" for k, v in sorted(r.statuses.items(), key=lambda kv: -kv[1]))
        table.add_row(r.scenario, r.mode, "yes" if r.compensation else "no", f"{w['coverage']:.0%}",
                      _fmt(w["k_median_rel"], ".1%"), _fmt(w["k_p90_rel"], ".1%"), _fmt(w["initial_convergence_s"], ".2f"),
                      _fmt(w["change_convergence_s"], ".2f"), _fmt(w["ocp_median_abs"], ".4f"),
                      _fmt(w["class_accuracy"], ".0%"), st, verdict)
    Console(width=200).print(table)
    rates = [r.estimate_rate for r in results]
    click.echo(f"estimate rate {min(rates):.0f}..{max(rates):.0f} samples/s; {len(results)} runs in {time.perf_counter() - t0:.0f} s")
    if json_out:
        Path(json_out).write_text(results_json(results))
    failed = [r for r in results if r.mode == "excitation" and r.compensation and not r.passes()]
    if failed:
        click.echo("targets missed (excitation, with compensation): " + ", ".join(r.scenario for r in failed), err=True)
        sys.exit(1)


COMMANDS.append(accuracy)
