"""``soilocp run``: the whole system on one machine, as separate OS processes, with a live view.

Starts ``soilocp router``, the five pipeline services and the source (synthetic vehicle or a log
replay), each as ``python -m soilocp_cli ...`` with its own log file, watches the vehicle's keys
from a client session of its own (OCPs, rejections, status, liveliness) and shows a live table
(rich) on a terminal, or a plain line every few seconds without one.  Ctrl-C / SIGTERM stop
everything: SIGTERM to each child in reverse order, wait, SIGKILL after a timeout.  The exit
status is non-zero if any process died or failed to stop.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter as Tally
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from schemas import keys
from services.stages.graph import PIPELINE_SERVICES
from schemas.messages import Rejection, ServiceHealth, SlipSetpoint
from schemas.pipeline import OcpEstimate

from services.runtime.config import DEFAULT_ENDPOINT, ENV_EXIT_WITH_PARENT

from services.runtime.log import JsonLog

from services.runtime.process import open_session

DRAIN_QUIET_S = 1.5  # after the source ends: stop once no OCP arrived for this long
DRAIN_MAX_S = 30.0
STOP_TIMEOUT_S = 5.0  # services stop in < 2 s; the margin is for a heavily loaded machine


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


def client_endpoints(listen: list[str]) -> list[str]:
    """Where local clients connect for a router listening on ``listen`` (0.0.0.0 / [::] -> loopback)."""
    out = []
    for ep in listen:
        out.append(ep.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:"))
    return out


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    proc: Optional[subprocess.Popen] = None
    stopping: bool = False
    outcome: str = "running"  # running | done | died | stopped | killed

    @property
    def pid(self) -> Optional[int]:
        return self.proc.pid if self.proc else None

    def start(self, env: dict[str, str]) -> None:
        fh = open(self.log_path, "ab")
        try:
            # own session: the terminal's Ctrl-C reaches only us; we stop the children in order
            self.proc = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=fh, stderr=fh, env=env,
                                         start_new_session=True)
        finally:
            fh.close()

    def poll(self) -> Optional[int]:
        return None if self.proc is None else self.proc.poll()


class ProcessGroup:
    """Children started in order and stopped in reverse order; every one is reaped."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.children: list[Child] = []
        self.env = dict(os.environ)
        self.env.pop("SOILOCP_CONFIG", None)  # the run passes every setting explicitly
        self.env["PYTHONUNBUFFERED"] = "1"
        # if this process is SIGKILLed, the children notice their new parent and stop themselves
        self.env[ENV_EXIT_WITH_PARENT] = "1"

    def start(self, name: str, args: list[str]) -> Child:
        child = Child(name, [sys.executable, "-m", "soilocp_cli", *args], self.log_dir / f"{name}.log")
        child.start(self.env)
        self.children.append(child)
        return child

    def stop_all(self, timeout: float = STOP_TIMEOUT_S) -> None:
        for child in reversed(self.children):
            if child.proc and child.proc.poll() is None:
                child.stopping = True
                try:
                    child.proc.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + timeout
        for child in reversed(self.children):
            if child.proc is None:
                continue
            try:
                child.proc.wait(max(0.05, deadline - time.monotonic()))
                if child.outcome == "running":
                    # -SIGTERM: stopped while still starting, before its handlers were installed
                    ok = child.proc.returncode in (0, -signal.SIGTERM)
                    child.outcome = "stopped" if ok else "died"
            except subprocess.TimeoutExpired:
                child.proc.kill()
                child.proc.wait()
                child.outcome = "killed"


