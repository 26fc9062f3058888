#!/usr/bin/env python3
"""Container health check: is this container's soilocp process reachable through Zenoh?

Installed in the image as ``soilocp-healthcheck`` (the Dockerfile's HEALTHCHECK). It finds the
``soilocp service NAME`` or ``soilocp router`` process of the container in /proc, rebuilds that
process's settings exactly as it did (its command line, its environment, its config file, through
the services' own loaders), then:

* service NAME: asks the router the service uses for the liveliness token
  ``soilocp/<vid>/alive/<NAME>`` of each of its vehicles: healthy if every token answers;
* router: opens a client session to its first listen endpoint (0.0.0.0 -> 127.0.0.1): healthy
  if the router accepts it.

Exit status 0 healthy, 1 unhealthy (one line on stdout says why). Also usable on a host:
``soilocp-healthcheck --pid PID``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Optional

ROLES = ("service", "router")


def _read_proc(pid: int) -> tuple[list[str], dict[str, str]]:
    argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    env_raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    env = {}
    for item in env_raw:
        key, sep, value = item.decode(errors="replace").partition("=")
        if sep:
            env[key] = value
    return [a.decode(errors="replace") for a in argv if a], env


def soilocp_args(argv: list[str]) -> Optional[list[str]]:
    """The arguments after the ``soilocp`` program in ``argv`` if they start with a role, else None.

    Matches ``.../soilocp service gateway ...`` (console script, possibly run by a python) and
    ``python -m soilocp.cli router ...``.
    """
    for i, arg in enumerate(argv):
        is_prog = os.path.basename(arg) == "soilocp" or (arg == "soilocp.cli" and i > 0 and argv[i - 1] == "-m")
        if is_prog and i + 1 < len(argv) and argv[i + 1] in ROLES:
            return argv[i + 1:]
    return None


def find_process() -> tuple[int, list[str], dict[str, str]]:
    me = os.getpid()
    for entry in sorted(Path("/proc").iterdir(), key=lambda p: (len(p.name), p.name)):
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        try:
            argv, env = _read_proc(int(entry.name))
        except OSError:  # gone, or not ours
            continue
        args = soilocp_args(argv)
        if args is not None:
            return int(entry.name), args, env
    raise LookupError("no 'soilocp service|router' process in this container")


def _options(args: list[str]) -> dict[str, list[str]]:
    """Repeatable ``--opt value`` / ``--opt=value`` pairs of a soilocp command line."""
    out: dict[str, list[str]] = {}
    i = 0
    while i < len(args):
        arg = args[i]
        if arg.startswith("--"):
            name, eq, value = arg[2:].partition("=")
            if not eq and i + 1 < len(args):
                value = args[i + 1]
                i += 1
            out.setdefault(name, []).append(value)
        i += 1
    return out


def _client_config(connect: list[str], timeout_ms: int):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    conf.insert_json5("connect/timeout_ms", str(int(timeout_ms)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if any(ep.startswith("tls/") for ep in connect):  # the secure fleet router: the container's own certificate
        from soilocp.services.security.fleet_security import apply_tls, check_client_tls

        apply_tls(conf, check_client_tls(connect), listener=False)
    return conf


#: The services' default router endpoint (soilocp.services.runtime.config.DEFAULT_ENDPOINT), repeated here so
#: that the common case needs no pydantic import: a health check runs every few seconds in every
#: container, and its CPU time adds up on a small vehicle computer.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_VEHICLE_ID = "rover1"  # soilocp.services.runtime.config.ServiceConfig's default


def alive_key(vehicle_id: str, service: str) -> str:
    """``soilocp.schemas.keys.alive()`` (``soilocp/<vid>/alive/<service>``) without its pydantic import."""
    return f"soilocp/{vehicle_id}/alive/{service}"


def _split(text: str) -> list[str]:
    return [p.strip() for p in text.split(",") if p.strip()]


def settings_of(args: list[str], env: dict[str, str]) -> dict[str, list[str]]:
    """``vehicle_ids`` and ``connect`` (service) or ``listen`` (router) as the process sees them.

    Precedence as in the services: command line > environment > config file > defaults.  With a
    config file the services' own loaders decide (exactly); without one the same rules are
    applied here directly.
    """
    role, opts = args[0], _options(args[1:])
    config_path = (opts.get("config") or [None])[-1] or env.get("SOILOCP_CONFIG")
    if role == "router":
        if config_path:
            from soilocp.services.router import router_settings

            listen = router_settings(config_path, tuple(opts.get("listen", ())), (), env=env)["listen"]
        else:
            listen = opts.get("listen") or _split(env.get("SOILOCP_LISTEN", "")) or [DEFAULT_ENDPOINT]
        return {"listen": listen}
    name = args[1] if len(args) > 1 else ""
    if config_path:
        from soilocp.services.runtime.config import load_service_config

        overrides = {"vehicle_ids": opts.get("vehicle-id"), "connect": opts.get("connect")}
        cfg = load_service_config(name, config_path=config_path, overrides=overrides, env=env)
        return {"vehicle_ids": list(cfg.vehicle_ids), "connect": list(cfg.connect)}
    return {
        "vehicle_ids": opts.get("vehicle-id") or _split(env.get("SOILOCP_VEHICLE_ID", "")) or [DEFAULT_VEHICLE_ID],
        "connect": opts.get("connect") or _split(env.get("SOILOCP_CONNECT", "")) or [DEFAULT_ENDPOINT],
    }


def check(args: list[str], env: dict[str, str], timeout_s: float) -> tuple[bool, str]:
    import zenoh

    settings = settings_of(args, env)
    if args[0] == "router":
        ep = settings["listen"][0].replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]")
        try:
            with zenoh.open(_client_config([ep], int(timeout_s * 1000))):
                return True, f"router answers on {ep}"
        except zenoh.ZError as exc:
            return False, f"router does not answer on {ep}: {str(exc).splitlines()[0][:200]}"

    name, vids, connect = args[1], settings["vehicle_ids"], settings["connect"]
    try:
        session = zenoh.open(_client_config(connect, int(timeout_s * 1000)))
    except zenoh.ZError as exc:
        return False, f"{name}: its router {connect} does not answer: {str(exc).splitlines()[0][:200]}"
    with session:
        missing = []
        for vid in vids:
            key = alive_key(vid, name)
            if not any(r.ok is not None for r in session.liveliness().get(key, timeout=timeout_s)):
                missing.append(key)
    if missing:
        return False, f"{name}: no liveliness token {missing} via {connect}"
    return True, f"{name}: alive for {vids} via {connect}"


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pid", type=int, help="check this process instead of searching /proc")
    parser.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for Zenoh answers")
    a = parser.parse_args(argv)
    try:
        if a.pid is not None:
            raw, env = _read_proc(a.pid)
            args = soilocp_args(raw)
            if args is None:
                raise LookupError(f"process {a.pid} is not 'soilocp service|router': {' '.join(raw)[:200]}")
        else:
            _, args, env = find_process()
        ok, why = check(args, env, a.timeout)
    except Exception as exc:  # any failure to check is "unhealthy", with the reason
        ok, why = False, f"{type(exc).__name__}: {exc}"
    print(("healthy: " if ok else "unhealthy: ") + why)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
