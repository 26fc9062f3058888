"""Physics subcommands: ``soilocp ocp``, ``soilocp curves``, ``soilocp calibrate``.

Pure library only (no Zenoh).  Bad input ends with a click usage error (exit code 2) naming the
option, never a traceback.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from soilocp.commands.errors import BadInput

from soilocp.model.constants import ModelConstants, load_constants


def _constants(path: str | None) -> ModelConstants:
    try:
        return load_constants(path)
    except ValueError as exc:  # pydantic's ValidationError is a ValueError too
        raise click.BadParameter(str(exc), param_hint="'--constants'") from None


def _soil_k(text: str, option: str) -> tuple[str, float]:
    """Parse NAME=K (e.g. sand=50) with K finite and > 0."""
    name, sep, value = text.partition("=")
    name = name.strip()
    try:
        k = float(value) if sep else float("nan")
    except ValueError:
        k = float("nan")
    if not name or not (math.isfinite(k) and k > 0):
        raise click.BadParameter(f"expected SOIL=K with a finite K > 0 (e.g. sand=50), got {text!r}", param_hint=option)
    return name, k


constants_option = click.option(
    "--constants",
    "constants_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="Model constants JSON (from `soilocp calibrate`); default: the paper's constants.",
)


# ------------------------------------------------------------------------------------- ocp
@click.command("ocp", short_help="mu_T, S_T, S_E for soil strength K (eqs. 7-10).")
@click.option(
    "--soil-strength",
    "-k",
    "soil_strength",
    type=float,
    multiple=True,
    metavar="K",
    help="Soil strength K > 0 (repeat for several).",
)
@click.option("--table", is_flag=True, help="Also list the reference soils of the constants (sand, gravel, ...).")
@constants_option
@click.option("--json", "as_json", is_flag=True, help="JSON output: keys soil_strength, mu_T, S_T, S_E.")
def ocp(soil_strength: tuple[float, ...], table: bool, constants_file: str | None, as_json: bool) -> None:
    """Optimal control parameters for soil strength K: mu_T (eq. 8), S_T (eq. 7, corrected), S_E (eq. 10).

    With one K and --json, prints one JSON object; with several K (or --table), a JSON list.
    """
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from soilocp.model.ocp import ocp_from_soil_strength

    for k in soil_strength:
        if not (math.isfinite(k) and k > 0):
            raise click.BadParameter(f"soil strength K must be a finite number > 0, got {k!r}", param_hint="'--soil-strength'")
    if not soil_strength and not table:
        raise click.UsageError("give at least one --soil-strength K, or --table for the reference soils")
    c = _constants(constants_file)
    rows: list[tuple[str, float]] = [("", k) for k in soil_strength]
    if table:
        rows += list(c.soils.items())
    results = []
    for name, k in rows:
        try:
            r = ocp_from_soil_strength(k, c)
        except ValueError as exc:  # e.g. K so small that eq. 7's argument underflows
            raise click.BadParameter(f"K = {k!r}: {exc}", param_hint="'--soil-strength'") from None
        if not all(math.isfinite(v) for v in r.as_dict().values()):
            raise click.BadParameter(
                f"K = {k!r} is outside the model's numeric range (OCPs {r.as_dict()})", param_hint="'--soil-strength'"
            )
        results.append((name, r))
    if as_json:
        dicts = [r.as_dict() for _, r in results]
        click.echo(json.dumps(dicts[0] if len(dicts) == 1 and not table else dicts))
        return
    t = Table(title="Optimal control parameters" + (f" ({escape(constants_file)})" if constants_file else " (paper constants)"))
    if table:
        t.add_column("soil")
    for col in ("K", "mu_T (eq. 8)", "S_T (eq. 7)", "S_E (eq. 10)"):
        t.add_column(col, justify="right")
    for name, r in results:
        cells = [f"{r.soil_strength:g}", f"{r.mu_T:.4f}", f"{r.S_T:.4f}", f"{r.S_E:.4f}"]
        t.add_row(*([escape(name) or "-"] if table else []), *cells)
    Console(width=100).print(t)


# ----------------------------------------------------------------------------------- curves
@click.command("curves", short_help="PNGs of the paper's Figs. 3-5 (traction, efficiency, OCPs vs K).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Directory for the PNG files.")
@constants_option
@click.option("--soil", "soils", multiple=True, help="Soil of the constants to draw (repeat); default: sand, gravel, EST, grass.")
def curves(out_dir: str, constants_file: str | None, soils: tuple[str, ...]) -> None:
    """Write the paper's Figs. 3 (traction-slip), 4 (tractive efficiency) and 5 (OCPs vs K) as PNGs."""
    from soilocp.analysis.curves import write_figures

    c = _constants(constants_file)
    try:
        paths = write_figures(out_dir, c, list(soils) or None)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--soil' / '--out'") from None
    for name, p in paths.items():
        click.echo(f"{name}: {p}")


