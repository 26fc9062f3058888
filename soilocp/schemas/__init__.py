"""Message contracts: a pydantic v2 model for every payload that crosses a process boundary.

Consumers in other languages use the JSON Schema files written by ``soilocp schemas export DIR``.

The models are re-exported lazily (PEP 562): ``soilocp.schemas.keys`` needs no pydantic, and the router,
which uses only the keys, must not build every model of the package (docs/performance.md, memory).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "SensorSample": "soilocp.schemas.sensor", "VEHICLE_ID_PATTERN": "soilocp.schemas.keys", "parse_sensor_line": "soilocp.schemas.sensor",
    "NormalForces": "soilocp.schemas.pipeline", "ObserverOutput": "soilocp.schemas.pipeline", "OcpEstimate": "soilocp.schemas.pipeline",
    "SoilEstimate": "soilocp.schemas.pipeline",
    "OcpReply": "soilocp.schemas.messages", "Rejection": "soilocp.schemas.messages", "ServiceHealth": "soilocp.schemas.messages",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'schemas' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
