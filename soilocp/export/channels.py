"""The Foxglove channels of soilocp: topics, JSON schemas and messages, one definition for the MCAP
export (:mod:`soilocp.export.mcap_out`) and the live WebSocket server (``services/io/foxglove_live``).

Per vehicle, JSON messages with JSON schemas, log time = the sensor sample's stamp (Unix ns when the
source had Unix header stamps, so the estimates line up with the robot's bag in Foxglove's timeline):

Estimate channels (from one OCP record, ``soilocp.schemas.pipeline.OcpEstimate``):

* ``/soilocp/<vid>/soil_strength``: K, its 1-sigma, K - std and K + std (plot all three), class,
  class probability, status, reason;
* ``/soilocp/<vid>/ocp``: mu_T, S_T, S_E, tractive efficiency at S_E, status;
* ``/soilocp/<vid>/wheels``: per-wheel slip (eq. 1) and net traction mu (eq. 6), wheels 1..4
  (LR, LF, RF, RR), plus their names;
* ``/soilocp/<vid>/status``: status and reason only (for a state-transitions panel).

Sensor channel (from one ``soilocp.schemas.sensor.SensorSample``):

* ``/soilocp/<vid>/sensors``: the sample as the robot sent it (specific force, roll, pitch, yaw
  rate, wheel speeds and torques, ground speed).

Fleet soil map channel (from a map's cells, :mod:`soilocp.map.grid`):

* ``/soilmap/<map_id>/<frame>/grid``: ``foxglove.Grid`` (protobuf, the SDK's schema) of one local
  frame's cells, fields mu_T, K, K_lo, K_hi, log_k_std, for the 3D panel and planners.
"""

from __future__ import annotations

import json

NS = 1_000_000_000
WHEEL_NAMES = ["1 left-rear", "2 left-front", "3 right-front", "4 right-rear"]

_NUM = {"type": ["number", "null"]}
_STR = {"type": ["string", "null"]}
_BASE = {"vehicle_id": {"type": "string"}, "seq": {"type": "integer"}, "stamp": {"type": "number", "description": "s"}}


def _array(n: int, item: str = "number", description: str = "") -> dict:
    out = {"type": "array", "items": {"type": item}, "minItems": n, "maxItems": n}
    if description:
        out["description"] = description
    return out


def _schema(title: str, props: dict, description: str) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": {**_BASE, **props}, "required": list(_BASE) + list(props)}


#: The channels made from one OCP record.
ESTIMATE_CHANNELS = ("soil_strength", "ocp", "wheels", "status")
#: The channels made from one sensor sample (the MCAP export and the live server both carry them).
SENSOR_CHANNELS = ("sensors",)

#: channel suffix -> (schema name, JSON schema)
CHANNEL_SCHEMAS: dict[str, tuple[str, dict]] = {
    "soil_strength": ("soilocp.SoilStrength", _schema("SoilStrength", {
        "K": _NUM, "K_std": _NUM, "K_minus_std": _NUM, "K_plus_std": _NUM,
        "soil_class": _STR, "soil_class_confidence": _NUM, "status": {"type": "string"}, "reason": {"type": "string"},
    }, "Soil strength K (null: no estimate) with its 1-sigma band")),
    "ocp": ("soilocp.Ocp", _schema("Ocp", {
        "mu_T": _NUM, "S_T": _NUM, "S_E": _NUM, "te_at_S_E": _NUM, "status": {"type": "string"},
    }, "Optimal control parameters: max traction mu_T (eq. 8), its slip S_T (eq. 7), best-efficiency slip S_E (eq. 10)")),
    "wheels": ("soilocp.Wheels", _schema("Wheels", {
        "slip": _array(4),
        "traction": _array(4),
        "wheel_names": {"type": "array", "items": {"type": "string"}},
    }, "Per-wheel slip (eq. 1) and net traction coefficient mu (eq. 6), wheels 1..4")),
    "status": ("soilocp.Status", _schema("Status", {"status": {"type": "string"}, "reason": {"type": "string"}},
                                         "Estimate status: ok | uncertain | holding | no_estimate | stale")),
    "sensors": ("soilocp.Sensors", _schema("Sensors", {
        "specific_force": _array(3, description="m/s^2, body frame x forward, y left, z up"),
        "roll": {"type": "number", "description": "rad"},
        "pitch": {"type": "number", "description": "rad, > 0 nose down"},
        "yaw_rate": {"type": "number", "description": "rad/s"},
        "wheel_speed": _array(4, description="rad/s, wheels 1..4"),
        "wheel_torque": _array(4, description="N m, wheels 1..4"),
        "ground_speed": {"type": ["number", "null"], "description": "m/s (null: no ground-speed sensor)"},
    }, "The robot's sensor sample (soilocp.schemas.sensor.SensorSample)")),
}