# -------------------------------------------------------------------------------- calibrate
@click.command("calibrate", short_help="Fit C1..C6 to testbed data (paper §2.2) or, --from-drive, to a robot's drives.")
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--out", "out_file", type=click.Path(dir_okay=False), required=True,
              help="Constants JSON to write (with --from-drive: the wheel's calibration file).")
@click.option("--from-drive", "from_drive", is_flag=True,
              help="DATA are sensor logs (JSON Lines) of the robot's own drives: fit its wheels' curve (needs --vehicle).")
@click.option("--vehicle", "vehicle_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="--from-drive: the robot's vehicle JSON.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="--from-drive: the estimator's settings (as soilocp estimate --config).")
@click.option(
    "--anchor",
    default=None,
    metavar="SOIL=K",
    help="Soil whose K is fixed to set the scale of K (default: sand=50, or the first data soil with a reference K).",
)
@click.option("--fix-k", "fix_k", multiple=True, metavar="SOIL=K", help="Also fix this soil's K (repeat).")
@click.option("--constants", "initial_file", type=click.Path(dir_okay=False), default=None, help="Initial constants (start values, C4, bridge, alpha/beta fallback).")
@click.option("--no-efficiency", is_flag=True, help="Do not refit S_E's alpha, beta (eq. 10); keep the initial ones.")
def calibrate(data: tuple[str, ...], out_file: str, from_drive: bool, vehicle_path: str | None, config_path: str | None,
              anchor: str | None, fix_k: tuple[str, ...], initial_file: str | None, no_efficiency: bool) -> None:
    """Fit C1..C6 and K per soil to testbed DATA (CSV) by nonlinear least squares (paper §2.2), or with
    --from-drive to the robot's own drives (sensor logs).

    Testbed DATA columns: slip, soil, and mu (F_DP/W) or drawbar_pull + normal_load [N]; optional
    gross_traction (or gross_force [N]) lets C4 be fitted.  K is identifiable only up to a common
    scale, so one soil's K is fixed (the anchor).  Then S_E's alpha, beta (eq. 10) are refitted
    through the tractive-efficiency peaks (eq. 9) of the fitted model, if it has them.

    From drives: the estimator's own (slip, net traction) pairs, split into soils where their curve
    changes, fitted by one curve with a K per soil (docs/calibration.md).  Writes a calibration file
    (constants with their bands and correlations, what could not be fitted and why, and how well the
    curve predicts held-out parts of the drives) that the vehicle file names as its traction_curve.
    """
    if from_drive:
        return _calibrate_from_drives(data, out_file, vehicle_path, config_path)
    if len(data) != 1 or vehicle_path or config_path:
        raise click.UsageError("testbed calibration takes one DATA file and no --vehicle/--config; for sensor logs of "
                               "drives add --from-drive")
    data = data[0]
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from soilocp.analysis.calibration import fit_constants
    from soilocp.analysis.testbed import read_testbed_csv
    from soilocp.model.constants import save_constants

    initial = _constants(initial_file)
    anchor_kv = _soil_k(anchor, "'--anchor'") if anchor else None
    fixed = dict(_soil_k(x, "'--fix-k'") for x in fix_k)
    try:
        d = read_testbed_csv(data)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'DATA'") from None
    try:
        res = fit_constants(d, anchor=anchor_kv, fixed_k=fixed, initial=initial, fit_efficiency=not no_efficiency)
    except ValueError as exc:
        raise click.UsageError(f"calibration failed: {exc}") from None
    save_constants(res.constants, out_file)

    con = Console(width=110)
    t = Table(title=f"Calibration of {escape(data)}: {len(d)} rows, {len(d.soils)} soils, rms residual {res.rms:.4g}")
    for col, just in (("parameter", "left"), ("value", "right"), ("± std error", "right"), ("status", "left")):
        t.add_column(col, justify=just)
    for p in res.parameters:
        t.add_row(escape(p.name), f"{p.value:.6g}", "-" if p.std_error is None else f"{p.std_error:.3g}", p.status)
    eff = res.efficiency
    t.add_row("alpha (eq. 10)", f"{eff.alpha:.6g}", "-", "fitted" if eff.fitted else "kept")
    t.add_row("beta (eq. 10)", f"{eff.beta:.6g}", "-", "fitted" if eff.fitted else "kept")
    con.print(t)
    for soil, sp in eff.peaks.items():
        con.print(f"  eq. 9 peak {soil}: " + (f"S = {sp:.4f}" if sp is not None else f"none ({eff.reasons.get(soil, '')})"), markup=False)
    for note in res.notes:
        con.print(f"note: {note}", markup=False)
    con.print(f"wrote {out_file}", markup=False)


def _calibrate_from_drives(logs: tuple[str, ...], out_file: str, vehicle_path: str | None, config_path: str | None) -> None:
    """``soilocp calibrate --from-drive``: the wheel's calibration file from sensor logs (module doc of
    soilocp.analysis.drive_calibration)."""
    from soilocp.analysis.drive_calibration import calibrate_from_drives
    from soilocp.estimation.config import load_pipeline_config
    from soilocp.model.wheel_curve import save_calibration

    if vehicle_path is None:
        raise click.UsageError("--from-drive needs --vehicle: the robot's vehicle JSON (mass, geometry, wheel radius), "
                               "without which the traction it reads is another robot's")
    for log in logs:
        if not Path(log).is_file():
            raise click.BadParameter(f"no such file: {log}", param_hint="'DATA'")
    try:
        cfg = load_pipeline_config(config_path, vehicle=vehicle_path)
        fit = calibrate_from_drives([(log, Path(log).open()) for log in logs], cfg)
    except ValueError as exc:
        raise click.UsageError(f"calibration failed: {exc}") from None
    save_calibration(fit.calibration, out_file)
    for m in fit.messages:
        click.echo(m)
    from soilocp.commands.calibration_report import echo_calibration

    echo_calibration(fit.calibration, out_file)


COMMANDS = [ocp, curves, calibrate]


# -------------------------------------------------------------------------------- calibrate-torque
@click.command("calibrate-torque", short_help="Fit the torque constant k (N m per unit of the torque column) of a log.")
@click.argument("log", type=click.Path(exists=True, dir_okay=False))
@click.option("--vehicle", "vehicle_path", type=click.Path(exists=True, dir_okay=False), required=True,
              help="Vehicle JSON (mass, wheel radius and inertia enter the force balance).")
@click.option("--accel", type=click.Choice(["imu", "ground_speed"]), default="imu", show_default=True,
              help="Acceleration from the IMU's f_x, or from the ground speed's change + pitch's gravity.")
@click.option("--window", type=float, default=None, help="Averaging window, s (default: the fit's own, shorter than the online torque scale's).")
@click.option("--min-speed", type=float, default=None,
              help="Windows slower than this (m/s) are skipped (default: the online torque scale's min_speed).")
@click.option("--max-yaw-rate", type=float, default=None,
              help="Windows turning faster (rad/s) are skipped (default: the online torque scale's max_yaw_rate).")
@click.option("--saturation", type=float, default=None, help="|logged torque| per wheel at which it clips.")
@click.option("--scale", "old_scale", type=float, default=None,
              help="The effort_scale / current_to_torque the log was imported with (to print the new one).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write the result as JSON.")
def calibrate_torque(log, vehicle_path, accel, window, min_speed, max_yaw_rate, saturation, old_scale, json_out):
    """Estimate the constant k that turns LOG's torque column (e.g. a motor current) into wheel
    torque, from the longitudinal force balance m f_x + I_w sum(omega_dot)/R = k sum(T)/R - F_MR
    (docs/method.md §15), on windows where the robot drives straight, forward,
    unsaturated.  LOG is a sensor log (JSON Lines, e.g. from soilocp import).  Says
    not_determined, and why, when the log cannot fix k.
    """
    from soilocp.analysis.torque_constant import TorqueSelection, fit_torque_constant, summary_lines
    from soilocp.model.files import read_jsonl
    from soilocp.model.vehicle import load_vehicle

    try:
        vehicle = load_vehicle(vehicle_path)
        given = dict(window=window, min_speed=min_speed, max_yaw_rate=max_yaw_rate)
        sel = TorqueSelection(saturation=saturation, accel=accel, **{k: v for k, v in given.items() if v is not None})
        fit = fit_torque_constant(read_jsonl(log), vehicle, sel)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    for line in summary_lines(fit, old_scale):
        click.echo(line)
    if fit.status != "ok":
        click.echo("what to drive: straight (yaw rate under --max-yaw-rate), forward above --min-speed, and accelerate "
                   "and brake firmly (|f_x| 0.5 m/s^2 or more) several times, e.g. 0 -> 1.5 m/s in 2 s and back; then "
                   "soilocp estimate LOG --torque-constant FILE.json (docs/from-no-estimate-to-ok.md)")
    if json_out:
        Path(json_out).write_text(json.dumps(fit.as_dict(), indent=2))


COMMANDS.append(calibrate_torque)


from soilocp.commands.calibrate_drive import calibrate_drive  # noqa: E402  (the command body imports lazily)

COMMANDS.append(calibrate_drive)
