"""The pipeline is declared once (services/stages/graph.py): its rows chain, every row runs as a
service, and both compose files deploy exactly those rows for every vehicle."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from soilocp.services.stages.graph import BATCHED_STAGES, BY_NAME, PIPELINE, PIPELINE_SERVICES
from soilocp.services.stages.registry import stage_service
from soilocp.services.stages.stage_service import StageService
from soilocp.estimation.pipeline import PipelineConfig

ROOT = Path(__file__).resolve().parent.parent


def test_rows_chain_output_to_input():
    produced = {PIPELINE[0].inputs[0].key("v1")}  # the raw samples come from outside
    models = {}
    for row in PIPELINE:
        for inp in row.inputs:
            assert inp.key("v1") in produced, f"{row.name} reads {inp.key('v1')}, which no earlier row writes"
            if inp.model is not None:
                assert models[inp.key("v1")] is inp.model, f"{row.name}: {inp.kind} parsed with another model"
        produced.add(row.output("v1"))
        models[row.output("v1")] = row.output_model
    assert PIPELINE_SERVICES[-1] == "ocp" and BATCHED_STAGES == PIPELINE_SERVICES[1:-1]


@pytest.mark.parametrize("name", PIPELINE_SERVICES)
def test_every_row_runs_as_a_stage_service(name):
    cls = stage_service(name)
    assert issubclass(cls, StageService) and cls.name == name and cls.spec is BY_NAME[name]
    factory = BY_NAME[name].stage
    if factory is not None:
        assert callable(factory(PipelineConfig()).step)


@pytest.mark.parametrize("compose", ["docker-compose.yml", "docker-compose.plain.yml"])
def test_compose_deploys_the_rows_of_the_graph(compose):
    services = yaml.safe_load((ROOT / compose).read_text())["services"]
    per_vehicle: dict[str, list[str]] = {}
    for svc_name, svc in services.items():
        cmd = svc.get("command") or []
        if len(cmd) >= 2 and cmd[0] == "service" and cmd[1] in PIPELINE_SERVICES:
            vehicle = svc_name[: -len(cmd[1]) - 1]
            assert svc_name == f"{vehicle}-{cmd[1]}", f"{compose}: {svc_name} runs {cmd[1]}"
            per_vehicle.setdefault(vehicle, []).append(cmd[1])
    assert per_vehicle, f"{compose} deploys no pipeline"
    for vehicle, rows in per_vehicle.items():
        assert sorted(rows) == sorted(PIPELINE_SERVICES), f"{compose}: {vehicle} runs {rows}"
