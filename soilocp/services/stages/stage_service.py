"""The one stage service: runs any row of :data:`soilocp.services.stages.graph.PIPELINE`.

Per vehicle it subscribes the row's inputs, parses each work item with the input's model, steps
the row's library stage and publishes the output on the row's key.  Rows with more to do
(the gateway's raw check, the observer's join by seq, the OCP publisher's queryable and
staleness) subclass it and override one hook: :meth:`handle`, :meth:`accept` or :meth:`emit`.
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar

from pydantic import BaseModel

from soilocp.services.runtime.service import Service
from soilocp.services.runtime.worker import WorkItem
from soilocp.services.stages.config import pipeline_config
from soilocp.services.stages.graph import StageSpec


class StageService(Service):
    """A pipeline stage as a service: ``spec`` names the row; ``name`` follows it."""

    spec: ClassVar[StageSpec]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "spec" in cls.__dict__:
            cls.name = cls.spec.name

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        factory = self.spec.stage
        pc = pipeline_config(cfg) if factory is not None else None
        self.stages: dict[str, Any] = {vid: factory(pc) for vid in cfg.vehicle_ids} if factory else {}
        self.pubs: dict[str, Any] = {}
        #: each input kind's parser, the model's own JSON validator (what ``model_validate_json`` calls, without
        #: its wrapper or the row lookup per message): the payload bytes straight to the model, every check kept
        self.parsers: dict[str, Callable[[bytes], Any]] = {
            i.kind: i.model.__pydantic_validator__.validate_json
            for i in self.spec.inputs + self.spec.feedback if i.model is not None}

    def declare(self, session, vehicle_id: str) -> None:
        self.pubs[vehicle_id] = self.publisher(session, self.spec.output(vehicle_id))
        for inp in self.spec.inputs:
            self.subscribe(session, inp.key(vehicle_id), vehicle_id, inp.kind)

    def handle(self, item: WorkItem) -> None:
        self.counters[item.vehicle_id].last_input_wall = item.wall
        self.accept(item.vehicle_id, item.kind, self.parsers[item.kind](item.payload))

    def accept(self, vehicle_id: str, kind: str, message: BaseModel) -> None:
        """One parsed input: step the stage and publish (a single-input row)."""
        self.emit(vehicle_id, self.stages[vehicle_id].step(message))

    def emit(self, vehicle_id: str, out: Any) -> None:
        # the model's JSON as bytes, put as they are: ``model_dump_json`` is these bytes decoded to a str, which
        # the put encodes back (5 us a message)
        self.pubs[vehicle_id].put(out.__pydantic_serializer__.to_json(out))
        c = self.counters[vehicle_id]
        c.published += 1
        c.last_seq, c.last_stamp = out.seq, out.stamp
