"""Soil-strength service: slip and soil strength K of each vehicle from its observer output
(``SoilStage``, the estimator's soil stage), published on ``soilocp/<vid>/soil``.

With ``map_prior`` in its config (or ``SOILOCP_MAP_PRIOR=<map id>``; docs/map.md §4) each vehicle's
belief starts from the fleet map's K and band on entering a mapped cell: the stage takes the
vehicle's :class:`soilocp.map.prior.MapPrior`, whose cells :class:`MapPriorFeed` keeps up to date
from the map service.  The estimates go on to the OCP publisher, and back to the observer service,
whose torque scale models the motion resistance at their K (:mod:`soilocp.services.stages.observer`).
"""

from __future__ import annotations

from typing import Optional

from pydantic import BaseModel

from soilocp.services.stages.config import pipeline_config
from soilocp.services.stages.graph import BY_NAME
from soilocp.services.stages.map_prior_feed import MapPriorFeed
from soilocp.services.stages.stage_service import StageService


class SoilStrengthService(StageService):
    """The soil-strength row, with the vehicles' map priors when configured."""

    spec = BY_NAME["soil-strength"]

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        self.feed: Optional[MapPriorFeed] = None
        if cfg.map_prior is None:
            return
        from soilocp.estimation.pipeline import SoilStage

        pc = pipeline_config(cfg)
        self.feed = MapPriorFeed(self, cfg.map_prior, cfg.vehicle_ids, pc.vehicle)
        for vid in cfg.vehicle_ids:
            self.stages[vid] = SoilStage(pc, self.feed.priors[vid])

    def accept(self, vehicle_id: str, kind: str, message: BaseModel) -> None:
        if self.feed is None:
            return super().accept(vehicle_id, kind, message)
        self.feed.saw(vehicle_id, message)
        before = self.feed.priors[vehicle_id].entered
        super().accept(vehicle_id, kind, message)
        self.feed.count(vehicle_id, message.seq, before)
