"""The estimation chain as stages: normal forces -> observer -> slip + soil strength -> OCPs.

Each stage is a small deterministic object with a ``step`` method that takes and returns the
message models of ``soilocp.schemas.pipeline``.  The live services run one stage each and pass the
messages over Zenoh; :class:`VehiclePipeline` composes them in one process.  The observer and soil
stages are views of one :class:`soilocp.estimation.estimator.Estimator`'s stage steps (the core's
``ChainCore.observe``, ``update`` and ``feed``), whose whole step (``ChainCore.step``) is those
stage steps in order: the offline path (``soilocp estimate``) and the batched service run that
whole step, the live services and :class:`VehiclePipeline` the stage steps, and K goes back to the
torque scale on every path (the observer stage's :meth:`ObserverStage.feed`).  The normal forces
and the OCPs run through their float-only calls, so that their services load no numpy
(:class:`soilocp.estimation.normal_force_stage.NormalForceStage`,
:class:`soilocp.estimation.ocp_stage.OcpStage`).
"""

from __future__ import annotations

from soilocp.schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp.estimation.config import PipelineConfig, load_pipeline_config
from soilocp.estimation.estimator import Estimator, observer_inputs, soil_message
from soilocp.estimation.normal_force_stage import NormalForceStage
from soilocp.estimation.observer_bank import LIFT_OFF_FORCE
from soilocp.estimation.ocp_stage import OcpStage, ocp_message
from soilocp.estimation.slip_gate import SlipGate

__all__ = ["LIFT_OFF_FORCE", "NormalForceStage", "ObserverStage", "OcpStage", "PipelineConfig", "SlipGate",
           "SoilStage", "VehiclePipeline", "load_pipeline_config", "observer_inputs", "ocp_message", "soil_message"]


class ObserverStage:
    """Per-wheel traction observer (eqs. 26-35; state chosen observable, §7; §11-12 resistance and
    bounds) with the online torque scale: vehicle 0 of an :class:`Estimator` (``estimator``; None: its
    own, N = 1), :meth:`Estimator.observe`; the soil estimates come back through :meth:`feed`."""

    def __init__(self, config: PipelineConfig, estimator: Estimator | None = None):
        self.estimator = est = estimator if estimator is not None else Estimator(config, 1)
        self.bank, self.scale = est.observer, est.scale

    @property
    def feeds_soil(self) -> bool:
        """Whether :meth:`feed` passes K to the torque scale (else the soil estimates need not come back)."""
        return self.estimator.feeds_soil

    def step(self, sample: SensorSample, forces: NormalForces) -> ObserverOutput:
        """One step of the scale and the observer (:meth:`Estimator.observe`).  ValueError when the
        forces belong to another sample."""
        return self.estimator.observe(0, sample, forces)

    def feed(self, soil: SoilEstimate) -> None:
        """The soil stage's estimate of the last sample stepped: the torque scale's modelled motion
        resistance of the next samples is at its K and slips (:meth:`Estimator.feed`)."""
        self.estimator.feed(0, soil)


class SoilStage:
    """Slip per wheel (eq. 1) and soil strength K (eqs. 36-37 corrected: a grid Bayes filter over
    ln K on gross traction, docs/method.md §4, §9, §11-12, or the paper's rule, ``method="paper"``),
    with a fleet map's ``prior`` (opt-in, :class:`soilocp.map.prior.MapPrior`): vehicle 0 of an
    :class:`Estimator` (``estimator``; None: its own, N = 1), :meth:`Estimator.update`."""

    def __init__(self, config: PipelineConfig, prior=None, estimator: Estimator | None = None):
        if estimator is None:
            estimator = Estimator(config, 1, None if prior is None else [prior])
        elif prior is not None:
            raise ValueError("prior: give it to the estimator (Estimator(config, 1, [prior]))")
        self.estimator = estimator
        self.cfg = estimator.config
        self.prior = None if estimator.priors is None else estimator.priors[0]
        self.gate, self.bank = estimator.gate, estimator.soil

    def step(self, obs: ObserverOutput) -> SoilEstimate:
        """Slip per wheel (4,) by eq. 1 from the filtered speeds, then one update of the ln K grid
        with the wheels' (slip, gross traction) pairs that the gate lets through (§9).

        Returns K (>0, dimensionless, the paper's soil strength) and its 1-sigma, the soil class
        with its probability, and a status that says when K is not determined, not observable, or
        not explained by the traction curve (§11-13), with the reason."""
        return self.estimator.update(0, obs)


class VehiclePipeline:
    """The four stages composed, for one vehicle, with their messages: the stage steps of one
    :class:`Estimator` (N = 1) in the order of its whole step, K fed back after each sample."""

    def __init__(self, config: PipelineConfig | None = None, prior=None):
        self.config = config or PipelineConfig()
        self.estimator = est = Estimator(self.config, 1, None if prior is None else [prior])
        self.normal = NormalForceStage(self.config)
        self.observer = ObserverStage(self.config, est)
        self.soil = SoilStage(self.config, estimator=est)
        self.ocp = OcpStage(self.config)

    def process_all(self, sample: SensorSample) -> tuple[NormalForces, ObserverOutput, SoilEstimate, OcpEstimate]:
        """One sample through the four stages; every stage's message, in order."""
        nf = self.normal.step(sample)
        ob = self.observer.step(sample, nf)
        so = self.soil.step(ob)
        self.observer.feed(so)  # the torque scale's modelled motion resistance (eq. 4) at this K and these slips
        return nf, ob, so, self.ocp.step(so)

    def process(self, sample: SensorSample) -> OcpEstimate:
        """One sample through the four stages; the OCP estimate."""
        return self.process_all(sample)[3]
