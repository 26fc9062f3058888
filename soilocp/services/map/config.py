"""Settings of one map service: defaults < JSON file < environment < command line."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field

from soilocp.schemas.map import MAP_ID_PATTERN

from soilocp.services.runtime.config import DEFAULT_ENDPOINT, ConfigError, Endpoints, env_settings, validated
from soilocp.map.cells import CellConfig
from soilocp.map.fusion import FusionConfig

ENV_MAP_STORE = "SOILOCP_MAP_STORE"
ENV_MAP_ID = "SOILOCP_MAP_ID"


class MapServiceConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    map_id: str = Field("fleet", pattern=MAP_ID_PATTERN, description="This map's id: its keys are soilmap/<map_id>/...")
    store: str = Field("soilmap.db", description="sqlite:PATH (or a path) or postgresql://user@host/db")
    mode: Literal["client", "peer"] = "client"
    connect: Endpoints = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    listen: Endpoints = Field(default_factory=list)
    multicast: bool = False
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    cells: CellConfig = Field(default_factory=CellConfig)
    fusion: FusionConfig = Field(default_factory=FusionConfig)
    queue_size: int = Field(200_000, ge=1, le=10_000_000, description="Estimates waiting for the worker; beyond: dropped")
    batch_max: int = Field(5000, ge=1, le=1_000_000, description="Estimates per committed transaction at most")
    batch_wait_s: float = Field(0.05, ge=0, le=10, description="Wait this long for more estimates before a commit")
    query_limit: int = Field(50_000, ge=1, description="Cells per query reply at most")
    status_period_s: float = Field(1.0, gt=0, le=3600)
    connect_retry_s: float = Field(1.0, gt=0, le=60)


def load_map_config(config_path: Optional[str], overrides: dict[str, Any],
                    env: Optional[dict[str, str]] = None) -> MapServiceConfig:
    """The map service's settings; ConfigError names the setting, the value and the reason."""
    env = dict(os.environ) if env is None else env
    values: dict[str, Any] = {}
    if config_path:
        try:
            data = json.loads(Path(config_path).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"config file {config_path}: cannot read: {exc.strerror or exc}") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f"config file {config_path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None
        if not isinstance(data, dict):
            raise ConfigError(f"config file {config_path}: top level must be a JSON object")
        values.update(data)
    values.update(env_settings(env, {"SOILOCP_CONNECT": "connect", "SOILOCP_LISTEN": "listen"},
                               {"SOILOCP_MODE": "mode", "SOILOCP_LOG_LEVEL": "log_level"}))
    if env.get(ENV_MAP_STORE):
        values["store"] = env[ENV_MAP_STORE].strip()
    if env.get(ENV_MAP_ID):
        values["map_id"] = env[ENV_MAP_ID].strip()
    for k, v in overrides.items():
        if v is None or v == () or v == []:
            continue
        if k in ("cell_size", "h3_resolution"):
            values["cells"] = {**values.get("cells", {}), k: v}
        elif k == "ageing_rate":
            values["fusion"] = {**values.get("fusion", {}), k: v}
        else:
            values[k] = list(v) if isinstance(v, tuple) else v
    return validated(MapServiceConfig, values, "the map service")
