"""Console commands of the services area: ``service``, ``router``, ``run``, ``schemas``.

Zenoh and the physics are imported inside the command bodies, so ``soilocp --help`` stays fast.
"""

from __future__ import annotations

import os
import sys

import click

from soilocp.services.router import router_cmd
from soilocp.services.runtime.process import exit_now as _exit_now, fatal as _fatal
from soilocp.services.stages.graph import ALL_SERVICES, PIPELINE_SERVICES


def _service_class(name: str):
    """The class that runs service ``name``: a pipeline row (``soilocp.services.stages.graph``), or one of
    the two other processes."""
    if name == "controller":
        from soilocp.services.control.controller import ControllerService

        return ControllerService
    if name == "vehicle":
        from soilocp.services.io.sensor_source import VehicleService

        return VehicleService
    if name == "ros2-in":
        from soilocp.services.ros2.ros2_in import Ros2InService

        return Ros2InService
    if name == "ros2-out":
        from soilocp.services.ros2.ros2_out import Ros2OutService

        return Ros2OutService
    from soilocp.services.stages.registry import stage_service

    return stage_service(name)


@click.command("service")
@click.argument("name", type=click.Choice(ALL_SERVICES))
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="Service config file (JSON); env SOILOCP_CONFIG.")
@click.option("--vehicle-id", "vehicle_ids", multiple=True, help="Vehicle id (repeatable); env SOILOCP_VEHICLE_ID.")
@click.option("--connect", multiple=True, help="Zenoh endpoint to connect to (repeatable); env SOILOCP_CONNECT.")
@click.option("--listen", multiple=True, help="Zenoh endpoint to listen on (repeatable, peer mode); env SOILOCP_LISTEN.")
@click.option("--mode", type=click.Choice(["client", "peer"]), help="Zenoh mode; env SOILOCP_MODE (default client).")
@click.option("--log-level", type=click.Choice(["debug", "info", "warning", "error"]), help="env SOILOCP_LOG_LEVEL.")
@click.option("--stale-timeout", type=float, help="OCP: stale after this many seconds without input; env SOILOCP_STALE_TIMEOUT.")
@click.option("--pipeline-config", type=click.Path(dir_okay=False), help="Physics PipelineConfig file (JSON).")
@click.option("--scenario", help="vehicle: simulator scenario to publish in real time.")
@click.option("--replay", type=click.Path(dir_okay=False), help="vehicle: sensor log (JSON Lines) to replay.")
@click.option("--speed", type=float, default=1.0, show_default=True, help="vehicle: replay speed factor (0 = as fast as possible).")
@click.option("--duration", type=float, help="vehicle: seconds of scenario / log to publish.")
@click.option("--rate", type=float, default=100.0, show_default=True, help="vehicle: scenario sample rate, Hz.")
@click.option("--seed", type=int, default=0, show_default=True, help="vehicle: scenario noise seed.")
@click.option("--wait-timeout", type=float, default=20.0, show_default=True,
              help="vehicle: wait at most this long for the pipeline services before publishing (0: don't wait).")
@click.option("--control", metavar="CONTROLLER",
              help="controller: the set-point policy (ocp_traction, ocp_efficiency, fixed_<slip>, speed); "
                   "vehicle: follow that controller's set-points (closed loop, --scenario only).")
@click.option("--follow-drive", is_flag=True,
              help="vehicle: follow a calibration drive's set-points (soilocp calibrate-drive) on --scenario's terrain; "
                   "publishes at once, stands still until set-points arrive.")
@click.option("--tyre", metavar="slow|grippy|vector|FILE.json",
              help="vehicle (--scenario): the simulated robot's tyre (its true traction constants; default: the paper's).")
@click.option("--ros2-map", type=click.Path(dir_okay=False), help="ros2-in: the topic map file (as for soilocp import).")
@click.option("--ros2-connect", multiple=True,
              help="ros2-in / ros2-out: the robot's Zenoh router (rmw_zenohd), repeatable; default tcp/127.0.0.1:7447.")
