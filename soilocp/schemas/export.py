"""JSON Schema export of every message that crosses a process boundary.

``soilocp schemas export DIR`` writes one ``<Title>.schema.json`` per model.  Versioned models
carry ``schema_version`` (a const) and an ``$id`` ``soilocp.<name>/<version>``; the raw
SensorSample has no version field by contract and is versioned by its ``$id`` alone.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from pydantic import BaseModel

from soilocp.schemas.map import MapCellUpdate, MapQueryReply, MapRejection, MapStatus
from soilocp.schemas.messages import (DriveSetpoint, OcpReply, Rejection, ServiceHealth, SlipSetpoint,
                                      SupervisorStatus)
from soilocp.schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SENSOR_SCHEMA_ID, SensorSample

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

#: Every message model, with the key(s) it travels on (documentation for consumers).
MESSAGE_MODELS: dict[type[BaseModel], str] = {
    SensorSample: "soilocp/<vid>/sensors/raw, soilocp/<vid>/sensors/clean",
    NormalForces: "soilocp/<vid>/normal_forces",
    ObserverOutput: "soilocp/<vid>/observer",
    SoilEstimate: "soilocp/<vid>/soil",
    OcpEstimate: "soilocp/<vid>/ocp (publication)",
    OcpReply: "soilocp/<vid>/ocp (queryable reply)",
    SlipSetpoint: "soilocp/<vid>/control/slip",
    DriveSetpoint: "soilocp/<vid>/control/drive",
    Rejection: "soilocp/<vid>/rejected",
    ServiceHealth: "soilocp/<vid>/status/<service> (publication and queryable reply)",
    SupervisorStatus: "soilocp/<vid>/supervisor (publication and queryable reply)",
    MapCellUpdate: "soilmap/<map_id>/cells",
    MapQueryReply: "soilmap/<map_id>/query (queryable reply)",
    MapRejection: "soilmap/<map_id>/rejected",
    MapStatus: "soilmap/<map_id>/status (publication and queryable reply)",
}


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def schema_id(model: type[BaseModel]) -> str:
    """``$id`` of a model: SensorSample's contract id, else ``soilocp.<snake_name>/<schema_version>``."""
    if model is SensorSample:
        return SENSOR_SCHEMA_ID
    field = model.model_fields.get("schema_version")
    if field is None:
        raise ValueError(f"model {model.__name__} has no schema_version field: every message must be versioned")
    return f"soilocp.{_snake(model.__name__)}/{field.default}"


def json_schema(model: type[BaseModel]) -> dict:
    """The model's JSON Schema (validation mode), with ``$schema``, ``$id`` and the key it travels on."""
    schema = model.model_json_schema(mode="validation")
    out = {"$schema": JSON_SCHEMA_DIALECT, "$id": schema_id(model)}
    out.update({k: v for k, v in schema.items() if k != "$id"})
    out["x-soilocp-keys"] = MESSAGE_MODELS[model]
    return out


def export_schemas(directory: str | Path) -> list[Path]:
    """Write one ``<Title>.schema.json`` per message model into ``directory``; returns the paths."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for model in MESSAGE_MODELS:
        p = d / f"{model.__name__}.schema.json"
        p.write_text(json.dumps(json_schema(model), indent=2, sort_keys=False) + "\n", encoding="utf-8")
        paths.append(p)
    return paths
