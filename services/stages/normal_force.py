"""Normal-force service: clean samples -> normal force per wheel (``NormalForceStage``).

Input ``soilocp/<vid>/sensors/clean``; output ``soilocp/<vid>/normal_forces`` (NormalForces JSON).
"""

from __future__ import annotations

from typing import Any

from schemas import keys
from schemas.sensor import SensorSample
from soilocp.estimation.pipeline import NormalForceStage

from services.runtime.service import Service
from services.stages.config import pipeline_config


class NormalForceService(Service):
    name = "normal-force"

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        pc = pipeline_config(cfg)
        self.stages = {vid: NormalForceStage(pc) for vid in cfg.vehicle_ids}
        self.pubs: dict[str, Any] = {}

    def declare(self, session, vehicle_id: str) -> None:
        self.pubs[vehicle_id] = self.publisher(session, keys.normal_forces(vehicle_id))
        self.subscribe(session, keys.clean(vehicle_id), vehicle_id, "sample")

    def handle(self, item) -> None:
        vid, _kind, payload, wall, _key = item
        c = self.counters[vid]
        c.last_input_wall = wall
        sample = SensorSample.model_validate_json(payload)
        out = self.stages[vid].step(sample)
        self.pubs[vid].put(out.model_dump_json())
        c.published += 1
        c.last_seq, c.last_stamp = out.seq, out.stamp