@click.option("--ros2-domain", type=int, help="ros2-in / ros2-out: ROS domain id; default $ROS_DOMAIN_ID or 0.")
def service_cmd(name, config_path, vehicle_ids, connect, listen, mode, log_level, stale_timeout, pipeline_config,
                scenario, replay, speed, duration, rate, seed, wait_timeout, control, follow_drive, tyre, ros2_map,
                ros2_connect, ros2_domain) -> None:
    """Run one service NAME of the pipeline (or the synthetic vehicle) until SIGINT/SIGTERM."""
    from soilocp.services.runtime.config import ConfigError, load_service_config
    from soilocp.services.runtime.service import run_service

    prefix = f"soilocp service {name}"
    overrides = dict(vehicle_ids=vehicle_ids, connect=connect, listen=listen, mode=mode, log_level=log_level,
                     stale_timeout_s=stale_timeout, pipeline_config=pipeline_config)
    kwargs = {}
    try:
        cfg = load_service_config(name, config_path=config_path, overrides=overrides)
        if name == "vehicle":
            from soilocp.services.io.sensor_source import replay_source, scenario_source

            if (scenario is None) == (replay is None):
                raise ConfigError("give exactly one of --scenario NAME or --replay FILE")
            wait = PIPELINE_SERVICES
            inbox = None
            if replay is not None:
                if control or follow_drive or tyre:
                    raise ConfigError("--control, --follow-drive and --tyre need --scenario (a replayed log cannot "
                                      "follow set-points or change its tyre)")
                source = replay_source(replay, duration)
                describe = f"replay {replay}"
            elif follow_drive:
                from soilocp.services.control.vehicle_drive import DriveInbox, drive_source

                if control:
                    raise ConfigError("--follow-drive and --control are two ways to drive: give one")
                if rate <= 0:
                    raise ConfigError(f"--rate {rate!r}: must be > 0 Hz")
                inbox = DriveInbox(cfg.vehicle_id)
                source = drive_source(scenario, cfg.vehicle_id, inbox, duration=duration, rate=rate, seed=seed, tyre=tyre)
                describe = f"scenario {scenario}, following calibration-drive set-points" + (f", tyre {tyre}" if tyre else "")
                wait = ()  # a robot publishes its sensors whether a pipeline listens or not
            elif tyre:
                raise ConfigError("--tyre needs --follow-drive (the open-loop scenarios drive the paper's wheel)")
            elif control:
                from soilocp.services.control.vehicle_control import SetpointInbox, controlled_source

                if rate <= 0:
                    raise ConfigError(f"--rate {rate!r}: must be > 0 Hz")
                inbox = SetpointInbox(cfg.vehicle_id, control, cfg.stale_timeout_s)
                source = controlled_source(scenario, cfg.vehicle_id, inbox, duration=duration, rate=rate, seed=seed)
                describe = f"scenario {scenario}, closed loop under {control}"
                wait = PIPELINE_SERVICES + ("controller",)
            else:
                if rate <= 0:
                    raise ConfigError(f"--rate {rate!r}: must be > 0 Hz")
                source = scenario_source(scenario, cfg.vehicle_id, duration=duration, rate=rate, seed=seed)
                describe = f"scenario {scenario}"
            kwargs = dict(source=source, speed=speed, describe=describe, inbox=inbox,
                          wait_for=wait if wait_timeout > 0 else (), wait_timeout_s=wait_timeout)
        elif name in ("ros2-in", "ros2-out"):
            from soilocp.services.runtime.config import check_endpoint

            eps = [check_endpoint(ep) for ep in ros2_connect] or [ROS2_DEFAULT_ENDPOINT]
            kwargs = dict(ros2_connect=eps, domain_id=_ros_domain(ros2_domain))
            if name == "ros2-in":
                from soilocp.ingest import load_map

                if ros2_map is None:
                    raise ConfigError("ros2-in needs --ros2-map MAP.yaml (the topic map file)")
                kwargs.update(tmap=load_map(ros2_map), wait_for=PIPELINE_SERVICES if wait_timeout > 0 else (),
                              wait_timeout_s=wait_timeout)
            elif ros2_map is not None:
                raise ConfigError("--ros2-map is an option of the ros2-in service only")
        elif scenario or replay or follow_drive or tyre:
            raise ConfigError("--scenario/--replay/--follow-drive/--tyre are options of the vehicle service only")
        elif name == "controller":
            kwargs = dict(control=control or "ocp_traction")
        elif control:
            raise ConfigError("--control is an option of the controller and vehicle services only")
        _exit_now(run_service(_service_class(name), cfg, **kwargs))
    except ConfigError as exc:
        _fatal(prefix, str(exc))
    except ValueError as exc:
        _fatal(prefix, str(exc))


#: rmw_zenoh's router (rmw_zenohd) listens here by default
ROS2_DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def _ros_domain(value) -> int:
    """--ros2-domain, else $ROS_DOMAIN_ID (as ROS 2 itself reads it), else 0."""
    if value is None:
        env = os.environ.get("ROS_DOMAIN_ID", "").strip()
        try:
            value = int(env) if env else 0
        except ValueError:
            raise ValueError(f"ROS_DOMAIN_ID={env!r}: not an integer") from None
    if not 0 <= value <= 232:
        raise ValueError(f"ROS domain id {value}: must be 0..232")
    return value


