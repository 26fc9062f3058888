"""``soilocp calibrate-drive``: drive the robot through the calibration protocol, then fit and write its
calibration file (docs/calibration.md, "The calibration drive").

Exit status: 0 when the file is written; 1 when the drive could not be done (the robot does not answer, stops,
does not follow) or showed too little to fit a curve (the message says what to change); 2 on bad options.
Nothing is written unless the curve was fitted: a vehicle file naming a calibration makes its OCPs ``ok``-able.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import click

from soilocp.commands.calibration_report import echo_calibration


class DriveError(click.ClickException):
    """Exit status 1 with the message: the drive failed or showed too little."""

    exit_code = 1


@click.command("calibrate-drive", short_help="Drive the robot through a <= 60 s calibration protocol, fit its wheels "
               "and force balance, write the calibration file.")
@click.option("--vehicle", "vehicle_path", type=click.Path(exists=True, dir_okay=False), required=True,
              help="The robot's vehicle JSON (mass, geometry, wheel radius).")
@click.option("--out", "out_file", type=click.Path(dir_okay=False), required=True,
              help="Calibration file to write; name it in the vehicle file as \"traction_curve\".")
@click.option("--vehicle-id", default="rover1", show_default=True, help="The robot's vehicle id (its Zenoh keys).")
@click.option("--connect", multiple=True, metavar="ENDPOINT",
              help="Zenoh router the robot's samples reach (repeatable); default tcp/127.0.0.1:7447.")
@click.option("--max-speed", type=float, default=1.0, show_default=True,
              help="m/s: no speed set-point exceeds it (swings 0.25-1.0 x, sweeps at 0.625 x).")
@click.option("--max-slip", type=float, default=0.6, show_default=True,
              help="Top of the slip sweep: past the traction peak of the robot's soil, within what you allow.")
@click.option("--duration", type=float, default=60.0, show_default=True, help="Seconds of driving, at most 60.")
@click.option("--known", type=click.Choice(["torque", "mass"]), default="torque", show_default=True,
              help="Which one the force balance may take as known: torque (the log's torques are N m: fit the payload) "
                   "or mass (the vehicle file's mass is right: fit the torque constant).")
@click.option("--answer-timeout", type=float, default=10.0, show_default=True,
              help="Seconds to wait for the robot's first sample.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="The estimator's settings (as soilocp estimate --config).")
@click.option("--save-log", type=click.Path(dir_okay=False), default=None,
              help="Also write the recorded sensor samples (JSON Lines) here, e.g. for soilocp calibrate --from-drive.")
@click.option("--ros2", is_flag=True, help="Also publish the speed set-point as geometry_msgs/Twist on cmd_vel (rmw_zenoh).")
@click.option("--ros2-connect", multiple=True, metavar="ENDPOINT",
              help="--ros2: the robot's rmw_zenoh router; default the --connect endpoint(s).")
@click.option("--ros2-topic", default="/cmd_vel", show_default=True, help="--ros2: the velocity command topic.")
@click.option("--ros2-domain", type=int, default=None, help="--ros2: ROS domain id; default $ROS_DOMAIN_ID or 0.")
def calibrate_drive(vehicle_path, out_file, vehicle_id, connect, max_speed, max_slip, duration, known, answer_timeout,
                    config_path, save_log, ros2, ros2_connect, ros2_topic, ros2_domain) -> None:
    """Drive the robot VEHICLE-ID through the calibration protocol over Zenoh: accelerate and brake, then a
    front-axle slip sweep from 0.05 to --max-slip at constant speed, twice, within --max-speed and --duration
    (at most 60 s).  It records the sensor samples the robot publishes on soilocp/<vid>/sensors/raw, then fits
    the wheels' traction curve (as soilocp calibrate --from-drive), the force balance's payload or torque
    constant and the rolling resistance, and writes the calibration file with each value's band, or the reason
    it could not be fitted.

    The robot follows soilocp.schemas.messages.DriveSetpoint on soilocp/<vid>/control/drive (and stops by itself when
    they stop); with --ros2 the speed also goes out as cmd_vel.  The simulated robot:
    soilocp service vehicle --scenario NAME --follow-drive [--tyre slow].
    """
    from soilocp.services.control.calibrate_drive import DriveFailed, run_drive
    from soilocp.services.runtime.settings import check_endpoint
    from soilocp.analysis.calibration_drive_fit import DriveTooLittle, fit_drive
    from soilocp.control.calibration_drive import DriveProtocol
    from soilocp.estimation.config import load_pipeline_config
    from soilocp.model.wheel_curve import save_calibration
    from soilocp.schemas import keys

    try:
        keys.check_vehicle_id(vehicle_id)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--vehicle-id'") from None
    try:
        protocol = DriveProtocol(duration=duration, max_speed=max_speed, max_slip=max_slip)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--duration' / '--max-speed' / '--max-slip'") from None
    try:
        eps = [check_endpoint(ep) for ep in connect] or ["tcp/127.0.0.1:7447"]
        ros2_eps = [check_endpoint(ep) for ep in ros2_connect] or eps
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--connect' / '--ros2-connect'") from None
    if (ros2_connect or ros2_domain is not None) and not ros2:
        raise click.UsageError("--ros2-connect and --ros2-domain need --ros2")
    try:
        cfg = load_pipeline_config(config_path, vehicle=vehicle_path)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--vehicle' / '--config'") from None
    ros2_opts = None
    if ros2:
        import os

        domain = ros2_domain if ros2_domain is not None else int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
        ros2_opts = {"connect": ros2_eps, "topic": ros2_topic, "domain_id": domain}

    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        rec = run_drive(vehicle_id, eps, protocol, answer_timeout_s=answer_timeout, ros2=ros2_opts,
                        progress=lambda m: click.echo(m), stop=stop)
    except DriveFailed as exc:
        raise DriveError(str(exc)) from None
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    click.echo(f"drive done: {len(rec.lines)} samples recorded, {rec.setpoints} set-points sent; fitting")
    if save_log:
        Path(save_log).write_text("".join(line.rstrip("\n") + "\n" for line in rec.lines))
        click.echo(f"wrote the samples to {save_log}")
    proto = {"duration": protocol.duration, "max_speed": protocol.max_speed, "max_slip": protocol.max_slip,
             "min_slip": protocol.min_slip, "phases": [[p, a, b] for p, a, b in protocol.phases()]}
    try:
        res = fit_drive(rec.lines, rec.phases, cfg, name=f"calibration drive of {vehicle_id}", known=known,
                        max_slip=max_slip, protocol=proto)
    except DriveTooLittle as exc:
        raise DriveError(f"the drive showed too little; nothing was written: {exc}") from None
    cal = res.calibration
    save_calibration(cal, out_file)
    for m in res.messages:
        click.echo(m)
    echo_calibration(cal, out_file)