def topic(vehicle_id: str, suffix: str) -> str:
    return f"/soilocp/{vehicle_id}/{suffix}"


def topics(vehicle_id: str, suffixes=ESTIMATE_CHANNELS + SENSOR_CHANNELS) -> list[str]:
    """The topics of one vehicle (every channel by default)."""
    return [topic(vehicle_id, s) for s in suffixes]


def log_time_ns(stamp: float) -> int:
    """A message's log time: the sample's own stamp, in ns."""
    return int(round(float(stamp) * NS))


def encode(message: dict) -> bytes:
    """The bytes of one JSON message, as both the MCAP file and the WebSocket carry them."""
    return json.dumps(message).encode()


def split_estimate(rec: dict) -> dict[str, dict]:
    """One OCP record (soilocp.schemas.pipeline.OcpEstimate as a dict) -> the message of each estimate channel."""
    base = {"vehicle_id": rec["vehicle_id"], "seq": rec["seq"], "stamp": rec["stamp"]}
    k, sd = rec.get("soil_strength"), rec.get("soil_strength_std")
    band = k is not None and sd is not None
    status, reason = rec.get("status", ""), rec.get("reason", "")
    return {
        "soil_strength": {**base, "K": k, "K_std": sd, "K_minus_std": k - sd if band else None,
                          "K_plus_std": k + sd if band else None, "soil_class": rec.get("soil_class"),
                          "soil_class_confidence": rec.get("soil_class_confidence"), "status": status, "reason": reason},
        "ocp": {**base, "mu_T": rec.get("mu_T"), "S_T": rec.get("S_T"), "S_E": rec.get("S_E"),
                "te_at_S_E": rec.get("te_at_S_E"), "status": status},
        "wheels": {**base, "slip": list(rec["slip"]), "traction": list(rec["mu"]), "wheel_names": WHEEL_NAMES},
        "status": {**base, "status": status, "reason": reason},
    }


def split_sensor(sample: dict) -> dict[str, dict]:
    """One sensor sample (soilocp.schemas.sensor.SensorSample as a dict) -> the message of each sensor channel."""
    return {"sensors": {
        "vehicle_id": sample["vehicle_id"], "seq": sample["seq"], "stamp": sample["stamp"],
        "specific_force": list(sample["specific_force"]), "roll": sample["roll"], "pitch": sample["pitch"],
        "yaw_rate": sample["yaw_rate"], "wheel_speed": list(sample["wheel_speed"]),
        "wheel_torque": list(sample["wheel_torque"]), "ground_speed": sample["ground_speed"],
    }}


def map_grid_topic(map_id: str, frame: str) -> str:
    """The fleet soil map's grid of one local frame (``foxglove.Grid``, protobuf)."""
    return f"/soilmap/{map_id}/{frame}/grid"


def map_grid_message(r, stamp: float):
    """A :class:`soilocp.map.grid.MapRaster` as a ``foxglove.Grid`` (the SDK's message; ``.encode()``
    gives its protobuf bytes, ``Grid.get_schema()`` the schema): float32 fields mu_T, K, K_lo, K_hi,
    log_k_std per cell, NaN where the map holds no cell, frame_id = the map frame."""
    from foxglove.messages import (Grid, PackedElementField, PackedElementFieldNumericType, Pose, Quaternion,
                                   Timestamp, Vector2, Vector3)

    from soilocp.map.grid import FIELDS

    rows, cols, nf = r.values.shape
    sec = int(stamp // 1)
    return Grid(
        timestamp=Timestamp(sec=sec, nsec=int(round((stamp - sec) * NS)) % NS), frame_id=r.frame,
        pose=Pose(position=Vector3(x=r.origin[0], y=r.origin[1], z=0.0), orientation=Quaternion(x=0, y=0, z=0, w=1)),
        column_count=cols, cell_size=Vector2(x=r.cell_size, y=r.cell_size), row_stride=cols * nf * 4, cell_stride=nf * 4,
        fields=[PackedElementField(name=n, offset=4 * i, type=PackedElementFieldNumericType.Float32)
                for i, n in enumerate(FIELDS)],
        data=r.values.astype("<f4").tobytes())

