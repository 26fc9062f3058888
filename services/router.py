"""``soilocp router``: a Zenoh router (a Python session in router mode is a real router).

The services of a vehicle connect to it (client mode); its ``connect`` endpoints link it to a
fleet router.  Default listen endpoint ``tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import os
import threading
from typing import Any, Optional

from .runtime import (DEFAULT_ENDPOINT, ENV_CONFIG, ENV_LISTEN, ENV_LOG_LEVEL, ConfigError, JsonLog,
                      _read_config_file, _split_list, check_endpoint, install_stop_handlers, watch_parent, zenoh_config)

#: The router's uplink (e.g. to a fleet router).  Not SOILOCP_CONNECT: in a shared environment that
#: names the router itself, for the services.
ENV_ROUTER_CONNECT = "SOILOCP_ROUTER_CONNECT"


def router_settings(config_path: Optional[str], listen: tuple[str, ...], connect: tuple[str, ...],
                    env: Optional[dict[str, str]] = None) -> dict[str, Any]:
    """listen/connect/multicast/log_level: defaults < file section ``router`` < env < command line."""
    env = dict(os.environ) if env is None else env
    out: dict[str, Any] = {"listen": [DEFAULT_ENDPOINT], "connect": [], "multicast": False, "log_level": "info"}
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
    if env.get(ENV_LISTEN):
        out["listen"] = _split_list(env[ENV_LISTEN])
    if env.get(ENV_ROUTER_CONNECT):
        out["connect"] = _split_list(env[ENV_ROUTER_CONNECT])
    if env.get(ENV_LOG_LEVEL):
        out["log_level"] = env[ENV_LOG_LEVEL].strip().lower()
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
    if out["log_level"] not in ("debug", "info", "warning", "error"):
        raise ConfigError(f"log_level={out['log_level']!r}: must be debug, info, warning or error")
    return out


def run_router(settings: dict[str, Any]) -> int:
    """Run the router until SIGINT/SIGTERM."""
    import zenoh

    log = JsonLog("router", settings["log_level"])
    stop = threading.Event()
    install_stop_handlers(stop, log)
    watch_parent(stop, log)
    conf = zenoh_config("router", settings["connect"], settings["listen"], multicast=settings["multicast"])
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ConfigError(f"router: cannot listen on {settings['listen']}: {str(exc).splitlines()[0][:200]}") from None
    try:
        log.info("running", listen=settings["listen"], connect=settings["connect"], zid=str(session.zid()),
                 pid=os.getpid())
        while not stop.wait(0.2):
            pass
    finally:
        session.close()
        log.info("stopped")
    return 0
