"""The live Zenoh streams that become the Foxglove channels, for the two tools that take them off
the bus, ``soilocp foxglove`` (serves them) and ``soilocp record`` (writes them to MCAP): which key
each stream is on, and each payload checked against its contract before it is served or written."""

from __future__ import annotations

from typing import Iterable

from soilocp.schemas import keys
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.schemas.sensor import parse_sensor_line
from soilocp.export.channels import ESTIMATE_CHANNELS, SENSOR_CHANNELS

#: stream -> (key builder per vehicle, fleet selector, the channels one payload makes)
STREAMS = {
    "ocp": (keys.ocp, keys.any_vehicle_ocp, ESTIMATE_CHANNELS),
    "sensors": (keys.raw, keys.any_vehicle_raw, SENSOR_CHANNELS),
}


def selectors(vehicle_ids: Iterable[str]) -> list[tuple[str, str]]:
    """(stream, key expression) to subscribe to: those vehicles' keys, or every vehicle's if none."""
    vids = list(vehicle_ids)
    return [(kind, sel) for kind, (per_vehicle, fleet, _channels) in STREAMS.items()
            for sel in ([per_vehicle(v) for v in vids] or [fleet()])]


def decode(kind: str, key: str, payload: bytes) -> dict:
    """The payload of stream ``kind`` on ``key`` as its contract's dict (``OcpEstimate``,
    ``SensorSample``); ValueError says why not, also when its vehicle id is not the key's."""
    vid, _rest = keys.split_key(key)
    if kind == "ocp":
        data = OcpEstimate.model_validate_json(payload).model_dump()
    else:
        data = parse_sensor_line(payload).model_dump()
    if data["vehicle_id"] != vid:
        raise ValueError(f"vehicle_id {data['vehicle_id']!r} on the key of vehicle {vid!r}")
    return data
