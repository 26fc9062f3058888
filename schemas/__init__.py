"""Message contracts: a pydantic v2 model for every payload that crosses a process boundary.

Consumers in other languages use the JSON Schema files written by ``soilocp schemas export DIR``.
"""

from schemas.sensor import SensorSample, VEHICLE_ID_PATTERN, parse_sensor_line  # noqa: F401
from schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate  # noqa: F401
from schemas.messages import OcpReply, Rejection, ServiceHealth  # noqa: F401
