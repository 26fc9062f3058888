"""Import commands: ROS 2 bags and multi-rate CSV logs -> the sensor log (``soilocp import``), and
the shared helper that lets ``soilocp estimate`` take a bag (``--map``) and write MCAP."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Optional

import click

from soilocp.commands.errors import BadInput


def _map_or_fail(map_path: str):
    from soilocp.ingest import load_map

    try:
        return load_map(map_path)
    except ValueError as exc:
        raise BadInput(str(exc)) from None


def _report(prov, issues: list[str], out) -> None:
    click.echo(f"{prov.samples} samples written from {prov.ticks} ticks -> {out} (+ {out}.provenance.json)", err=True)
    for reason, n in sorted(prov.skipped.items()):
        click.echo(f"  skipped {n} tick{'s' if n != 1 else ''}: {reason}", err=True)
    for line in issues:
        click.echo(f"  dropped: {line}", err=True)
    click.echo(f"  drive {prov.drive}; ground speed {prov.ground_speed}; wheel torque {prov.wheel_torque}; "
               f"roll/pitch from {prov.attitude}", err=True)
    if not prov.identifiable:
        click.echo("  K NOT IDENTIFIABLE from this log: " + "; ".join(prov.reasons)
                   + " -> soilocp estimate writes status no_estimate (reason not_identifiable) and no K", err=True)


def run_import(bag: Optional[str], csv_specs: tuple[str, ...], map_path: str, out: str, *, strict: bool = False,
               progress: bool = True, quiet: bool = False):
    """Import and report; click errors on bad input (used by import, estimate --map, run --map)."""
    from soilocp.ingest import import_source

    tmap = _map_or_fail(map_path)
    files = {}
    for spec in csv_specs:
        role, sep, path = spec.partition("=")
        if not sep or not role or not path:
            raise click.UsageError(f"--csv {spec!r}: expected ROLE=FILE, e.g. --csv imu=IMU.csv")
        files[role] = path
    try:
        prov, issues = import_source(bag, files or None, tmap, out, strict=strict, progress=progress)
    except ValueError as exc:  # BagImportError / CsvImportError name topic or file, field and reason
        raise click.ClickException(str(exc)) from None
    if not quiet:
        _report(prov, issues, out)
    return prov


@click.command("import")
@click.argument("bag", required=False, type=click.Path(exists=True))
@click.option("--csv", "csv_specs", multiple=True, metavar="ROLE=FILE",
              help="CSV log per role of the map's csv section (imu, wheels, ground_speed); repeat")
@click.option("--map", "map_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Map file (YAML): topics or columns -> sensor-log fields")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="Sensor log (JSON Lines) to write")
@click.option("--strict", is_flag=True, help="Stop at the first bad message instead of dropping it with a reason")
@click.option("--no-progress", is_flag=True, help="No progress bar on long bags")
def import_cmd(bag, csv_specs, map_path, out, strict, no_progress):
    """A ROS 2 bag (rosbag2 dir, sqlite3 or MCAP storage, or a .mcap file) or CSV logs -> sensor log.

    Topics of different rates are put on one clock of rate_hz ticks: each takes its last value up
    to its max_age; a tick with a stale stream is skipped and counted.  Header stamps (Unix time)
    are kept.  Bad messages are dropped with their topic, field and reason; the rest is kept.
    """
    if (bag is None) == (not csv_specs):
        raise click.UsageError("give a BAG, or --csv ROLE=FILE files (not both)")
    run_import(bag, csv_specs, map_path, out, strict=strict, progress=not no_progress)


def estimate_source(sensors: str, map_path: Optional[str], out: str, cfg, *, full: bool = False, map_prior=None):
    """``soilocp estimate``: a sensor log (with its provenance file, if any) or, with ``map_path``, a bag;
    ``map_prior(vehicle_id)``: a vehicle's fleet-map prior, or None."""
    from soilocp.export.estimate_out import estimate_to
    from soilocp.ingest import read_provenance

    if map_path is None:
        if Path(sensors).is_dir() or Path(sensors).suffix in (".mcap", ".db3"):
            raise click.UsageError(f"{sensors} looks like a ROS 2 bag: give its topics with --map MAP.yaml")
        try:
            prov = _with_torque_constant(read_provenance(sensors), cfg)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
        _check_drive(prov, cfg)
        withheld: dict[str, int] = {}
        return _said(estimate_to(sensors, out, cfg, full=full, provenance=prov, withheld=withheld,
                                 map_prior=map_prior), withheld)
    with tempfile.TemporaryDirectory(prefix="soilocp-import-") as tmp:
        log = str(Path(tmp) / "sensors.jsonl")
        prov = _with_torque_constant(run_import(sensors, (), map_path, log, progress=sys.stderr.isatty()), cfg)
        _check_drive(prov, cfg)
        withheld = {}
        return _said(estimate_to(log, out, cfg, full=full, provenance=prov, label=f"{sensors} (imported)",
                                 withheld=withheld, map_prior=map_prior), withheld)


def _with_torque_constant(prov, cfg):
    """The provenance once a torque constant is given: a current of unknown scale is no longer a reason to
    withhold K (the constant is the scale); any other reason still is."""
    if prov is None or cfg.torque_constant == 1.0 or prov.wheel_torque != "current_unknown_scale":
        return prov
    import dataclasses

    reasons = [r for r in prov.reasons if "current with an unknown scale" not in r]
    click.echo(f"torque constant {cfg.torque_constant:g} given: the log's motor currents are taken as "
               f"{cfg.torque_constant:g} N m per unit", err=True)
    return dataclasses.replace(prov, wheel_torque="current_scaled", reasons=reasons, identifiable=not reasons)


def _check_drive(prov, cfg) -> None:
    if prov is not None and prov.drive != cfg.vehicle.drive:
        click.echo(f"WARNING: the log's wheels are {prov.drive} (one speed and torque per side) but the vehicle's "
                   f"drive is {cfg.vehicle.drive}: give --vehicle with \"drive\": \"{prov.drive}\"", err=True)


def _said(summary, withheld: dict):
    if withheld:
        click.echo("K withheld on every record (the log cannot identify it); the chain's own statuses were "
                   + ", ".join(f"{k} {v}" for k, v in sorted(withheld.items())), err=True)
    return summary


COMMANDS = [import_cmd]