@click.command("run")
@click.option("--synthetic", "scenario", metavar="SCENARIO", help="Drive a simulator scenario in real time.")
@click.option("--replay", type=click.Path(exists=True), help="Replay a sensor log (or, with --map, a ROS 2 bag) instead.")
@click.option("--map", "map_path", type=click.Path(exists=True, dir_okay=False),
              help="--replay is a ROS 2 bag: its map file (soilocp import); the map's vehicle_id is used.")
@click.option("--speed", type=float, default=1.0, show_default=True, help="Replay speed factor (0 = as fast as possible).")
@click.option("--vehicle-id", default="rover1", show_default=True,
              help="The vehicle's id; with --replay LOG default the log's own vehicle_id.")
@click.option("--duration", type=float, help="Stop after this many seconds of driving (default: when the source ends).")
@click.option("--listen", multiple=True, help="Router endpoint(s); default tcp/127.0.0.1:7447.")
@click.option("--pipeline-config", type=click.Path(exists=True, dir_okay=False), help="Physics PipelineConfig file.")
@click.option("--vehicle", "vehicle_path", type=click.Path(exists=True, dir_okay=False),
              help="Vehicle parameters JSON (as soilocp estimate --vehicle); over --pipeline-config's vehicle.")
@click.option("--torque-constant", metavar="K|FILE.json",
              help="N m per unit of the log's wheel_torque, or the JSON of soilocp calibrate-torque --json "
                   "(as soilocp estimate --torque-constant).")
@click.option("--stale-timeout", type=float, default=0.5, show_default=True,
              help="OCP publisher: stale after this many seconds without input.")
@click.option("--seed", type=int, default=0, show_default=True, help="--synthetic: seed of the sensor noise.")
@click.option("--log-dir", type=click.Path(file_okay=False), help="Where each process's log goes (default: a new temp dir).")
@click.option("--plain", is_flag=True, help="Periodic plain lines instead of the live table (automatic without a TTY).")
@click.option("--control", metavar="CONTROLLER",
              help="Close the loop: run the controller service with this policy (ocp_traction, ocp_efficiency, "
                   "fixed_<slip>, speed); the synthetic vehicle follows its slip set-points.")
@click.option("--foxglove", "foxglove_addr", is_flag=False, flag_value="127.0.0.1:8765", metavar="[HOST:PORT]",
              help="Serve the vehicle's estimates and sensors to Foxglove on a WebSocket (default 127.0.0.1:8765; "
                   "port 0: any free one).")
@click.option("--ros2", "ros2_out", is_flag=True,
              help="Also publish the estimates as ROS 2 topics (rmw_zenoh) on the robot's router: "
                   "/soilocp/<vid>/estimate and /diagnostics (docs/ros2.md).")
@click.option("--ros2-in", "ros2_in", metavar="MAP.yaml", type=click.Path(exists=True, dir_okay=False),
              help="Take the sensors from the robot's ROS 2 topics (rmw_zenoh), mapped as for soilocp import; "
                   "the map's vehicle_id is used.")
@click.option("--ros2-connect", multiple=True, metavar="ENDPOINT",
              help="The robot's Zenoh router (rmw_zenohd) for --ros2 / --ros2-in; default tcp/127.0.0.1:7447 "
                   "(then give --listen another port for soilocp's own router).")
@click.option("--ros2-domain", type=int, help="ROS domain id for --ros2 / --ros2-in; default $ROS_DOMAIN_ID or 0.")
@click.option("--restart", is_flag=True, help="Restart a router or service that dies (at most 5 times a minute each) "
                                              "instead of stopping the run; `soilocp fleet status` shows the restarts.")
@click.option("--map-store", metavar="URL",
              help="Also run the fleet soil map service on this store (sqlite:PATH or postgresql://user@host/db), "
                   "fed by the vehicle's soil estimates (they carry places when the vehicle has a pose: "
                   "SOILOCP_START_POSE for --synthetic; docs/map.md).")
