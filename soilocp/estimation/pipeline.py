"""The estimation chain as stages: normal forces -> observer -> slip + soil strength -> OCPs.

Each stage is a small deterministic object with a ``step`` method that takes and returns the
message models of ``soilocp.schemas.pipeline``.  The offline ``soilocp estimate`` composes them in one
process (:class:`VehiclePipeline`); the live services run one stage each and pass the same
messages over Zenoh.  Same code, same numbers.  Every stage runs the core's kernels with N = 1 (the normal forces
and the OCPs through their float-only calls, so that their services load no numpy:
:class:`soilocp.estimation.normal_force_stage.NormalForceStage`,
:mod:`soilocp.estimation.observer_bank`, :class:`soilocp.estimation.slip_gate.SlipGate`,
:class:`soilocp.estimation.soil_strength.SoilBank`,
:class:`soilocp.estimation.ocp_stage.OcpStage`): the batched service (:mod:`soilocp.estimation.batch`) runs the very same
kernels with N = many.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from soilocp.schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp.estimation.config import PipelineConfig, load_pipeline_config
from soilocp.estimation.normal_force_stage import NormalForceStage
from soilocp.estimation.observer_bank import LIFT_OFF_FORCE, ObserverBank, ObserverInputs, observer_message
from soilocp.estimation.ocp_stage import OcpStage, ocp_message
from soilocp.estimation.slip_gate import SlipGate, pack_message
from soilocp.estimation.soil_state import SoilInputs, SoilState
from soilocp.estimation.soil_strength import PaperSoilEstimator, SoilBank
from soilocp.estimation.torque_scale import TorqueScaleBank
from soilocp.map.place import estimate_place

__all__ = ["LIFT_OFF_FORCE", "NormalForceStage", "OcpStage", "PipelineConfig", "VehiclePipeline", "SlipGate",
           "load_pipeline_config", "ocp_message"]


def _quad(a) -> tuple[float, float, float, float]:
    if type(a) is not np.ndarray or a.dtype != np.float64:
        a = np.asarray(a, dtype=float)
    return tuple(a.tolist())  # type: ignore[return-value]


_ZERO = np.zeros(1, dtype=int)


def _bools(a) -> tuple[bool, bool, bool, bool]:
    return tuple(a.tolist() if isinstance(a, np.ndarray) else (bool(v) for v in a))  # type: ignore[return-value]


def observer_inputs(samples: Sequence[SensorSample], normal_forces: Sequence,
                    torque_constant: float = 1.0) -> ObserverInputs:
    """Stack k sensor samples and their normal forces (each a 4-sequence, N) into the kernel's
    inputs: scalars (k,) (stamp s, specific force x m/s^2, yaw rate rad/s, pitch rad, ground speed
    m/s or NaN when absent) and per-wheel arrays (k, 4) (speeds rad/s, torques N m, forces N); the
    logged torques times ``torque_constant`` (N m per unit of the log's column, PipelineConfig)."""
    if len(samples) != len(normal_forces):
        raise ValueError(f"{len(samples)} samples but {len(normal_forces)} normal-force quads")
    # one array for the scalars and one per quad: a handful of numpy calls whatever k is
    sc = np.array([(s.stamp, s.specific_force[0], s.yaw_rate, s.pitch, np.nan if s.ground_speed is None
                    else s.ground_speed) for s in samples], dtype=float).reshape(-1, 5).T
    torque = np.array([s.wheel_torque for s in samples], dtype=float).reshape(-1, 4)
    if torque_constant != 1.0:
        torque *= torque_constant
    return ObserverInputs(
        stamp=sc[0], specific_force_x=sc[1], yaw_rate=sc[2], pitch=sc[3], ground_speed=sc[4],
        wheel_speed=np.array([s.wheel_speed for s in samples], dtype=float).reshape(-1, 4),
        wheel_torque=torque,
        normal_force=_forces(normal_forces),
    )


def _forces(normal_forces) -> np.ndarray:
    """The normal-force quads as a new (k, 4) float array: a solver's (k, 4) block is copied whole (the
    batched service's), anything else stacked quad by quad."""
    if type(normal_forces) is np.ndarray and normal_forces.ndim == 2 and normal_forces.dtype == np.float64:
        return np.array(normal_forces, dtype=float, order="C")
    return np.array([np.asarray(f, dtype=float) for f in normal_forces])


class ObserverStage:
    """Per-wheel traction observer (eqs. 26-35; state chosen observable, §7; §11-12 resistance and
    bounds): the kernel :class:`soilocp.estimation.observer_bank.ObserverBank` with N = 1."""

    def __init__(self, config: PipelineConfig):
        self.bank = ObserverBank(config.vehicle, config.observer, 1)
        self.torque_constant = config.torque_constant
        self.scale = TorqueScaleBank(config.vehicle, config.torque_scale, config.soil.gross_scale_sigma, 1,
                                     config.constants, slip_floor=config.slip_floor, gravity=config.observer.gravity)

    def step(self, sample: SensorSample, forces: NormalForces) -> ObserverOutput:
        """One predict + gated update of the observer (eqs. 26-35 with the §7 state).

        Parameters: the sample (wheel speeds (4,) rad/s, torques (4,) N m, specific force x m/s^2,
        yaw rate rad/s, pitch rad, ground speed m/s or None) and its normal forces (4,) N, same seq.
        Returns per wheel (4,): net traction mu (eq. 6's F_DP/W) and its variance, motion
        resistance (eq. 4 with |S|, §11), gross traction mu + mu_MR (what eq. 13 sees) and its
        variance, the filtered wheel speeds; the filtered ground speed and yaw rate; whether each mu
        is determined (posterior 1-sigma <= ``mu_std_determined``, §12) and any reset's reason.
        ValueError when the forces belong to another sample."""
        if forces.seq != sample.seq or forces.vehicle_id != sample.vehicle_id:
            raise ValueError(
                f"normal forces are for {forces.vehicle_id}#{forces.seq}, sample is {sample.vehicle_id}#{sample.seq}"
            )
        inputs, scale_sigma = self.scale.apply(_ZERO, observer_inputs([sample], [forces.normal_force],
                                                                     self.torque_constant))
        out = self.bank.step(None, inputs)  # N = 1: every vehicle
        if scale_sigma is None:
            msg = observer_message(sample.vehicle_id, sample.seq, sample.stamp, out, 0)
        else:
            msg = observer_message(sample.vehicle_id, sample.seq, sample.stamp, out, 0, float(self.scale.theta[0, 0]),
                                   float(scale_sigma[0]))
        if sample.position is not None or sample.geo is not None:  # for the soil estimate's place (docs/map.md)
            msg = msg.model_copy(update={"position": sample.position, "geo": sample.geo})
        return msg


def soil_message(vehicle_id: str, seq: int, stamp: float, inp: SoilInputs, st: SoilState, mu, mu_determined,
                 j: int) -> SoilEstimate:
    """The j-th vehicle of a soil-kernel step as the SoilEstimate message: slip (4,) from ``inp``,
    K, its std (and ln K's), class, status and reason from ``st``, the observer's mu (4,) and its
    determined flags (4,) passed through."""
    return SoilEstimate(
        vehicle_id=vehicle_id, seq=seq, stamp=stamp, slip=_quad(inp.slip[j]), informative=st.used,
        soil_strength=st.soil_strength, soil_strength_std=st.soil_strength_std, log_k_std=st.log_k_std,
        soil_class=st.soil_class, soil_class_confidence=st.soil_class_confidence, status=st.status,
        reason=st.reason, reason_code=st.reason_code, last_update_stamp=st.last_update_stamp, mu=_quad(mu), mu_determined=_bools(mu_determined),
        held_for_s=st.held_for_s, unusable=st.unusable,
    )


class SoilStage:
    """Slip per wheel (eq. 1) and soil strength K (eqs. 36-37 corrected: a grid Bayes filter over
    ln K on gross traction, docs/method.md §4, §9, §11-12): :class:`SlipGate` and
    :class:`soilocp.estimation.soil_strength.SoilBank` with N = 1 (or the paper's rule, ``method="paper"``)."""

    def __init__(self, config: PipelineConfig, prior=None):
        self.cfg = config
        # opt-in: prior(obs) -> (ln K, 1-sigma) when the vehicle enters a mapped cell (soilocp.map.prior)
        self.prior = prior
        self.gate = SlipGate(config, 1)
        self.bank = SoilBank(config.constants, config.soil, 1) if config.soil.method == "bayes" else None
        self.paper = PaperSoilEstimator(config.constants, config.soil) if self.bank is None else None

    def step(self, obs: ObserverOutput) -> SoilEstimate:
        """Slip per wheel (4,) by eq. 1 from the filtered speeds, then one update of the ln K grid
        with the wheels' (slip, gross traction) pairs that the gate lets through (§9).

        Returns K (>0, dimensionless, the paper's soil strength) and its 1-sigma, the soil class
        with its probability, and a status that says when K is not determined, not observable, or
        not explained by the traction curve (§11-13), with the reason."""
        rows = pack_message(obs)  # the observer's output as the one array the core reads
        stamp = np.array([obs.stamp])
        scale_sigma = None if obs.torque_scale_std is None else np.array([obs.torque_scale_std])
        if self.bank is not None and self.prior is None:  # the gate and the update: one core call
            inp, states = self.bank.step_gated(self.gate, _ZERO, stamp, rows, scale_sigma)
            st = states[0]
        elif self.bank is not None:  # the map's hook runs between the gate and the update
            from soilocp.map.prior import start_from_map

            inp = start_from_map([self.prior], self.bank, _ZERO, [obs], self.gate.step(_ZERO, stamp, rows))
            st = self.bank.update(_ZERO, stamp, inp, scale_sigma)[0]
        else:
            inp = self.gate.step(_ZERO, stamp, rows)
            st = self.paper.update(obs.stamp, inp.slip[0], inp.observed[0], inp.variance[0],
                                   inp.informative[0] & ~inp.held[0] & ~inp.ground_stale[0], inp.slip_sigma[0])
        msg = soil_message(obs.vehicle_id, obs.seq, obs.stamp, inp, st, obs.mu, obs.mu_determined, 0)
        if obs.position is not None or obs.geo is not None:  # where: the informing wheels' contact patches
            msg = msg.model_copy(update={"where": estimate_place(self.cfg.vehicle, obs.position, obs.geo, st.used)})
        return msg


class VehiclePipeline:
    """The four stages composed, for one vehicle: the offline path (``soilocp estimate``)."""

    def __init__(self, config: PipelineConfig | None = None, prior=None):
        self.config = config or PipelineConfig()
        self.normal = NormalForceStage(self.config)
        self.observer = ObserverStage(self.config)
        self.soil = SoilStage(self.config, prior)
        self.ocp = OcpStage(self.config)

    def process_all(self, sample: SensorSample) -> tuple[NormalForces, ObserverOutput, SoilEstimate, OcpEstimate]:
        """One sample through the four stages; every stage's message, in order."""
        nf = self.normal.step(sample)
        ob = self.observer.step(sample, nf)
        so = self.soil.step(ob)
        # the torque scale's modelled motion resistance (eq. 4) at this K and these slips (torque_scale.model_resistance)
        self.observer.scale.feed_soil(_ZERO, [so.soil_strength], np.asarray(so.slip, dtype=float))
        return nf, ob, so, self.ocp.step(so)

    def process(self, sample: SensorSample) -> OcpEstimate:
        """One sample through the four stages; the OCP estimate."""
        return self.process_all(sample)[3]
