"""Service configuration: defaults < file < environment < command line (pydantic ``ServiceConfig``).

The pydantic-free settings (environment variables, endpoints, the config file reader and the Zenoh
config every process opens) live in :mod:`soilocp.services.runtime.settings` and are re-exported here."""

from __future__ import annotations

import json
import os
from typing import Annotated, Any, Literal, Optional

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from soilocp.schemas.sensor import VehicleId
from soilocp.validation import MAX_PAYLOAD_BYTES
from soilocp.services.runtime.settings import (  # noqa: F401  (re-exported: the services' settings in one import)
    DEFAULT_ENDPOINT, ENV_BATCHING, ENV_CONFIG, ENV_CONNECT, ENV_EXIT_WITH_PARENT, ENV_EXPRESS, ENV_LISTEN,
    ENV_LOG_LEVEL, ENV_MAP_PRIOR, ENV_MODE, ENV_STALE_TIMEOUT, ENV_VEHICLE_ID, ConfigError, _read_config_file,
    _split_list, check_endpoint, env_settings, zenoh_config)


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

    vehicle_ids: list[VehicleId] = Field(default_factory=lambda: ["rover1"], min_length=1,
                                        description="Vehicle ids this process serves")
    mode: Literal["client", "peer"] = Field("client", description="Zenoh mode: client (every link through the "
                                         "router) or peer (direct links between the processes; the router "
                                         "introduces them)")
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT],
                               description="Zenoh endpoints to connect to, proto/address")
    listen: Endpoints = Field(default_factory=list, description="Zenoh endpoints to listen on, proto/address "
                              "(peer mode)")
    multicast: bool = Field(False, description="Zenoh multicast scouting (off: explicit endpoints only)")
    express: bool = Field(False, description="Zenoh: pipeline publishers send each message at once, never "
                          "batched with others (docs/performance.md, 'Zenoh settings, chosen')")
    batching: bool = Field(True, description="Zenoh: the links may batch messages queued together "
                           "(transport/link/tx/queue/batching; docs/performance.md)")
    log_level: Literal["debug", "info", "warning", "error"] = Field("info", description="Lowest level of the "
                                                                   "messages the process logs")
    stale_timeout_s: float = Field(0.5, gt=0, le=3600, description="OCP publisher: stale after this much silence")
    queue_size: int = Field(4096, ge=1, le=1_000_000, description="Worker queue bound; beyond it inputs are dropped")
    join_buffer: int = Field(256, ge=1, le=100_000, description="Observer: samples waiting for their normal forces")
    join_timeout_s: float = Field(0.2, gt=0, description="Observer: give up on a sample's normal forces after this")
    soil_feed_timeout_s: float = Field(0.5, gt=0, description="Observer, when the torque scale models the motion "
                                       "resistance at the soil's K: wait at most this long, s, for the soil estimate "
                                       "of the sample before, then step with the last K")
    history_size: int = Field(1000, ge=1, le=1_000_000, description="OCP publisher: estimates kept for ?last / ?since")
    status_period_s: float = Field(1.0, gt=0, le=3600, description="Period of the health publication")
    max_payload_bytes: int = Field(MAX_PAYLOAD_BYTES, ge=256, description="Gateway: larger raw payloads are "
                                   "rejected before parsing (4 KiB: 5x the largest valid sample; the limit of "
                                   "soilocp estimate, soilocp.validation.MAX_PAYLOAD_BYTES)")
    connect_retry_s: float = Field(1.0, gt=0, le=60, description="Client: wait per connection attempt to the router")
    pipeline_config: Optional[str] = Field(None, description="Path of the physics PipelineConfig file (null: defaults)")
    map_prior: Optional[MapPriorConfig] = Field(None, description="Soil-strength: start the belief from a fleet "
                                                "soil map (opt-in; env SOILOCP_MAP_PRIOR)")

    @property
    def vehicle_id(self) -> str:
        return self.vehicle_ids[0]


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