@click.option("--map-id", default="fleet", show_default=True, help="With --map-store: the map's id (keys soilmap/<id>/...).")
def run_cmd(scenario, replay, map_path, speed, vehicle_id, duration, listen, pipeline_config, vehicle_path,
            torque_constant, stale_timeout, seed, log_dir, plain, control, foxglove_addr, ros2_out, ros2_in, ros2_connect,
            ros2_domain, restart=False, map_store=None, map_id="fleet") -> None:
    """Start the router, the five services and a source as separate processes; show live OCPs.

    Ends with the OCP records per status and reason code, each with its next step, and says what any
    service dropped and why.  Exits non-zero at once, with the service's own message, when a service
    cannot start; with --restart a router or service that dies is restarted instead."""
    from soilocp.schemas import keys

    from soilocp.services.supervisor.run import RunOptions, run_system

    if sum(x is not None for x in (scenario, replay, ros2_in)) != 1:
        _fatal("soilocp run", "give exactly one of --synthetic SCENARIO, --replay FILE or --ros2-in MAP.yaml")
    ros2_eps: list[str] = []
    if ros2_out or ros2_in:
        try:
            ros2_eps = _ros2_endpoints(ros2_connect, listen)
            ros2_domain = _ros_domain(ros2_domain)
            if ros2_in is not None:
                from soilocp.ingest import load_map

                vehicle_id = load_map(ros2_in).vehicle_id
                if control is not None:
                    raise ValueError("--control needs --synthetic SCENARIO (the robot's topics cannot follow set-points)")
        except ValueError as exc:
            _fatal("soilocp run", str(exc))
    elif ros2_connect or ros2_domain is not None:
        _fatal("soilocp run", "--ros2-connect / --ros2-domain need --ros2 or --ros2-in")
    try:
        keys.check_vehicle_id(vehicle_id)
        if control is not None:
            from soilocp.control import make_policy
            from soilocp.control.rig import RIG_SCENARIOS

            make_policy(control)  # ValueError listing the controllers
            if scenario is None:
                raise ValueError("--control needs --synthetic SCENARIO (a replayed log cannot follow set-points)")
        if scenario is not None and not (control is not None and scenario in RIG_SCENARIOS):
            from soilocp.sim.scenarios import get_scenario

            get_scenario(scenario)  # ValueError listing the known scenarios
        if duration is not None and duration <= 0:
            raise ValueError(f"--duration {duration!r}: must be > 0 s")
        keys.check_map_id(map_id)
        if map_store is not None and not map_store.strip():
            raise ValueError("--map-store: empty; give sqlite:PATH or postgresql://user@host/db")
        if speed < 0:
            raise ValueError(f"--speed {speed!r}: must be >= 0")
        if foxglove_addr is not None:
            from soilocp.services.io.foxglove_live import parse_address

            parse_address(foxglove_addr)
    except ValueError as exc:
        _fatal("soilocp run", str(exc))
    if map_path is not None:
        replay, vehicle_id = _import_for_replay(replay, map_path, log_dir)
    elif replay is not None and os.path.isdir(replay):
        _fatal("soilocp run", f"--replay {replay}: a directory (ROS 2 bag?) needs --map MAP.yaml")
    elif replay is not None:
        explicit = click.get_current_context().get_parameter_source("vehicle_id") != click.core.ParameterSource.DEFAULT
        vehicle_id = _replay_vehicle_id(replay, vehicle_id, explicit)
    if pipeline_config or vehicle_path or torque_constant:
        log_dir = log_dir or _new_log_dir()
        pipeline_config = _run_pipeline_config(pipeline_config, vehicle_path, torque_constant, log_dir)
    opts = RunOptions(scenario=scenario, replay=replay, speed=speed, vehicle_id=vehicle_id, duration=duration,
                      listen=list(listen) or None, pipeline_config=pipeline_config, stale_timeout=stale_timeout,
                      seed=seed, log_dir=log_dir, plain=plain, control=control, foxglove=foxglove_addr,
                      ros2_out=ros2_out, ros2_in=ros2_in, ros2_connect=ros2_eps, ros2_domain=ros2_domain,
                      restart=restart, map_store=map_store, map_id=map_id)
    try:
        code = run_system(opts)
    except ValueError as exc:  # the Foxglove port is taken: nothing was started
        _fatal("soilocp run", str(exc))
    sys.exit(code)


def _new_log_dir() -> str:
    import tempfile

    return tempfile.mkdtemp(prefix="soilocp-run-")


