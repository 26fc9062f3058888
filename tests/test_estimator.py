"""The estimator (soilocp.estimation.estimator): its whole step and its stage steps in order give the same
records with every input of the chain in use (K fed back to a learnt torque scale, a map prior, a terrain
change), and the paper's soil method runs through its stage steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp import _core

from soilocp.estimation.estimator import Estimator
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.map.prior import MapPrior
from soilocp.model.normal_force import NormalForceSolver
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.schemas.map import MapCell
from soilocp.sim.controller import ControllerParams
from soilocp.sim.field import StartPose
from soilocp.sim.simulator import simulate


def _cells() -> list[MapCell]:
    out = []
    for ix in range(1, 6):
        for iy in (-1, 0, 1):
            cx, cy = (ix + 0.5) * 5.0, (iy + 0.5) * 5.0
            k = 50.0 if cx < 12.0 else 80.0
            out.append(MapCell(cell=f"field/5/{ix}/{iy}", frame="field", center=(cx, cy), K=k, log_k_std=0.1,
                               K_lo=k * math.exp(-0.1), K_hi=k * math.exp(0.1), count=10, last_seen=0.0,
                               vehicles=["a"]))
    return out


def test_the_whole_step_is_the_stage_steps_in_order():
    """A payload (+25 %) and speed swings (the torque scale learns k and models the resistance at the fed-back
    K), sand -> gravel at 12 m, a map prior: VehiclePipeline (the stage steps with their messages, as the live
    services) and Estimator.step_all (one core call) give the same records, field by field; without K fed
    back they would not."""
    true = DEFAULT_VEHICLE.model_copy(update={"mass": DEFAULT_VEHICLE.mass * 1.25})
    samples = [s for s, _ in simulate("mixed", duration=16.0, seed=2, vehicle=true, vehicle_id="e1",
                                      controller=ControllerParams(speed_swing=0.5),
                                      start=StartPose(frame="field", x=0.0, y=2.5, heading=0.0))]
    cfg = PipelineConfig(torque_scale=TorqueScaleConfig(model_resistance=True))
    stages_prior, whole_prior = MapPrior(_cells(), vehicle=cfg.vehicle), MapPrior(_cells(), vehicle=cfg.vehicle)
    stages, whole = VehiclePipeline(cfg, stages_prior), Estimator(cfg, 2, [whole_prior, None])
    assert whole.feeds_soil and stages.observer.feeds_soil
    unfed = Estimator(cfg, 1, [MapPrior(_cells(), vehicle=cfg.vehicle)])
    unfed.chain = _core.ChainCore(unfed.observer._core, unfed.gate.core, unfed.soil.core, unfed.scale._core,
                                  feed_soil=False)  # the same chain, K not fed back
    solve = NormalForceSolver(cfg.vehicle)
    differ = 0
    for s in samples:
        a = stages.process_all(s)[3].model_dump()
        fz = solve(np.array([s.specific_force], dtype=float))
        b = whole.step(np.array([0]), [s], fz)[0].model_dump()
        assert a == b, s.seq
        differ += a != unfed.step(np.array([0]), [s], fz)[0].model_dump()
    assert stages_prior.entered == whole_prior.entered >= 2
    assert differ > 500


def test_the_papers_soil_method_runs_through_the_stage_steps():
    """method "paper": the offline path runs the stage steps (the whole step refuses it, naming it)."""
    from soilocp.estimation.estimate import estimate_lines

    cfg = PipelineConfig()
    cfg = cfg.model_copy(update={"soil": cfg.soil.model_copy(update={"method": "paper", "measurement": "net"})})
    lines = [s.model_dump_json() for s, _ in simulate("sand", duration=10.0, seed=1)]
    recs = list(estimate_lines(lines, cfg))
    assert len(recs) == len(lines)
    assert sum(r["status"] == "ok" for r in recs) > 500
    assert abs(recs[-1]["soil_strength"] / 50.0 - 1) < 0.2
    with pytest.raises(ValueError, match="'paper'"):
        Estimator(cfg, 1).step(np.array([0]), [], [])


def test_the_soil_estimate_carries_the_ground_speeds_latency_on_both_paths():
    """A late GNSS-grade ground speed: the soil estimate passes on the latency estimate its slips were formed
    under (the curve learner drops the pairs of another, docs/method.md §19), the same on the stage steps
    (as the live services) and the whole step."""
    from soilocp.sim.variants import get_variant

    cfg = PipelineConfig()
    stages, whole = VehiclePipeline(cfg), Estimator(cfg, 1)
    solve = NormalForceSolver(cfg.vehicle)
    seen = []
    for s, _ in get_variant("gnss-5hz-lost").simulate(0, duration=12.0):
        _, obs, soil, _ = stages.process_all(s)
        fz = solve(np.array([s.specific_force], dtype=float))
        ob, soils, _ = whole.step_all(np.array([0]), [s], fz)
        assert soil.ground_speed_latency == obs.ground_speed_latency == soils[0].ground_speed_latency, s.seq
        assert soils[0].ground_speed_latency == float(ob.ground_speed_latency[0])
        seen.append(soil.ground_speed_latency)
    # the variant's speed is 0.15 s late: undetermined at first, then measured
    assert seen[0] == 0.0 and abs(seen[-1] - 0.15) < 0.05, (seen[0], seen[-1])