class Monitor:
    """What the run shows, fed by Zenoh callbacks (cheap: store and count only)."""

    def __init__(self, vehicle_id: str, stale_timeout: float):
        self.vid = vehicle_id
        self.stale_timeout = stale_timeout
        self.lock = threading.Lock()
        self.latest: Optional[OcpEstimate] = None
        self.latest_wall: Optional[float] = None
        self.ocp_count = 0
        self.arrivals: deque[float] = deque(maxlen=5000)
        self.rejections = 0
        self.rejection_codes: Tally = Tally()
        self.health: dict[str, ServiceHealth] = {}
        self.alive: set[str] = set()
        self.stale_reports = 0
        self.setpoint: Optional[SlipSetpoint] = None
        self._decls: list[Any] = []

    def attach(self, session) -> None:
        import zenoh

        vid = self.vid

        def on_ocp(sample) -> None:
            try:
                est = OcpEstimate.model_validate_json(sample.payload.to_bytes())
            except ValueError:
                return
            now = time.time()
            with self.lock:
                self.latest, self.latest_wall = est, now
                self.ocp_count += 1
                self.arrivals.append(now)

        def on_rejected(sample) -> None:
            try:
                rej = Rejection.model_validate_json(sample.payload.to_bytes())
                code = rej.code
            except ValueError:
                code = "?"
            with self.lock:
                self.rejections += 1
                self.rejection_codes[code] += 1

        def on_status(sample) -> None:
            try:
                h = ServiceHealth.model_validate_json(sample.payload.to_bytes())
            except ValueError:
                return
            with self.lock:
                self.health[h.service] = h
                if h.service == "ocp" and h.stale:
                    self.stale_reports += 1

        def on_setpoint(sample) -> None:
            try:
                sp = SlipSetpoint.model_validate_json(sample.payload.to_bytes())
            except ValueError:
                return
            with self.lock:
                self.setpoint = sp

        def on_alive(sample) -> None:
            try:
                _vid, service = keys.service_of_alive_key(str(sample.key_expr))
            except ValueError:
                return
            with self.lock:
                if sample.kind == zenoh.SampleKind.PUT:
                    self.alive.add(service)
                else:
                    self.alive.discard(service)

        self._decls = [
            session.declare_subscriber(keys.ocp(vid), on_ocp),
            session.declare_subscriber(keys.rejected(vid), on_rejected),
            session.declare_subscriber(keys.vehicle_status_all(vid), on_status),
            session.declare_subscriber(keys.control_slip(vid), on_setpoint),
            session.liveliness().declare_subscriber(keys.vehicle_alive_all(vid), on_alive, history=True),
        ]

    def detach(self) -> None:
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:
                pass
        self._decls = []

    def snapshot(self) -> dict[str, Any]:
        now = time.time()
        with self.lock:
            recent = [t for t in self.arrivals if now - t <= 2.0]
            rate = len(recent) / 2.0 if recent else 0.0
            est = self.latest
            age = None if self.latest_wall is None else now - self.latest_wall
            ocp_h = self.health.get("ocp")
            return dict(
                est=est,
                age=age,
                stale=age is None or age > self.stale_timeout,
                rate=rate,
                count=self.ocp_count,
                rejections=self.rejections,
                codes=dict(self.rejection_codes),
                alive=set(self.alive),
                health=dict(self.health),
                ocp_stale_reported=bool(ocp_h and ocp_h.stale),
                setpoint=self.setpoint,
            )


def _fmt(x: Optional[float], spec: str = ".3f") -> str:
    return "-" if x is None else format(x, spec)


def _row(snap: dict[str, Any], source_ended: bool = False) -> dict[str, str]:
    est: Optional[OcpEstimate] = snap["est"]
    k = "-"
    cls = "-"
    status = "waiting"
    if est is not None:
        if est.soil_strength is not None:
            k = f"{est.soil_strength:.1f} ± {_fmt(est.soil_strength_std, '.1f')}"
        if est.soil_class:
            cls = est.soil_class + (f" ({est.soil_class_confidence:.2f})" if est.soil_class_confidence is not None else "")
        status = est.status
    fresh = "STALE" if snap["stale"] and est is not None else ("fresh" if est is not None else "-")
    if source_ended and fresh == "STALE":
        fresh = "source ended"  # silence after the end of the drive is expected, not a fault
    alive = snap["alive"]
    want = PIPELINE_SERVICES
    sp: Optional[SlipSetpoint] = snap.get("setpoint")
    n_alive = sum(1 for s in want if s in alive)
    return {
        "K ± std": k,
        "soil class": cls,
        "mu_T": _fmt(est.mu_T if est else None),
        "S_T": _fmt(est.S_T if est else None),
        "S_E": _fmt(est.S_E if est else None),
        "status": f"{status} / {fresh}",
        "samples/s": f"{snap['rate']:.1f}",
        "rejections": str(snap["rejections"]),
        "services alive": f"{n_alive}/{len(want)}" + ("" if n_alive == len(want) else
                                                      " (missing " + ",".join(s for s in want if s not in alive) + ")"),
        **({} if sp is None else {"slip set-point": f"{_fmt(sp.slip[0] if sp.slip else None)} ({sp.source})"}),
    }


def live_table(vid: str, snap: dict[str, Any], elapsed: float, title_extra: str = "", *, width: int = 200,
               source_ended: bool = False):
    """One row per vehicle on a wide terminal; a field/value column pair on a narrow one."""
    from rich.table import Table

    row = _row(snap, source_ended)
    title = f"soilocp run — {vid} — t={elapsed:.1f} s{title_extra}"
    if width < 130:
        t = Table(title=title, title_justify="left", show_header=False)
        t.add_column("field", style="bold")
        t.add_column("value", no_wrap=True)
        for name, value in row.items():
            t.add_row(name, value)
        return t
    t = Table(title=title, title_justify="left")
    t.add_column("vehicle")
    for name in row:
        t.add_column(name, no_wrap=True,
                     justify="right" if name not in ("soil class", "status", "services alive") else "left")
    t.add_row(vid, *row.values())
    return t


