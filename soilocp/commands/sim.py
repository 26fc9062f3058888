"""``soilocp simulate``: drive the simulated rover and write its sensor log (and ground truth)."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import click

from soilocp.model.constants import load_constants
from soilocp.sim.scenarios import MODES, SweepParams, get_scenario, list_scenarios
from soilocp.sim.sensor_models import SensorNoise
from soilocp.model.vehicle import load_vehicle


def _print_scenarios() -> None:
    for sc in list_scenarios():
        click.echo(
            f"{sc.name}: {sc.description}\n  default mode {sc.mode}, {sc.duration:g} s at {sc.speed:g} m/s; "
            f"front-axle sweep {sc.sweep.s_min:g}..{sc.sweep.s_max:g}..{sc.sweep.s_min:g} in {sc.sweep.period:g} s + {sc.sweep.dwell:g} s dwell"
        )
        start = 0.0
        for i, seg in enumerate(sc.segments):
            end = "end" if math.isinf(seg.length) else f"{start + seg.length:g} m"
            click.echo(
                f"    [{i}] {start:g} m .. {end}: {seg.soil_class} K={seg.soil_strength:g}, "
                f"grade {math.degrees(seg.grade):g} deg, cross-slope {math.degrees(seg.cross_slope):g} deg"
            )
            start += seg.length


@click.command("simulate")
@click.option("--scenario", "scenario_name", metavar="NAME", help="Scenario name (see --list).")
@click.option("--list", "list_only", is_flag=True, help="List the scenarios with their segments and exit.")
@click.option("--duration", type=float, default=None, help="Seconds to drive [default: the scenario's].")
@click.option("--rate", type=float, default=100.0, show_default=True, help="Sensor sample rate, Hz.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sensor noise.")
@click.option("--vehicle", "vehicle_path", type=click.Path(dir_okay=False), default=None, help="Vehicle JSON file [default: built-in rover].")
@click.option("--constants", "constants_path", type=click.Path(dir_okay=False), default=None, help="Model constants JSON [default: the paper's].")
@click.option("--mode", type=click.Choice(MODES), default=None, help="Controller mode [default: the scenario's].")
@click.option("--sweep-min", type=float, default=None, help="Excitation: lowest slip of the sweep.")
@click.option("--sweep-max", type=float, default=None, help="Excitation: highest slip of the sweep.")
@click.option("--sweep-period", type=float, default=None, help="Excitation: sweep period, s.")
@click.option("--sweep-dwell", type=float, default=None, help="Excitation: seconds held at the lowest slip after each sweep.")
@click.option("--vehicle-id", default="rover1", show_default=True, help="vehicle_id written in every record.")
@click.option("--noiseless", is_flag=True, help="Exact truth through the sensors (no noise, bias or quantisation).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None, help="Sensor log to write (JSON Lines, SensorSample).")
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None, help="Truth log to write (JSON Lines, TruthRecord).")
@click.option("--start", "start_pose", metavar="FRAME:X,Y[,HEADING][@LAT,LON]", default=None,
              help="Start pose in a map frame: the samples carry true positions (docs/map.md).")
def simulate(
    scenario_name, list_only, duration, rate, seed, vehicle_path, constants_path, mode,
    sweep_min, sweep_max, sweep_period, sweep_dwell, vehicle_id, noiseless, out_path, truth_path, start_pose=None,
):  # fmt: skip
    """Drive the simulated rover over a scenario; write the sensor log (and the ground truth)."""
    from soilocp.sim.field import parse_start_pose
    from soilocp.sim.simulator import simulate as run_simulation

    if list_only:
        _print_scenarios()
        return
    if not scenario_name:
        raise click.UsageError("--scenario NAME is required (or --list)")
    if not out_path:
        raise click.UsageError("--out SENSORS.jsonl is required")
    try:
        sc = get_scenario(scenario_name)
        sw = sc.sweep
        if any(v is not None for v in (sweep_min, sweep_max, sweep_period, sweep_dwell)):
            sw = SweepParams(
                s_min=sw.s_min if sweep_min is None else sweep_min,
                s_max=sw.s_max if sweep_max is None else sweep_max,
                period=sw.period if sweep_period is None else sweep_period,
                dwell=sw.dwell if sweep_dwell is None else sweep_dwell,
            )
        gen = run_simulation(
            sc,
            duration=duration,
            rate=rate,
            seed=seed,
            vehicle=load_vehicle(vehicle_path),
            constants=load_constants(constants_path),
            mode=mode,
            noise=SensorNoise.noiseless() if noiseless else None,
            vehicle_id=vehicle_id,
            sweep=sw,
            start=parse_start_pose(start_pose) if start_pose else None,
        )
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc

    t0, c0 = time.perf_counter(), time.process_time()
    n = 0
    smin = [math.inf] * 4
    smax = [-math.inf] * 4
    last = None
    out = Path(out_path).open("w")
    tr = Path(truth_path).open("w") if truth_path else None
    try:
        for sample, truth in gen:
            out.write(sample.model_dump_json() + "\n")
            if tr:
                tr.write(truth.model_dump_json() + "\n")
            smin = [min(a, b) for a, b in zip(smin, truth.slip)]
            smax = [max(a, b) for a, b in zip(smax, truth.slip)]
            n += 1
            last = truth
    finally:
        out.close()
        if tr:
            tr.close()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    sim_t = n / rate
    click.echo(
        f"{sc.name} ({last.mode}): {n} samples, {sim_t:g} s simulated in {wall:.2f} s wall / {cpu:.2f} s CPU "
        f"({sim_t / wall:.0f}x real time) -> {out_path}" + (f", {truth_path}" if truth_path else ""),
        err=True,
    )
    click.echo(
        "  slip range per wheel (1 LR, 2 LF, 3 RF, 4 RR): "
        + ", ".join(f"[{a:.3f}, {b:.3f}]" for a, b in zip(smin, smax))
        + f"; final speed {last.ground_speed:.3f} m/s, distance {last.distance:.1f} m",
        err=True,
    )
    sys.stderr.flush()


COMMANDS = [simulate]
