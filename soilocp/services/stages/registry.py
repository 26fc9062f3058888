"""Which class runs each row of the pipeline: the row's own subclass where it has more to do
than step and publish, else the generic :class:`~soilocp.services.stages.stage_service.StageService`."""

from __future__ import annotations

from soilocp.services.stages.gateway import GatewayService
from soilocp.services.stages.graph import BY_NAME
from soilocp.services.stages.observer import ObserverService
from soilocp.services.stages.ocp import OcpService
from soilocp.services.stages.soil_strength import SoilStrengthService
from soilocp.services.stages.stage_service import StageService

SPECIAL: dict[str, type[StageService]] = {cls.name: cls for cls in (GatewayService, ObserverService, OcpService,
                                                                     SoilStrengthService)}


def stage_service(name: str) -> type[StageService]:
    """The service class of row ``name`` (KeyError for a name that is not a row)."""
    if name in SPECIAL:
        return SPECIAL[name]
    return type(f"StageService[{name}]", (StageService,), {"spec": BY_NAME[name]})
