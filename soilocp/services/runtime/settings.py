"""The settings every soilocp process shares, without pydantic: the environment variables, the
endpoint check, the config file reader and the Zenoh config with explicit endpoints (and mutual
TLS from the environment).

Split from :mod:`soilocp.services.runtime.config` (the services' pydantic ``ServiceConfig``) so that the
router, which needs only these, does not load pydantic and the message models (resident
memory; tests/test_lean_processes.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

#: Environment variables (documented in docs/services.md; deploy/ configs, units and images use them).
ENV_CONFIG = "SOILOCP_CONFIG"
ENV_VEHICLE_ID = "SOILOCP_VEHICLE_ID"
ENV_CONNECT = "SOILOCP_CONNECT"
ENV_LISTEN = "SOILOCP_LISTEN"
ENV_MODE = "SOILOCP_MODE"
ENV_LOG_LEVEL = "SOILOCP_LOG_LEVEL"
ENV_STALE_TIMEOUT = "SOILOCP_STALE_TIMEOUT"
#: Zenoh transport settings of a service's publishers and links (docs/performance.md, "Zenoh settings, chosen")
ENV_EXPRESS = "SOILOCP_EXPRESS"
ENV_BATCHING = "SOILOCP_BATCHING"
#: The soil-strength service starts its belief from this fleet soil map (a map id, or the JSON of MapPriorConfig)
ENV_MAP_PRIOR = "SOILOCP_MAP_PRIOR"
#: Set to 1 by ``soilocp run`` for its children: stop when the parent process goes away.
ENV_EXIT_WITH_PARENT = "SOILOCP_EXIT_WITH_PARENT"


class ConfigError(Exception):
    """A fatal configuration problem: the process prints one line and exits with status 2."""


def check_endpoint(ep: object) -> str:
    """A Zenoh locator ``proto/address`` (e.g. ``tcp/127.0.0.1:7447``); ValueError otherwise."""
    if not isinstance(ep, str) or "/" not in ep or ep.startswith("/") or ep.endswith("/") or any(c.isspace() for c in ep):
        raise ValueError(f"endpoint {ep!r} is invalid: expected 'proto/address', e.g. {DEFAULT_ENDPOINT}")
    return ep




def _split_list(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def env_settings(env: dict[str, str], lists: dict[str, str], words: dict[str, str]) -> dict[str, Any]:
    """Settings from the environment: ``lists`` maps a variable to a setting read as a
    comma-separated list, ``words`` to one read as a lower-case word; unset or empty is absent."""
    out: dict[str, Any] = {field: _split_list(env[var]) for var, field in lists.items() if env.get(var)}
    out.update({field: env[var].strip().lower() for var, field in words.items() if env.get(var)})
    return out


def _read_config_file(path: str) -> dict[str, Any]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"config file {path}: cannot read: {exc.strerror or exc}") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"config file {path}: not valid JSON: {exc.msg} at line {exc.lineno}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path}: top level must be a JSON object, got {type(data).__name__}")
    return data


def zenoh_config(
    mode: str, connect: list[str], listen: list[str], *, multicast: bool = False, connect_timeout_ms: Optional[int] = None,
    tls_from_environment: bool = True, batching: bool = True,
):
    """A ``zenoh.Config`` with explicit endpoints (multicast scouting off unless asked for);
    ``batching`` False: the links send each message in its own batch."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    if not batching:
        conf.insert_json5("transport/link/tx/queue/batching/enabled", "false")
    if connect_timeout_ms is not None:
        conf.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_ms)))
    # After a lost link (router restarted), retry quickly: the default backoff grows to several
    # seconds, far longer than the stale timeout of the OCP output.
    conf.insert_json5("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}")
    # Links that leave a vehicle are tls/ (mutual TLS, docs/deploy.md): the certificate comes from
    # SOILOCP_TLS_CA/_CERT/_KEY; plain tcp/ endpoints of the same process ignore it.
    from soilocp.services.security.fleet_security import apply_tls, tls_from_env

    if not tls_from_environment:  # the caller (the router) applies its own, file < environment
        return conf
    try:
        tls = tls_from_env()
        tls_eps = [ep for ep in [*connect, *listen] if ep.startswith("tls/")]
        if tls_eps and tls is None:
            raise ValueError(f"endpoints {tls_eps} use TLS but SOILOCP_TLS_CA, SOILOCP_TLS_CERT and "
                             "SOILOCP_TLS_KEY are not set")
        if tls is not None:
            apply_tls(conf, tls, listener=any(ep.startswith("tls/") for ep in listen))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return conf
