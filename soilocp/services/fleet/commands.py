"""Console commands of the fleet view: ``soilocp fleet status`` and ``soilocp dashboard``.

Zenoh, Starlette and uvicorn are imported inside the command bodies, so ``soilocp --help`` stays
fast.  Registered by ``soilocp.services.commands`` (its ``EXTRA_COMMAND_MODULES``).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from typing import Any, Optional

import click

ENV_CONNECT = "SOILOCP_CONNECT"


def tool_endpoints(connect: tuple[str, ...]) -> list[str]:
    """Where a fleet tool (fleet status, dashboard, foxglove) connects: --connect (repeatable) >
    SOILOCP_CONNECT (comma-separated) > the default router endpoint; each endpoint checked."""
    from soilocp.services.runtime.config import DEFAULT_ENDPOINT, check_endpoint

    eps = list(connect) or [e.strip() for e in os.environ.get(ENV_CONNECT, "").split(",") if e.strip()] \
        or [DEFAULT_ENDPOINT]
    for ep in eps:
        check_endpoint(ep)  # ValueError naming the endpoint
    return eps


def _fmt(x: Optional[float], spec: str = ".3f") -> str:
    return "-" if x is None else format(x, spec)


def _age(x: Optional[float]) -> str:
    if x is None:
        return "-"
    return f"{x:.1f} s" if x < 120 else f"{x / 60:.0f} min"


def fleet_table(rows: list[dict[str, Any]], title: str):
    """A rich table, one row per vehicle."""
    from rich.table import Table
    from rich.text import Text

    t = Table(title=title, title_justify="left")
    for name in ("vehicle", "services", "K ± std", "soil class", "mu_T", "S_T", "S_E", "status", "age", "rej",
                 "restarts"):
        t.add_column(name, no_wrap=True,
                     justify="right" if name in ("K ± std", "mu_T", "S_T", "S_E", "age", "rej") else "left")
    colours = {"fresh": "green", "stale": "yellow", "no estimate": "dim"}
    for r in rows:
        n = len(r["services_alive"])
        total = n + len(r["services_missing"])
        if r["state"] == "offline":
            svc = Text(f"0/{total} offline since " + time.strftime("%H:%M:%S", time.gmtime(r["offline_since"])),
                       style="red")
        elif r["services_missing"]:
            svc = Text(f"{n}/{total} missing " + ",".join(r["services_missing"]), style="yellow")
        else:
            svc = Text(f"{n}/{total}", style="green")
        k = "-" if r["K"] is None else f"{r['K']:.1f} ± {_fmt(r['K_std'], '.1f')}"
        cls = r["soil_class"] or "-"
        if r["soil_class"] and r["soil_class_confidence"] is not None:
            cls += f" ({r['soil_class_confidence']:.2f})"
        status = r["status"] + (f" / {r['estimate_status']}" if r["estimate_status"] and r["status"] != "stale" else "")
        rej = Text(str(r["rejections"]))
        if r["second_source"]:
            rej = Text(f"{r['rejections']} (2nd source: {r['source_conflicts']})", style="red")
        t.add_row(r["vehicle_id"], svc, k, cls, _fmt(r["mu_T"]), _fmt(r["S_T"]), _fmt(r["S_E"]),
                  Text(status, style=colours.get(r["status"], "")), _age(r["age_s"]), rej, restarts_text(r))
    return t


#: A service this much younger than the oldest of its vehicle was started again since
YOUNGER_S = 5.0


def restarts_text(row: dict[str, Any]) -> str:
    """The ``restarts`` cell: the supervisor's total, and the process restarted last with how long ago
    ("3, ocp 12.0 s ago"); without a supervisor report (systemd, Docker), the new processes the services'
    health showed while this monitor listened ("2 seen, ocp 12.0 s ago"), else the youngest service where
    it is younger than the oldest ("ocp up 12.0 s"); "-" without any of these."""
    if row.get("restarts_total") is None:
        seen = row.get("restarts_seen") or {}
        if seen:
            age, name = min((p["last_restart_age_s"], n) for n, p in seen.items())
            return f"{row['restarts_seen_total']} seen, {name} {_age(age)} ago"
        up = row.get("uptime_s") or {}
        if up and min(up.values()) < max(up.values()) - YOUNGER_S:
            age, name = min((a, n) for n, a in up.items())
            return f"{name} up {_age(age)}"
        return "-"
    per = row.get("restarts") or {}
    died = [n for n, p in per.items() if p["state"] == "died"]
    timed = [(p["last_restart_age_s"], n) for n, p in per.items() if p["last_restart_age_s"] is not None]
    out = str(row["restarts_total"])
    if timed:
        age, name = min(timed)
        out += f", {name} {_age(age)} ago"
    if died:
        out += ", died: " + ",".join(died)
    return out


def _install_stop(stop: threading.Event) -> dict:
    def _handler(signum, _frame) -> None:
        if stop.is_set():  # second signal: leave at once
            os._exit(128 + signum)
        stop.set()

    return {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}


def run_status(connect: list[str], timeout: float, watch: bool, as_json: bool, interval: float = 1.0) -> int:
    """``soilocp fleet status``; returns the exit status (1: no router / nothing answered)."""
    import zenoh
    from rich.console import Console

    from soilocp.services.fleet.monitor import query_fleet
    from soilocp.services.fleet.state import FleetState
    from soilocp.services.runtime.config import zenoh_config

    console = Console()
    if not console.is_terminal:  # piped: wide enough for the whole table, no colour codes
        console = Console(width=160, no_color=True)
    stop = threading.Event()
    old = _install_stop(stop)
    try:
        conf = zenoh_config("client", connect, [], multicast=False, connect_timeout_ms=int(timeout * 1000))
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            click.echo(f"soilocp fleet status: no router answered on {', '.join(connect)} within {timeout:g} s "
                       f"({str(exc).splitlines()[0].split(' at /')[0][:160]})", err=True)
            return 1
        with session:
            state = FleetState()
            if not watch:
                n = query_fleet(session, state, timeout)
                rows = state.rows()
                if as_json:
                    click.echo(json.dumps({"time": time.time(), "connect": connect, "vehicles": rows}, indent=2))
                elif rows:
                    console.print(fleet_table(rows, f"soilocp fleet — {len(rows)} vehicle(s) via {', '.join(connect)}"))
                if n == 0 or not rows:
                    click.echo(f"soilocp fleet status: no vehicle answered on {', '.join(connect)} within {timeout:g} s",
                               err=True)
                    return 1
                return 0
            import contextlib

            from rich.live import Live

            # JSON lines go straight to stdout; the table is redrawn in place
            live_view = contextlib.nullcontext() if as_json else Live(console=console, refresh_per_second=4)
            with live_view as live:
                while not stop.is_set():
                    query_fleet(session, state, timeout, misses=2)
                    rows = state.rows()
                    if as_json:
                        click.echo(json.dumps({"time": time.time(), "connect": connect, "vehicles": rows}))
                    else:
                        live.update(fleet_table(rows, f"soilocp fleet — {len(rows)} vehicle(s) via "
                                                      f"{', '.join(connect)} — {time.strftime('%H:%M:%S')} "
                                                      "(Ctrl-C to stop)"))
                    stop.wait(interval)
            return 0
    finally:
        for s, h in old.items():
            signal.signal(s, h)


@click.group("fleet")
def fleet_group() -> None:
    """Every vehicle behind a router: liveliness, latest OCP, freshness, rejections."""


@fleet_group.command("status")
@click.option("--connect", multiple=True, help="Router endpoint (repeatable); env SOILOCP_CONNECT; default tcp/127.0.0.1:7447.")
@click.option("--timeout", type=float, default=2.0, show_default=True, help="Seconds to wait for the router and for replies.")
@click.option("--watch", is_flag=True, help="Refresh the table every second until Ctrl-C.")
@click.option("--json", "as_json", is_flag=True, help="JSON output (with --watch: one JSON object per line).")
def fleet_status_cmd(connect, timeout, watch, as_json) -> None:
    """One row per vehicle: services alive, K ± std, soil class, mu_T, S_T, S_E, freshness, rejections.

    Exit status 1 when no router or no vehicle answers within --timeout."""
    from soilocp.services.security.fleet_security import check_client_tls

    try:
        eps = tool_endpoints(connect)
        check_client_tls(eps)
        if not (timeout > 0):
            raise ValueError(f"--timeout {timeout!r}: must be > 0 s")
    except ValueError as exc:
        click.echo(f"soilocp fleet status: error: {exc}", err=True)
        sys.exit(2)
    sys.exit(run_status(eps, timeout, watch, as_json))


@click.command("dashboard")
@click.option("--port", type=click.IntRange(0, 65535), default=8050, show_default=True, help="TCP port of the web page.")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to serve on.")
@click.option("--connect", multiple=True, help="Router endpoint (repeatable); env SOILOCP_CONNECT; default tcp/127.0.0.1:7447.")
@click.option("--constants", "constants_path", type=click.Path(exists=True, dir_okay=False),
              help="Model constants (soilocp calibrate output) for the traction curve and the soil bands.")
@click.option("--poll", type=float, default=1.0, show_default=True, help="Seconds between two fleet queries.")
def dashboard_cmd(port, host, connect, constants_path, poll) -> None:
    """Serve a live web page of the fleet (table, K / OCP plots, traction-slip curve) until Ctrl-C."""
    from soilocp.model.constants import load_constants

    from soilocp.services.fleet.dashboard.app import DashboardHub, serve

    from soilocp.services.security.fleet_security import check_client_tls

    try:
        eps = tool_endpoints(connect)
        check_client_tls(eps)
        if not (poll > 0):
            raise ValueError(f"--poll {poll!r}: must be > 0 s")
        constants = load_constants(constants_path)
        hub = DashboardHub(eps, constants=constants, poll_period_s=poll)
    except ValueError as exc:
        click.echo(f"soilocp dashboard: error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"soilocp dashboard: http://{host}:{port}/ (router {', '.join(eps)})", err=True)
    sys.exit(serve(hub, host, port))


COMMANDS = [fleet_group, dashboard_cmd]
