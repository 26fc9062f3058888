"""``soilocp run``: the whole system on one machine, as separate OS processes, with a live view.

Starts ``soilocp router``, the five pipeline services (with ``--map-store``, the fleet soil map
service too) and the source (synthetic vehicle or a log replay), each as
``python -m soilocp.cli ...`` with its own log file, watches the vehicle's keys
from a client session of its own (OCPs, rejections, status, liveliness) and shows a live table
(rich) on a terminal, or a plain line every few seconds without one.  Ctrl-C / SIGTERM stop
everything: SIGTERM to each child in reverse order, wait, SIGKILL after a timeout.  The exit
status is non-zero if any process died or failed to stop.  With ``--restart`` a process that dies
is started again instead, and the restarts are answered on the vehicle's supervisor key for the
fleet tools (:mod:`soilocp.services.supervisor.restarts`).
"""

from __future__ import annotations

import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.services.stages.graph import BY_NAME, PIPELINE_SERVICES
from soilocp.schemas.messages import ServiceHealth

from soilocp.services.runtime.config import DEFAULT_ENDPOINT

from soilocp.services.runtime.log import JsonLog

from soilocp.services.runtime.process import open_session
from soilocp.services.supervisor.liveliness import wait_alive
from soilocp.services.supervisor.log_watch import LogWatch
from soilocp.services.supervisor.monitor import Monitor
from soilocp.services.supervisor.processes import STOP_TIMEOUT_S, Child, ProcessGroup
from soilocp.services.supervisor.restarts import RestartBook
from soilocp.services.supervisor.table import drop_lines, live_table, plain_line, summary_tables
from soilocp.estimation.next_steps import status_table, verdict

DRAIN_QUIET_S = 1.5  # after the source ends: stop once no OCP arrived for this long
DRAIN_MAX_S = 30.0
#: --restart: a process that dies more than RESTART_MAX times within RESTART_WINDOW_S stops the run after all
RESTART_MAX = 5
RESTART_WINDOW_S = 60.0


@dataclass
class RunOptions:
    scenario: Optional[str] = None
    replay: Optional[str] = None
    speed: float = 1.0
    vehicle_id: str = "rover1"
    duration: Optional[float] = None
    listen: Optional[list[str]] = None
    pipeline_config: Optional[str] = None
    stale_timeout: float = 0.5
    seed: int = 0
    log_dir: Optional[str] = None
    plain: bool = False
    startup_timeout_s: float = 90.0
    control: Optional[str] = None  # closed loop: the controller service's policy, the vehicle follows it
    foxglove: Optional[str] = None  # HOST:PORT of a Foxglove WebSocket server serving the vehicle's channels
    ros2_out: bool = False  # also publish the estimates as ROS 2 topics (ros2-out service)
    ros2_in: Optional[str] = None  # map file: the sensors come from the robot's ROS 2 topics (ros2-in service)
    ros2_connect: Optional[list[str]] = None  # the robot's Zenoh router (rmw_zenohd)
    ros2_domain: int = 0
    restart: bool = False  # a router or service that dies is restarted (RESTART_MAX a RESTART_WINDOW_S), not fatal
    map_store: Optional[str] = None  # also run the fleet soil map service on this store (sqlite:PATH, postgresql://)
    map_id: str = "fleet"


