"""The normal-force stage: a sensor sample's specific force -> the normal force per wheel (eqs. 16-25,
the zero-warp solution of docs/method.md §2-3), as the :class:`~soilocp.schemas.pipeline.NormalForces`
record.  No numpy on this path: the normal-force service, which runs only this stage, loads none
(tests/test_lean_processes.py); the core's map is the one every path uses
(:func:`soilocp.model.normal_force_map.core_solver`)."""

from __future__ import annotations

from soilocp.schemas.pipeline import NormalForces
from soilocp.schemas.sensor import SensorSample

from soilocp.estimation.config import PipelineConfig
from soilocp.model.normal_force_map import core_solver, solve_one


class NormalForceStage:
    """Normal forces from the measured specific force (eqs. 16-25, zero-warp, docs/method.md §2-3)."""

    def __init__(self, config: PipelineConfig):
        self.vehicle = config.vehicle
        self._solver = core_solver(config.vehicle)

    def step(self, sample: SensorSample) -> NormalForces:
        """One sample's normal forces.

        Parameters: ``sample.specific_force`` (3,), m/s^2, body frame (x forward, y left, z up).
        Returns F_z per wheel (4,), N, wheels 1 LR, 2 LF, 3 RF, 4 RR (eqs. 21-25, the zero-warp
        solution; not clipped: <= 0 is a lifted wheel, docs/method.md §2-3).  ValueError naming
        ``specific_force`` and its value if it is not three finite numbers."""
        # the model's validator on the fields (what NormalForces(**fields) runs, without the keyword call)
        return _validate(dict(
            vehicle_id=sample.vehicle_id,
            seq=sample.seq,
            stamp=sample.stamp,
            normal_force=solve_one(self._solver, sample.specific_force),
        ))


_validate = NormalForces.__pydantic_validator__.validate_python