def plain_line(vid: str, snap: dict[str, Any], elapsed: float) -> str:
    row = _row(snap)
    return f"t={elapsed:6.1f}s {vid} " + " ".join(f"{k.replace(' ', '_')}={v.replace(' ', '')}" for k, v in row.items())


def summary_tables(vid: str, snap: dict[str, Any], group: ProcessGroup, elapsed: float, width: int = 200):
    from rich.table import Table

    ended = any(c.name == "vehicle" and c.outcome == "done" for c in group.children)
    top = live_table(vid, snap, elapsed, " — summary", width=width, source_ended=ended)
    t = Table(title="processes", title_justify="left")
    # short headers: the table must fit an 80-column terminal
    for col in ("process", "pid", "outcome", "rc", "recv", "pub", "rej", "drop", "err"):
        t.add_column(col, no_wrap=True, justify="left" if col in ("process", "outcome") else "right",
                     min_width={"process": 13, "pid": 7, "outcome": 7, "recv": 5, "pub": 5}.get(col))
    for child in group.children:
        h = snap["health"].get(child.name)
        rc = child.proc.returncode if child.proc else None
        t.add_row(child.name, str(child.pid), child.outcome, "-" if rc is None else str(rc),
                  *(str(getattr(h, f)) if h else "-" for f in ("received", "published", "rejected", "dropped", "errors")))
    return top, t


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

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    group = ProcessGroup(log_dir)
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
        for name in PIPELINE_SERVICES:
            args = ["service", name, *common]
            if name == "ocp":
                args += ["--stale-timeout", str(opts.stale_timeout)]
            if opts.pipeline_config and name != "gateway":
                args += ["--pipeline-config", opts.pipeline_config]
            group.start(name, args)
        want_alive = set(PIPELINE_SERVICES)
        if opts.control:
            group.start("controller", ["service", "controller", *common, "--control", opts.control,
                                       "--stale-timeout", str(opts.stale_timeout)])
            want_alive.add("controller")
        session = _open_monitor_session(connect, group, stop, failures)
        if session is not None:  # None: interrupted, or a process died while connecting
            monitor.attach(session)
            # wait until every pipeline service holds its token (or one dies)
            deadline = time.monotonic() + opts.startup_timeout_s
            while not stop.is_set():
                dead = [c.name for c in group.children if c.poll() is not None]
                if dead:
                    for c in group.children:
                        if c.name in dead:
                            c.outcome = "died"
                            failures.append(f"{c.name} exited during startup (exit {c.proc.returncode}); see {c.log_path}")
                    break
                if want_alive <= monitor.snapshot()["alive"]:
                    break
                if time.monotonic() > deadline:
                    failures.append(f"services not alive after {opts.startup_timeout_s:.0f} s: "
                                    + ",".join(sorted(want_alive - monitor.snapshot()["alive"])))
                    break
                stop.wait(0.1)
            if not failures and not stop.is_set():
                vargs = ["service", "vehicle", *common, "--speed", str(opts.speed), "--wait-timeout", "10"]
                if opts.scenario:
                    vargs += ["--scenario", opts.scenario, "--seed", str(opts.seed)]
                    if opts.control:
                        vargs += ["--control", opts.control, "--stale-timeout", str(opts.stale_timeout)]
                else:
                    vargs += ["--replay", str(opts.replay)]
                if opts.duration is not None:
                    vargs += ["--duration", str(opts.duration)]
                vehicle = group.start("vehicle", vargs)
                t_drive = time.monotonic()
                console.print(f"soilocp run: all services alive after {t_drive - t_start:.1f} s; driving "
                              + (f"scenario {opts.scenario}" if opts.scenario else f"replay {opts.replay}"))
                failures += _watch(opts, group, vehicle, monitor, stop, t_drive, console, interactive)
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
        if session is not None:
            session.close()
        for s, h in old.items():
            signal.signal(s, h)
    elapsed = time.monotonic() - (t_drive or t_start)
    for table in summary_tables(opts.vehicle_id, snap, group, elapsed, width=console.width):
        console.print(table)
    if snap["codes"]:
        console.print("rejections by code: " + ", ".join(f"{k}={v}" for k, v in sorted(snap["codes"].items())))
    console.print(f"OCP records received: {snap['count']}; logs in {log_dir}")
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


def _open_monitor_session(connect: list[str], group: ProcessGroup, stop: threading.Event, failures: list[str]):
    """The run's own client session, opened on a thread so that a router that dies at startup
    (port taken) or a Ctrl-C is noticed while the connection is still being attempted."""
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
        if dead or stop.is_set():
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


def _watch(opts: RunOptions, group: ProcessGroup, vehicle: Child, monitor: Monitor, stop: threading.Event,
           t_drive: float, console, interactive: bool) -> list[str]:
    """The live loop; returns failures (processes that died)."""
    from rich.live import Live

    failures: list[str] = []
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
                else:
                    child.outcome = "died"
                    failures.append(f"{child.name} died (exit {rc}); see {child.log_path}")
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
