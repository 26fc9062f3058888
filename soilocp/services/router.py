"""``soilocp router``: a Zenoh router (a Python session in router mode is a real router).

The services of a vehicle connect to it (client mode); its ``connect`` endpoints link it to a
fleet router.  Default listen endpoint ``tcp/127.0.0.1:7447``.

The router process starts through :data:`process_main` (``soilocp.cli.entry``) and imports neither
pydantic nor the message models: it only forwards bytes (tests/test_lean_processes.py).
"""

from __future__ import annotations

import os
import threading
from typing import Any, Optional

import click

from soilocp.services.security.fleet_security import (ENV_FLEET_MAPS, ENV_FLEET_TOOLS, ENV_FLEET_VEHICLES, ENV_TLS_CA, ENV_TLS_CERT, ENV_TLS_KEY, TlsFiles,
                             apply_access_control, apply_fleet_link_qos, apply_tls, fleet_access_control,
                             tls_from_env)
from soilocp.services.runtime.settings import ConfigError, DEFAULT_ENDPOINT, ENV_BATCHING, ENV_CONFIG, ENV_LISTEN, ENV_LOG_LEVEL, _read_config_file, _split_list, check_endpoint, env_settings, zenoh_config
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.process import exit_now, fatal, install_stop_handlers, watch_parent

#: The router's uplink (e.g. to a fleet router).  Not SOILOCP_CONNECT: in a shared environment that
#: names the router itself, for the services.
ENV_ROUTER_CONNECT = "SOILOCP_ROUTER_CONNECT"


def router_settings(config_path: Optional[str], listen: tuple[str, ...], connect: tuple[str, ...],
                    env: Optional[dict[str, str]] = None) -> dict[str, Any]:
    """listen/connect/multicast/log_level/batching: defaults < file section ``router`` < env < command line."""
    env = dict(os.environ) if env is None else env
    out: dict[str, Any] = {"listen": [DEFAULT_ENDPOINT], "connect": [], "multicast": False, "log_level": "info",
                           "batching": True, "tls": None, "access_control": None}
    path = config_path or env.get(ENV_CONFIG)
    if path:
        data = _read_config_file(path)
        section = data.get("router", {})
        if not isinstance(section, dict):
            raise ConfigError(f"config file {path}: 'router' must be an object")
        unknown = set(section) - set(out)
        if unknown:
            raise ConfigError(f"config file {path}: unknown router setting(s) {sorted(unknown)}")
        out.update(section)
        if "log_level" in data and "log_level" not in section:
            out["log_level"] = data["log_level"]
    out.update(env_settings(env, {ENV_LISTEN: "listen", ENV_ROUTER_CONNECT: "connect"},
                            {ENV_LOG_LEVEL: "log_level", ENV_BATCHING: "batching"}))
    out["batching"] = _flag("batching", out["batching"])
    _security_settings(out, env)
    if listen:
        out["listen"] = list(listen)
    if connect:
        out["connect"] = list(connect)
    for name in ("listen", "connect"):
        if not isinstance(out[name], list):
            raise ConfigError(f"router setting {name}={out[name]!r}: must be a list of endpoints")
        for ep in out[name]:
            try:
                check_endpoint(ep)
            except ValueError as exc:
                raise ConfigError(f"router setting {name}: {exc}") from None
    if not out["listen"]:
        raise ConfigError("router setting listen: at least one endpoint is needed")
    tls_eps = [ep for ep in out["listen"] + out["connect"] if ep.startswith("tls/")]
    if tls_eps and out["tls"] is None:
        raise ConfigError(f"router endpoints {tls_eps} use TLS but no certificate is set: give router.tls "
                          f"{{ca, cert, key}} in the config file or {ENV_TLS_CA}, {ENV_TLS_CERT}, {ENV_TLS_KEY}")
    if out["access_control"] is not None and not any(ep.startswith("tls/") for ep in out["listen"]):
        raise ConfigError(f"router: access control identifies vehicles and tools by their TLS certificate, but it "
                          f"listens on {out['listen']} without tls/: every link would match no policy and be denied")
    if out["tls"] is not None:
        try:
            out["tls"].check()
        except ValueError as exc:
            raise ConfigError(f"router: {exc}") from None
    if out["log_level"] not in ("debug", "info", "warning", "error"):
        raise ConfigError(f"log_level={out['log_level']!r}: must be debug, info, warning or error")
    return out


