"""Message contracts: a pydantic v2 model for every payload that crosses a process boundary.

Consumers in other languages use the JSON Schema files written by ``soilocp schemas export DIR``.

The models are re-exported lazily (PEP 562): ``schemas.keys`` needs no pydantic, and the router,
which uses only the keys, must not build every model of the package (docs/performance.md, memory).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "SensorSample": "schemas.sensor", "VEHICLE_ID_PATTERN": "schemas.keys", "parse_sensor_line": "schemas.sensor",
    "NormalForces": "schemas.pipeline", "ObserverOutput": "schemas.pipeline", "OcpEstimate": "schemas.pipeline",
    "SoilEstimate": "schemas.pipeline",
    "OcpReply": "schemas.messages", "Rejection": "schemas.messages", "ServiceHealth": "schemas.messages",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'schemas' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
