"""Service configuration: defaults < file < environment < command line, and the Zenoh config
with explicit endpoints (and mutual TLS from the environment) that every process opens."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from schemas.sensor import VehicleId

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


def _check_endpoints(value: list[str]) -> list[str]:
    for ep in value:
        check_endpoint(ep)
    return value


#: A ``connect`` / ``listen`` list of endpoints, each checked (:func:`check_endpoint`); every process's settings
Endpoints = Annotated[list[str], AfterValidator(_check_endpoints)]


class MapPriorConfig(BaseModel):
    """Opt-in: the soil-strength service asks this fleet soil map for the cells around the vehicle
    and starts its belief from a cell's K and band when the vehicle enters it (docs/map.md §4)."""

    model_config = ConfigDict(extra="forbid")

    map_id: str = Field(pattern=r"^[A-Za-z0-9_-]{1,64}$", description="The map service's id (soilmap/<map_id>/...)")
    radius_m: float = Field(200.0, gt=0, le=100_000, description="Half-side of the box asked around the vehicle, m")
    refresh_s: float = Field(10.0, gt=0, le=3600, description="Ask again this often (new cells), or on leaving "
                             "the middle half of the last box")
    min_count: int = Field(1, ge=1, description="A cell seen by fewer estimates is not trusted")
    cell_size: float = Field(5.0, ge=0.1, le=10_000, description="The map's square cell side, m (its --cell-size)")
    h3_resolution: int = Field(12, ge=0, le=15, description="The map's H3 resolution (its --h3-resolution)")
    timeout_s: float = Field(2.0, gt=0, le=60, description="Wait this long for the map service's reply")


class ServiceConfig(BaseModel):
    """Settings of one service process (file < environment < command line)."""

    model_config = ConfigDict(extra="forbid")

    vehicle_ids: list[VehicleId] = Field(default_factory=lambda: ["rover1"], min_length=1)
    mode: Literal["client", "peer"] = "client"
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    listen: Endpoints = Field(default_factory=list)
    multicast: bool = Field(False, description="Zenoh multicast scouting (off: explicit endpoints only)")
    express: bool = Field(False, description="Zenoh: pipeline publishers send each message at once, never "
                          "batched with others (docs/performance.md, 'Zenoh settings, chosen')")
    batching: bool = Field(True, description="Zenoh: the links may batch messages queued together "
                           "(transport/link/tx/queue/batching; docs/performance.md)")
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    stale_timeout_s: float = Field(0.5, gt=0, le=3600, description="OCP publisher: stale after this much silence")
    queue_size: int = Field(4096, ge=1, le=1_000_000, description="Worker queue bound; beyond it inputs are dropped")
    join_buffer: int = Field(256, ge=1, le=100_000, description="Observer: samples waiting for their normal forces")
    join_timeout_s: float = Field(0.2, gt=0, description="Observer: give up on a sample's normal forces after this")
    history_size: int = Field(1000, ge=1, le=1_000_000, description="OCP publisher: estimates kept for ?last / ?since")
    status_period_s: float = Field(1.0, gt=0, le=3600, description="Period of the health publication")
    max_payload_bytes: int = Field(4096, ge=256, description="Gateway: larger raw payloads are rejected before "
                                   "parsing (4 KiB: 5x the largest valid sample; services.stages.gateway)")
    connect_retry_s: float = Field(1.0, gt=0, le=60, description="Client: wait per connection attempt to the router")
    pipeline_config: Optional[str] = Field(None, description="Path of the physics PipelineConfig file (null: defaults)")
    map_prior: Optional[MapPriorConfig] = Field(None, description="Soil-strength: start the belief from a fleet "
                                                "soil map (opt-in; env SOILOCP_MAP_PRIOR)")

    @property
    def vehicle_id(self) -> str:
        return self.vehicle_ids[0]


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


def _file_section(data: dict[str, Any], service: str, path: str) -> dict[str, Any]:
    """Merge a deployment file's common keys with its ``services.<service>`` section.

    ``vehicle_id`` (one id) is accepted as a shorthand for ``vehicle_ids``; the ``router`` and
    ``services`` sections belong to other processes and are skipped here.
    """
    out = {k: v for k, v in data.items() if k not in ("services", "router", "$comment")}
    sections = data.get("services", {})
    if not isinstance(sections, dict):
        raise ConfigError(f"config file {path}: 'services' must be an object of per-service sections")
    own = sections.get(service, {})
    if not isinstance(own, dict):
        raise ConfigError(f"config file {path}: 'services.{service}' must be an object")
    out.update(own)
    if "vehicle_id" in out:
        vid = out.pop("vehicle_id")
        out["vehicle_ids"] = vid if isinstance(vid, list) else [vid]
    return out


def load_service_config(
    service: str,
    *,
    config_path: Optional[str] = None,
    overrides: Optional[dict[str, Any]] = None,
    env: Optional[dict[str, str]] = None,
) -> ServiceConfig:
    """Build a :class:`ServiceConfig`: defaults < file < environment < ``overrides`` (command line).

    The file is ``config_path`` or ``$SOILOCP_CONFIG``.  Raises :class:`ConfigError` with a
    one-line message naming the setting, its value and the reason.
    """
    env = dict(os.environ) if env is None else env
    values: dict[str, Any] = {}
    path = config_path or env.get(ENV_CONFIG) or None
    if path:
        values.update(_file_section(_read_config_file(path), service, path))
    values.update(env_settings(env, {ENV_VEHICLE_ID: "vehicle_ids", ENV_CONNECT: "connect", ENV_LISTEN: "listen"},
                               {ENV_MODE: "mode", ENV_LOG_LEVEL: "log_level", ENV_EXPRESS: "express",
                                ENV_BATCHING: "batching"}))
    if env.get(ENV_STALE_TIMEOUT):
        raw = env[ENV_STALE_TIMEOUT].strip()
        try:
            values["stale_timeout_s"] = float(raw)
        except ValueError:
            raise ConfigError(f"{ENV_STALE_TIMEOUT}={raw!r} is not a number of seconds") from None
    if env.get(ENV_MAP_PRIOR, "").strip():
        raw = env[ENV_MAP_PRIOR].strip()
        if raw.startswith("{"):
            try:
                values["map_prior"] = json.loads(raw)
            except json.JSONDecodeError as exc:
                raise ConfigError(f"{ENV_MAP_PRIOR}: not valid JSON: {exc.msg}") from None
        else:
            values["map_prior"] = {"map_id": raw}
    for k, v in (overrides or {}).items():
        if v is not None and v != () and v != []:
            values[k] = list(v) if isinstance(v, tuple) else v
    try:
        return ServiceConfig.model_validate(values)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in err.get("loc", ())) or "<config>"
        raise ConfigError(
            f"invalid setting {loc}={err.get('input')!r} for service {service}: {err.get('msg')}"
            + (f" (config file {path})" if path else "")
        ) from None


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
    from services.security.fleet_security import apply_tls, tls_from_env

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