_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def _flag(name: str, value: Any) -> bool:
    """A yes/no router setting from the file (a JSON boolean) or the environment (a word)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in _TRUE + _FALSE:
        return value.strip().lower() in _TRUE
    raise ConfigError(f"router setting {name}={value!r}: must be true or false")


def _security_settings(out: dict[str, Any], env: dict[str, str]) -> None:
    """``tls`` {ca, cert, key} and ``access_control`` {vehicles, tools}: file < environment."""
    section = out["tls"]
    tls = None
    if section is not None:
        if not isinstance(section, dict) or set(section) != {"ca", "cert", "key"}:
            raise ConfigError(f"router setting tls={section!r}: must be an object with exactly ca, cert and key (paths)")
        tls = TlsFiles(str(section["ca"]), str(section["cert"]), str(section["key"]))
    try:
        tls = tls_from_env(env) or tls
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    out["tls"] = tls
    acl = out["access_control"]
    if acl is None and not env.get(ENV_FLEET_VEHICLES):
        return
    acl = dict(acl or {})
    unknown = set(acl) - {"vehicles", "tools", "maps"}
    if unknown:
        raise ConfigError(f"router setting access_control: unknown key(s) {sorted(unknown)} (vehicles, tools, maps)")
    if env.get(ENV_FLEET_VEHICLES):
        acl["vehicles"] = _split_list(env[ENV_FLEET_VEHICLES])
    if env.get(ENV_FLEET_TOOLS):
        acl["tools"] = _split_list(env[ENV_FLEET_TOOLS])
    if env.get(ENV_FLEET_MAPS):  # the fleet soil map's services (docs/map.md)
        acl["maps"] = _split_list(env[ENV_FLEET_MAPS])
    acl.setdefault("vehicles", [])
    acl.setdefault("tools", ["dashboard"])
    try:
        fleet_access_control(acl["vehicles"], acl["tools"], acl.get("maps", ()))
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"router setting access_control: {exc}") from None
    out["access_control"] = {"vehicles": list(acl["vehicles"]), "tools": list(acl["tools"])}
    if acl.get("maps"):
        out["access_control"]["maps"] = list(acl["maps"])


def run_router(settings: dict[str, Any]) -> int:
    """Run the router until SIGINT/SIGTERM."""
    import zenoh

    log = JsonLog("router", settings["log_level"])
    stop = threading.Event()
    install_stop_handlers(stop, log)
    watch_parent(stop, log)
    conf = zenoh_config("router", settings["connect"], settings["listen"], multicast=settings["multicast"],
                        tls_from_environment=False, batching=settings.get("batching", True))
    if settings.get("tls") is not None:
        apply_tls(conf, settings["tls"], listener=any(ep.startswith("tls/") for ep in settings["listen"]))
        apply_fleet_link_qos(conf)
    if settings.get("access_control") is not None:
        apply_access_control(conf, settings["access_control"]["vehicles"], settings["access_control"]["tools"],
                             settings["access_control"].get("maps", ()))
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ConfigError(f"router: cannot listen on {settings['listen']}: {str(exc).splitlines()[0][:200]}") from None
    try:
        acl = settings.get("access_control")
        log.info("running", listen=settings["listen"], connect=settings["connect"], zid=str(session.zid()),
                 pid=os.getpid(), tls=settings.get("tls") is not None,
                 access_control=None if acl is None else {"vehicles": acl["vehicles"], "tools": acl["tools"]})
        while not stop.wait(0.2):
            pass
    finally:
        session.close()
        log.info("stopped")
    return 0


@click.command("router")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="Deployment config; its 'router' section.")
@click.option("--listen", multiple=True, help="Endpoint to listen on (repeatable); default tcp/127.0.0.1:7447; env SOILOCP_LISTEN.")
@click.option("--connect", multiple=True, help="Endpoint of another router, e.g. a fleet router; env SOILOCP_ROUTER_CONNECT.")
def router_cmd(config_path, listen, connect) -> None:
    """Run a Zenoh router for the vehicle's services until SIGINT/SIGTERM."""
    try:
        exit_now(run_router(router_settings(config_path, listen, connect)))
    except ConfigError as exc:
        fatal("soilocp router", str(exc))


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def process_main() -> None:
    """soilocp: the router process."""


process_main.add_command(router_cmd)
