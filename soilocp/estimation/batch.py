"""Many vehicles at once: the estimation chain of N vehicles in one core call per step.

:class:`BatchPipeline` builds the banks the single-vehicle stages of :mod:`soilocp.estimation.pipeline` run
with N = 1 (the torque scale :class:`soilocp.estimation.torque_scale.TorqueScaleBank`, the observer
:class:`soilocp.estimation.observer_bank.ObserverBank`, the slip gate :class:`soilocp.estimation.slip_gate.SlipGate`
and the soil strength :class:`soilocp.estimation.soil_strength.SoilBank`) and steps them all with the compiled
core's ``ChainCore`` (soilocp/_core/src/py/chain.rs): scale, observer, gate, soil update with its records, K fed
back to the scale, and the OCPs (eqs. 7-10), in one call for every vehicle stepped.  Its records are built by
the same message functions, so every field (statuses, reasons, classes, te_at_S_E) is the stages'
(``tests/test_batch.py`` checks them all on real drives).  The offline path (``soilocp estimate``) runs it with
N = 1 per vehicle, the batched service with N = many.

Every step takes the indices of the vehicles that have a sample now (any subset, each at most once): vehicles
are independent and need not be in step.  Only the default ``bayes`` soil method is batched; with fleet-map
priors the map's hook runs between the gate and the update, so the banks are called one by one.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp import _core
from soilocp.model.checks import check_count
from soilocp.estimation.observer_bank import ObserverBank, ObserverBlocks
from soilocp.model.ocp import ocp_arrays
from soilocp.model.ocp_values import OCP_NAMES
from soilocp.estimation.pipeline import PipelineConfig, observer_inputs, soil_message
from soilocp.estimation.slip_gate import SlipGate, pack_output
from soilocp.estimation.soil_state import SoilInputs
from soilocp.estimation.soil_strength import SoilBank
from soilocp.estimation.torque_scale import TorqueScaleBank
from soilocp.estimation.wheel_curve import WheelCurve


class BatchPipeline:
    """Observer -> slip + soil strength -> OCPs for N vehicles (normal forces come from outside,
    as in the services: the normal-force stage is cheap and per sample)."""

    def __init__(self, config: PipelineConfig | None, n_vehicles: int, priors: Sequence | None = None):
        self.config = cfg = config or PipelineConfig()
        self.n_vehicles = check_count(n_vehicles)
        # opt-in: each vehicle's fleet-map prior (soilocp.map.prior.MapPrior, or None), as SoilStage's
        self.priors = list(priors) if priors is not None else None
        if self.priors is not None and len(self.priors) != self.n_vehicles:
            raise ValueError(f"priors: {len(self.priors)} given for {self.n_vehicles} vehicles")
        if cfg.soil.method != "bayes":
            raise ValueError(f"soil method {cfg.soil.method!r}: the batched pipeline implements 'bayes' only")
        self.observer = ObserverBank(cfg.vehicle, cfg.observer, self.n_vehicles)
        self.gate = SlipGate(cfg, self.n_vehicles)
        self.soil = SoilBank(cfg.constants, cfg.soil, self.n_vehicles)
        self.scale = TorqueScaleBank(cfg.vehicle, cfg.torque_scale, cfg.soil.gross_scale_sigma, self.n_vehicles,
                                     cfg.constants, slip_floor=cfg.slip_floor, gravity=cfg.observer.gravity)
        self.curve = WheelCurve(cfg, self.n_vehicles)  # the wheel's learnt curve and the OCP records' rule
        # the whole chain in one core call per step, over the banks above (their state); the map prior's
        # hook runs between the gate and the update, so with priors the stages are called one by one
        self.chain = None if self.priors is not None else _core.ChainCore(
            self.observer._core, self.gate.core, self.soil.core, cfg.constants.kernel, self.scale._core,
            feed_soil=self.scale.active and cfg.torque_scale.model_resistance)

    def step(self, idx, samples: Sequence[SensorSample], normal_forces: Sequence) -> list[OcpEstimate]:
        """One sample per vehicle in ``idx`` (same order): the OCP record of each."""
        return self.step_all(idx, samples, normal_forces)[2]

    def step_all(self, idx, samples: Sequence[SensorSample],
                 normal_forces: Sequence) -> tuple[ObserverBlocks, list[SoilEstimate], list[OcpEstimate]]:
        """One sample per vehicle in ``idx`` (same order): the observer's output (arrays, one row per vehicle),
        and each vehicle's soil estimate and OCP record."""
        ix = self.observer.index(idx)
        inputs = observer_inputs(samples, normal_forces, self.config.torque_constant)
        if self.chain is not None:  # one core call: scale, observer, gate, soil update, K fed back, OCPs
            blocks, fields, report, ocp = self.observer.run(self.chain.step, ix, inputs)
            ob, inp = ObserverBlocks(*blocks), SoilInputs(*fields)
            states = self.soil.states(ix, inputs.stamp, inp, report)
        else:  # the map's hook runs between the gate and the update, as in SoilStage
            from soilocp.map.prior import start_from_map

            inputs, scale_sigma = self.scale.apply(ix, inputs)
            ob = self.observer.step(ix, inputs)
            inp = start_from_map([self.priors[i] for i in ix], self.soil, ix, samples,
                                 self.gate.step(ix, inputs.stamp, pack_output(ob)))
            states = self.soil.update(ix, inputs.stamp, inp, scale_sigma)
            ks = np.array([np.nan if s.soil_strength is None else s.soil_strength for s in states])
            self.scale.feed_soil(ix, ks, inp.slip)  # the next samples' modelled motion resistance (eq. 4) at this K
            arrays = ocp_arrays(ks, self.config.constants)
            ocp = tuple(arrays[n] for n in OCP_NAMES)
        soils, ocps = [], []
        for j, (sample, st) in enumerate(zip(samples, states)):
            soil = soil_message(sample.vehicle_id, sample.seq, sample.stamp, inp, st, ob.mu[j], ob.mu_determined[j], j)
            soils.append(soil)
            ocps.append(self.curve.record(int(ix[j]), soil, [a[j] for a in ocp]))
        return ob, soils, ocps
