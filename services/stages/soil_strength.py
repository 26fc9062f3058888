"""Soil-strength service: observer output -> slip and soil strength K (``SoilStage``).

Input ``soilocp/<vid>/observer``; output ``soilocp/<vid>/soil`` (SoilEstimate JSON).
"""

from __future__ import annotations

from typing import Any

from schemas import keys
from schemas.pipeline import ObserverOutput
from soilocp.estimation.pipeline import SoilStage

from services.runtime.service import Service
from services.stages.config import pipeline_config


class SoilStrengthService(Service):
    name = "soil-strength"

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        pc = pipeline_config(cfg)
        self.stages = {vid: SoilStage(pc) for vid in cfg.vehicle_ids}
        self.pubs: dict[str, Any] = {}

    def declare(self, session, vehicle_id: str) -> None:
        self.pubs[vehicle_id] = self.publisher(session, keys.soil(vehicle_id))
        self.subscribe(session, keys.observer(vehicle_id), vehicle_id, "observer")

    def handle(self, item) -> None:
        vid, _kind, payload, wall, _key = item
        c = self.counters[vid]
        c.last_input_wall = wall
        obs = ObserverOutput.model_validate_json(payload)
        out = self.stages[vid].step(obs)
        self.pubs[vid].put(out.model_dump_json())
        c.published += 1
        c.last_seq, c.last_stamp = out.seq, out.stamp