def _replay_vehicle_id(log: str, given: str, explicit: bool) -> str:
    """The vehicle id to run a replay of ``log`` under: the log's own (its first samples' vehicle_id).
    ``given`` (``explicit``: the user's --vehicle-id) must match it: the services serve one id, and every
    sample of another would be rejected (vehicle_mismatch), leaving no estimate."""
    import json

    ids: list[str] = []
    try:
        with open(log, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if len(ids) >= 50:
                    break
                if not line.strip():
                    continue
                try:
                    vid = json.loads(line).get("vehicle_id")
                except (ValueError, AttributeError):
                    continue
                if isinstance(vid, str):
                    ids.append(vid)
    except OSError as exc:
        _fatal("soilocp run", f"--replay {log}: cannot read it: {exc}")
    found = sorted(set(ids))
    if not found:
        if explicit:
            return given
        _fatal("soilocp run", f"--replay {log}: no sample with a vehicle_id in its first lines; is it a sensor log "
                              "(docs/sensor-log.md)? A ROS 2 bag needs --map MAP.yaml")
    if len(found) > 1:
        _fatal("soilocp run", f"--replay {log}: the log holds samples of several vehicles ({', '.join(found)}); "
                              "soilocp run replays one: split the log per vehicle_id")
    if explicit and given != found[0]:
        _fatal("soilocp run", f"--vehicle-id {given!r} but the samples of {log} are vehicle_id {found[0]!r}: every "
                              f"one would be rejected (vehicle_mismatch); leave --vehicle-id out (the log's id is "
                              f"used) or give --vehicle-id {found[0]}")
    return found[0]


def _run_pipeline_config(pipeline_config, vehicle_path, torque_constant, log_dir: str) -> str:
    """The pipeline config the services get: ``pipeline_config`` checked now (a typo fails here, not in five
    services), with ``vehicle_path``'s vehicle and ``torque_constant`` over it, written into ``log_dir``."""
    import json

    from soilocp.estimation.config import load_pipeline_config

    try:
        cfg = load_pipeline_config(pipeline_config, vehicle=vehicle_path, torque_constant=torque_constant)
    except ValueError as exc:
        _fatal("soilocp run", str(exc))
    if vehicle_path is None and torque_constant is None:
        return pipeline_config
    data = json.loads(open(pipeline_config, encoding="utf-8").read()) if pipeline_config else {}
    if vehicle_path is not None:
        data["vehicle"] = cfg.vehicle.model_dump()
    if torque_constant is not None:
        data["torque_constant"] = cfg.torque_constant
    os.makedirs(log_dir, exist_ok=True)
    out = os.path.join(log_dir, "pipeline-config.json")
    with open(out, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=2)
    return out


def _ros2_endpoints(ros2_connect, listen) -> list[str]:
    """The robot's router endpoints; it cannot be the address soilocp's own router listens on."""
    from soilocp.services.runtime.config import DEFAULT_ENDPOINT, check_endpoint
    from soilocp.services.supervisor.run import client_endpoints

    eps = [check_endpoint(ep) for ep in ros2_connect] or [ROS2_DEFAULT_ENDPOINT]
    ours = set(client_endpoints(list(listen) or [DEFAULT_ENDPOINT]))
    clash = [ep for ep in eps if ep in ours]
    if clash:
        raise ValueError(f"the robot's router {clash[0]} is where soilocp's own router would listen: give "
                         "--listen another endpoint (e.g. --listen tcp/127.0.0.1:7448)")
    return eps


def _import_for_replay(bag: str, map_path: str, log_dir):
    """A bag -> a sensor log in the run's log dir (or a temp dir), replayed like any other log."""
    import tempfile

    from soilocp.commands.io import run_import
    from soilocp.ingest import load_map

    out_dir = log_dir or tempfile.mkdtemp(prefix="soilocp-import-")
    os.makedirs(out_dir, exist_ok=True)
    out = os.path.join(out_dir, "imported-sensors.jsonl")
    try:
        prov = run_import(bag, (), map_path, out, progress=sys.stderr.isatty())
    except click.ClickException as exc:
        _fatal("soilocp run", exc.message)
    if not prov.identifiable:
        click.echo("soilocp run: WARNING: the live chain does not read provenance files; K from this log is not "
                   "identifiable (" + "; ".join(prov.reasons) + ")", err=True)
    return out, load_map(map_path).vehicle_id


@click.group("schemas")
def schemas_group() -> None:
    """Message contracts (JSON Schema for consumers in other languages)."""


@schemas_group.command("export")
@click.argument("directory", type=click.Path(file_okay=False))
def schemas_export(directory: str) -> None:
    """Write one JSON Schema file per message model into DIRECTORY."""
    from soilocp.schemas.export import export_schemas

    for p in export_schemas(directory):
        click.echo(str(p))


#: The commands of the long-running processes (the only ones ``soilocp service`` / ``soilocp router``
#: load, see ``soilocp.cli.entry``), and the rest of the services area's own commands.
PROCESS_COMMANDS = [service_cmd, router_cmd]
COMMANDS = [run_cmd, schemas_group]
