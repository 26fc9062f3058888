"""The pipeline, declared once, as data: each stage's service name (also its liveliness token and
status key chunk), its inputs (work-item kind, key, message model), its output key and model, and
the library stage it runs.

Everything that needs the shape of the pipeline reads this table: the generic stage service
(:mod:`soilocp.services.stages.stage_service`), the command line (``soilocp service NAME``), ``soilocp
run``, the bench, the batched service (which implements the rows between the gateway and the OCP
publisher), the fleet view, the test rig, and a test that holds ``docker-compose.yml`` to it.

The library stages are built by small factories with a local import, so that a process imports
only the physics of the stage it runs (the gateway carries no numpy).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

from pydantic import BaseModel

from soilocp.schemas import keys
from soilocp.schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample


@dataclass(frozen=True)
class StageInput:
    """One input of a stage: the work item's ``kind``, the key it comes from, and the model that
    parses it (None: raw bytes, checked by the stage itself)."""

    kind: str
    key: Callable[[str], str]
    model: Optional[type[BaseModel]]


@dataclass(frozen=True)
class StageSpec:
    """One row of the pipeline."""

    name: str
    inputs: tuple[StageInput, ...]
    output: Callable[[str], str]
    output_model: type[BaseModel]
    #: ``factory(PipelineConfig) -> stage`` with ``stage.step(*messages) -> output_model``; None
    #: for the gateway, whose check is per vehicle and needs no physics.
    stage: Optional[Callable[[Any], Any]]
    summary: str
    #: inputs from a later row that the stage feeds back into itself, taken only while it does
    #: (``stage.feeds_soil``): the observer's torque scale models the motion resistance at the soil's K
    feedback: tuple[StageInput, ...] = ()

    def input_model(self, kind: str) -> Optional[type[BaseModel]]:
        for i in self.inputs + self.feedback:
            if i.kind == kind:
                return i.model
        raise KeyError(f"stage {self.name} has no input of kind {kind!r}")


def _normal_force_stage(pc):
    from soilocp.estimation.normal_force_stage import NormalForceStage  # no numpy: the service loads none

    return NormalForceStage(pc)


def _observer_stage(pc):
    from soilocp.estimation.pipeline import ObserverStage

    return ObserverStage(pc)


def _soil_stage(pc):
    from soilocp.estimation.pipeline import SoilStage

    return SoilStage(pc)


def _ocp_stage(pc):
    from soilocp.estimation.ocp_stage import OcpStage  # no numpy: the OCP publisher loads none

    return OcpStage(pc)


PIPELINE: tuple[StageSpec, ...] = (
    StageSpec("gateway", (StageInput("raw", keys.raw, None),), keys.clean, SensorSample, None,
              "validates raw samples; rejects with a reason on soilocp/<vid>/rejected"),
    StageSpec("normal-force", (StageInput("sample", keys.clean, SensorSample),), keys.normal_forces, NormalForces,
              _normal_force_stage, "normal force per wheel (eqs. 21-25)"),
    StageSpec("observer", (StageInput("sample", keys.clean, SensorSample),
                           StageInput("forces", keys.normal_forces, NormalForces)), keys.observer, ObserverOutput,
              _observer_stage, "Kalman observer of per-wheel traction (joins its inputs by seq)",
              feedback=(StageInput("soil", keys.soil, SoilEstimate),)),
    StageSpec("soil-strength", (StageInput("observer", keys.observer, ObserverOutput),), keys.soil, SoilEstimate,
              _soil_stage, "soil strength K from slip and gross traction"),
    StageSpec("ocp", (StageInput("soil", keys.soil, SoilEstimate),), keys.ocp, OcpEstimate, _ocp_stage,
              "mu_T, S_T, S_E; queryable, with staleness"),
)

#: Service names in pipeline order (each holds a liveliness token ``soilocp/<vid>/alive/<name>``).
PIPELINE_SERVICES: tuple[str, ...] = tuple(s.name for s in PIPELINE)
BY_NAME: dict[str, StageSpec] = {s.name: s for s in PIPELINE}
#: The rows the batched service implements in one process (it also is the OCP publisher).
BATCHED_STAGES: tuple[str, ...] = PIPELINE_SERVICES[1:-1]
#: Processes that are not pipeline stages but hold liveliness tokens too.
OTHER_SERVICES: tuple[str, ...] = ("vehicle", "controller", "ros2-in", "ros2-out")
ALL_SERVICES: tuple[str, ...] = PIPELINE_SERVICES + OTHER_SERVICES