def client_endpoints(listen: list[str]) -> list[str]:
    """Where local clients connect for a router listening on ``listen`` (0.0.0.0 / [::] -> loopback)."""
    out = []
    for ep in listen:
        out.append(ep.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:"))
    return out


def run_system(opts: RunOptions) -> int:
    """Run everything until the duration, the end of the source, a death or a signal; 0 if all went well."""
    from rich.console import Console

    import shutil

    console = Console()
    if not console.is_terminal:  # piped / CI: wide enough for the table, no colours or cursor tricks
        console = Console(width=max(shutil.get_terminal_size((160, 24)).columns, 160), no_color=True)
    listen = opts.listen or [DEFAULT_ENDPOINT]
    connect = client_endpoints(listen)
    log_dir = Path(opts.log_dir) if opts.log_dir else Path(tempfile.mkdtemp(prefix="soilocp-run-"))
    log_dir.mkdir(parents=True, exist_ok=True)
    interactive = console.is_terminal and not opts.plain
    stop = threading.Event()
    interrupted = {"sig": None}

    def _on_signal(signum, _frame):
        interrupted["sig"] = signum
        stop.set()

    fox = None
    if opts.foxglove is not None:
        # inside the run, on the run's own session: subscribed before the source starts (nothing
        # missed, no token to wait for), and no seventh interpreter on a small computer; its Zenoh
        # callbacks only enqueue, so the live table's subscribers are not held up
        from soilocp.services.io.foxglove_live import FoxgloveLive, parse_address

        host, port = parse_address(opts.foxglove)
        # its warnings (invalid samples, drops) go to a log of their own, not across the live table
        fox_log = open(log_dir / "foxglove.log", "a", encoding="utf-8")
        try:
            fox = FoxgloveLive(host, port, [opts.vehicle_id], log=JsonLog("foxglove", stream=fox_log))
        except ValueError:  # the port is taken: fail before any process starts
            fox_log.close()
            raise
        console.print(f"soilocp run: Foxglove WebSocket server on {fox.url} (layout: docs/foxglove/soilocp-layout.json)")
    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    group = ProcessGroup(log_dir)
    book = RestartBook(opts.vehicle_id, group, opts.restart)
    monitor = Monitor(opts.vehicle_id, opts.stale_timeout)
    session = None
    failures: list[str] = []
    t_start = time.monotonic()
    t_drive: Optional[float] = None
    vehicle: Optional[Child] = None
    console.print(f"soilocp run: logs in {log_dir}; router {', '.join(listen)}; vehicle {opts.vehicle_id}")
    try:
        common = ["--vehicle-id", opts.vehicle_id, "--log-level", "info"]
        for ep in connect:
            common += ["--connect", ep]
        router_args = ["router"]
        for ep in listen:
            router_args += ["--listen", ep]
        group.start("router", router_args)
        if opts.map_store:
            margs = ["service", "map", "--map-id", opts.map_id, "--store", opts.map_store, "--log-level", "info"]
            for ep in connect:
                margs += ["--connect", ep]
            group.start("map", margs)
        for name in PIPELINE_SERVICES:
            args = ["service", name, *common]
            if name == "ocp":
                args += ["--stale-timeout", str(opts.stale_timeout)]
            if opts.pipeline_config and BY_NAME[name].stage is not None:  # the rows that run physics
                args += ["--pipeline-config", opts.pipeline_config]
            group.start(name, args)
        want_alive = set(PIPELINE_SERVICES)
        ros2_args = ["--ros2-domain", str(opts.ros2_domain)]
        for ep in opts.ros2_connect or []:
            ros2_args += ["--ros2-connect", ep]
        if opts.ros2_out:
            group.start("ros2-out", ["service", "ros2-out", *common, *ros2_args,
                                     "--stale-timeout", str(opts.stale_timeout)])
            want_alive.add("ros2-out")
        if opts.control:
            group.start("controller", ["service", "controller", *common, "--control", opts.control,
                                       "--stale-timeout", str(opts.stale_timeout)])
            want_alive.add("controller")
        # a service that logs an error, or waits on something the run does not start (the robot's ROS 2
        # router), stops the run at once with its own words, instead of a liveliness timeout
        watch = LogWatch(log_dir, [c.name for c in group.children])
        seen: list = []

        def blocked() -> bool:
            if not seen:
                problem = watch.poll()
                if problem is not None:
                    seen.append(problem)
            return bool(seen)

        session = _open_monitor_session(connect, group, stop, failures, blocked)
        if seen:
            failures.append(str(seen[0]))
        if session is not None and not seen:  # None: interrupted, or a process died while connecting
            monitor.attach(session)
            book.attach(session)
            if fox is not None:
                fox.attach(session)
            # wait until every pipeline service holds its token (or one dies, or says it cannot start)
            missing = wait_alive(session, [opts.vehicle_id], want_alive, opts.startup_timeout_s, stop=stop,
                                 dead=lambda: group.dead() or blocked(), interval=0.1)
            dead = group.dead()
            for c in group.children:
                if c.name in dead:
                    c.outcome = "died"
                    failures.append(f"{c.name} exited during startup (exit {c.proc.returncode}); see {c.log_path}")
            if seen and not dead:
                failures.append(str(seen[0]))
            if missing and not dead and not seen and not stop.is_set():
                failures.append(f"services not alive after {opts.startup_timeout_s:.0f} s: "
                                + ",".join(sorted(s for _v, s in missing)))
            if opts.map_store and not failures and not stop.is_set() and not _map_alive(
                    session, opts.map_id, opts.startup_timeout_s, stop, lambda: group.dead() or blocked()):
                failures.append(f"map service (map id {opts.map_id}) not alive; see {log_dir / 'map.log'}")
            if not failures and not stop.is_set():
                vargs = ["service", "vehicle", *common, "--speed", str(opts.speed), "--wait-timeout", "10"]
                if opts.ros2_in:
                    vargs = ["service", "ros2-in", *common, *ros2_args, "--ros2-map", str(opts.ros2_in),
                             "--wait-timeout", "10"]
                elif opts.scenario:
                    vargs += ["--scenario", opts.scenario, "--seed", str(opts.seed)]
                    if opts.control:
                        vargs += ["--control", opts.control, "--stale-timeout", str(opts.stale_timeout)]
                else:
                    vargs += ["--replay", str(opts.replay)]
                if opts.duration is not None and not opts.ros2_in:  # a live robot ends when the run does
                    vargs += ["--duration", str(opts.duration)]
                vehicle = group.start(vargs[1], vargs)
                t_drive = time.monotonic()
                console.print(f"soilocp run: all services alive after {t_drive - t_start:.1f} s; driving "
                              + (f"scenario {opts.scenario}" if opts.scenario else f"replay {opts.replay}"
                                 if opts.replay else f"from ROS 2 topics ({opts.ros2_in})"))
                watch = LogWatch(log_dir, [vehicle.name], {})
                failures += _watch(opts, group, vehicle, monitor, stop, t_drive, console, interactive, watch, book)
    finally:
        snap_running = monitor.snapshot()  # what the table showed last, before anything stops
        if session is not None and not failures:
            _final_health(session, group, vehicle, monitor, opts.vehicle_id)
        group.stop_all()
        for child in group.children:
            if child.outcome in ("died", "killed"):
                if not any(f.startswith(child.name + " ") for f in failures):
                    failures.append(f"{child.name} {child.outcome} (exit {child.proc.returncode if child.proc else '-'})")
        snap = monitor.snapshot()  # final counters: the services' "stopping" health reports
        snap.update({k: snap_running[k] for k in ("est", "age", "stale", "rate", "alive")})
        monitor.detach()
        book.detach()
        if fox is not None:
            fox.close()
            fox.log.stream.close()
        if session is not None:
            session.close()
        for s, h in old.items():
            signal.signal(s, h)
    elapsed = time.monotonic() - (t_drive or t_start)
    for table in summary_tables(opts.vehicle_id, snap, group, elapsed, width=console.width):
        console.print(table)
    if snap["codes"]:
        console.print("rejections by code: " + ", ".join(f"{k}={v}" for k, v in sorted(snap["codes"].items())))
        if snap["codes"].get("vehicle_mismatch"):
            console.print(f"  vehicle_mismatch: the samples' vehicle_id is not {opts.vehicle_id!r}, the id the "
                          "services were started for: give --vehicle-id with the log's id", markup=False)
    for line in drop_lines(snap["health"], opts.speed if opts.replay else None):
        console.print(line, markup=False, highlight=False)
    if snap["reasons"]:
        console.print(status_table(snap["reasons"], "OCP records per status and reason"))
        console.print(verdict(snap["reasons"]), markup=False, highlight=False)
    console.print(f"OCP records received: {snap['count']}; logs in {log_dir}")
    if fox is not None:
        console.print("Foxglove: " + ", ".join(f"{k} {v}" for k, v in fox.counts.items()))
    if failures:
        for f in failures:
            console.print(f"[red]FAILED[/red]: {f}")
        for child in group.children:  # the last words of what died, so nobody has to dig for the log
            if child.outcome in ("died", "killed") or (child.proc and child.proc.returncode not in (0, None)):
                for line in _tail(child.log_path, 3):
                    console.print(f"  {child.name}: {line}", markup=False, highlight=False)
        return 1
    if interrupted["sig"] is not None:
        console.print("interrupted: everything stopped")
        return 130 if interrupted["sig"] == signal.SIGINT else 143
    return 0


def _open_monitor_session(connect: list[str], group: ProcessGroup, stop: threading.Event, failures: list[str],
                          blocked=lambda: False):
    """The run's own client session, opened on a thread so that a router that dies at startup
    (port taken), a service that says it cannot start (``blocked()``) or a Ctrl-C is noticed while the
    connection is still being attempted."""
    box: dict[str, Any] = {}
    give_up = threading.Event()

    def _open() -> None:
        box["session"] = open_session("client", connect, [], multicast=False, stop=give_up, log=JsonLog("run", "error"))
        if give_up.is_set() and box["session"] is not None:
            box["session"].close()
            box["session"] = None

    th = threading.Thread(target=_open, name="monitor-open", daemon=True)
    th.start()
    while th.is_alive():
        dead = [c for c in group.children if c.poll() is not None]
        if dead or stop.is_set() or blocked():
            for c in dead:
                c.outcome = "died"
                failures.append(f"{c.name} exited during startup (exit {c.proc.returncode}); see {c.log_path}")
            give_up.set()
            th.join(3.0)  # let a connection attempt in progress end (it is bounded) before we go on
            return None
        th.join(0.1)
    return box.get("session")


def _tail(path: Path, n: int) -> list[str]:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return []
    return [x[:300] for x in lines[-n:]]


def _final_health(session, group: ProcessGroup, vehicle: Optional[Child], monitor: Monitor, vid: str) -> None:
    """Stop the source first, let the pipeline drain, then ask every service for its counters,
    so that the summary's counts are consistent with each other."""
    if vehicle is not None and vehicle.proc is not None and vehicle.proc.poll() is None:
        vehicle.stopping = True
        vehicle.proc.send_signal(signal.SIGTERM)
        try:
            vehicle.proc.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pass
    time.sleep(0.5)
    try:
        for reply in session.get(keys.vehicle_status_all(vid), timeout=2.0):
            if reply.ok is None:
                continue
            try:
                h = ServiceHealth.model_validate_json(reply.ok.payload.to_bytes())
            except ValueError:
                continue
            with monitor.lock:
                monitor.health[h.service] = h
    except Exception:  # the summary falls back to the last periodic reports
        pass


def _map_alive(session, map_id: str, timeout: float, stop: threading.Event, dead) -> bool:
    """Wait until the map service holds its liveliness token (False: timeout, stop, or ``dead()``)."""
    deadline = time.monotonic() + timeout
    key = keys.map_key(map_id, "alive")
    while time.monotonic() < deadline and not stop.is_set() and not dead():
        if any(r.ok is not None for r in session.liveliness().get(key, timeout=1.0)):
            return True
        stop.wait(0.1)
    return False


def _restart(group: ProcessGroup, child: Child, restarts: dict[str, list[float]], now: float,
             book: Optional[RestartBook] = None) -> bool:
    """Start ``child``'s command again under its name, unless it has died too often lately (False);
    ``book`` records the restart for the fleet tools."""
    recent = [t for t in restarts.get(child.name, []) if now - t < RESTART_WINDOW_S]
    if len(recent) >= RESTART_MAX:
        return False
    child.outcome = "restarted"
    group.start_argv(child.name, child.argv)
    restarts[child.name] = [*recent, now]
    if book is not None:
        book.record(child.name, child.proc.returncode if child.proc else None)
    return True


def _watch(opts: RunOptions, group: ProcessGroup, vehicle: Child, monitor: Monitor, stop: threading.Event,
           t_drive: float, console, interactive: bool, watch: Optional[LogWatch], book: RestartBook) -> list[str]:
    """The live loop; returns failures (processes that died, or a source that says it cannot start:
    ``watch`` reads its log).  With ``opts.restart`` what dies is started again and ``book`` records it."""
    from rich.live import Live

    failures: list[str] = []
    restarts: dict[str, list[float]] = {}
    source_done_at: Optional[float] = None
    next_plain = 0.0
    live = Live(console=console, refresh_per_second=4, transient=False) if interactive else None
    if live:
        live.start()
    try:
        while not stop.wait(0.25):
            now = time.monotonic()
            elapsed = now - t_drive
            for child in group.children:
                rc = child.poll()
                if rc is None or child.outcome != "running":
                    continue
                if child is vehicle and rc == 0:
                    child.outcome = "done"
                    source_done_at = now
                elif opts.restart and child is not vehicle and _restart(group, child, restarts, now, book):
                    console.print(f"soilocp run: {child.name} exited (exit {rc}); restarted as pid "
                                  f"{group.procs[child.name].pid} (restart {book.count(child.name)})")
                else:
                    child.outcome = "died"
                    failures.append(f"{child.name} died (exit {rc}); see {child.log_path}")
            problem = watch.poll() if watch is not None else None
            if problem is not None:
                failures.append(str(problem))
            snap = monitor.snapshot()
            if live:
                live.update(live_table(opts.vehicle_id, snap, elapsed, width=console.width))
            elif now >= next_plain:
                next_plain = now + 2.0
                print(plain_line(opts.vehicle_id, snap, elapsed), flush=True)
            if failures:
                break
            # the source stops itself after the duration; this is only the safety net (slow start)
            if opts.duration is not None and elapsed >= opts.duration + 15.0:
                break
            if opts.ros2_in and opts.duration is not None and elapsed >= opts.duration:
                break  # a robot's topics do not end: the run's duration does
            if source_done_at is not None and now - source_done_at > 1.0:
                # drained: the OCP stream has gone quiet (a loaded machine may lag the source by
                # seconds), or a bound in case nothing comes out at all
                quiet = snap["age"] is None or snap["age"] > DRAIN_QUIET_S
                if quiet or now - source_done_at > DRAIN_MAX_S:
                    break
    finally:
        if live:
            live.stop()
    return failures
