"""The estimation chain of a bank of N vehicles, assembled once: :class:`Estimator`.

The chain is torque scale -> observer -> slip gate -> soil-grid update -> K back to the torque scale ->
OCPs (eqs. 7-10), with a fleet map's prior (:class:`soilocp.map.prior.MapPrior`) as an optional input of
the soil update.  Its order and what each stage hands the next are written once, in the compiled core
(``ChainCore``, soilocp/_core/src/py/chain.rs): its whole step (``ChainCore.step``, the offline path and
the batched service) is its stage steps called in order, and the same stage steps are what the live
services run one each (``ChainCore.observe`` in the observer service, ``ChainCore.update`` in the
soil-strength service, ``ChainCore.feed`` in the observer service again, when the soil estimate comes
back).  So a map prior and the feedback of K reach the same kernels in the same order on every path.

This module holds the stage objects of the bank (their settings and their state), turns the samples
into the core's inputs and its outputs into the messages of :mod:`soilocp.schemas.pipeline`.

* :meth:`Estimator.step_all`: the whole step of the vehicles that have a sample now (any subset, each
  at most once), one core call;
* :meth:`Estimator.observe`, :meth:`Estimator.update`, :meth:`Estimator.feed`: one vehicle's stage
  steps on the messages the live services pass each other.

The paper's soil rule (``soil.method = "paper"``) is not in the core: its update replaces the grid
update in :meth:`Estimator.update`, and it has no whole step (the offline path runs its stage steps).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from soilocp import _core
from soilocp.schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp.estimation.config import PipelineConfig
from soilocp.estimation.observer_bank import ObserverBank, ObserverBlocks, ObserverInputs, observer_message
from soilocp.estimation.slip_gate import SlipGate, pack_message
from soilocp.estimation.soil_state import SoilInputs, SoilState
from soilocp.estimation.soil_strength import PaperSoilEstimator, SoilBank
from soilocp.estimation.torque_scale import TorqueScaleBank
from soilocp.estimation.wheel_curve import WheelCurve
from soilocp.map.place import estimate_place
from soilocp.model.checks import check_count

__all__ = ["Estimator", "observer_inputs", "soil_message"]


def _quad(a) -> tuple[float, float, float, float]:
    if type(a) is tuple:  # a message's quad (the live soil stage's mu): the same floats, without an array
        return tuple(map(float, a))  # type: ignore[return-value]
    if type(a) is not np.ndarray or a.dtype != np.float64:
        a = np.asarray(a, dtype=float)
    return tuple(a.tolist())  # type: ignore[return-value]


def _bools(a) -> tuple[bool, bool, bool, bool]:
    return tuple(a.tolist() if isinstance(a, np.ndarray) else map(bool, a))  # type: ignore[return-value]


def observer_inputs(samples: Sequence[SensorSample], normal_forces: Sequence,
                    torque_constant: float = 1.0) -> ObserverInputs:
    """Stack k sensor samples and their normal forces (each a 4-sequence, N) into the kernel's
    inputs: scalars (k,) (stamp s, specific force x m/s^2, yaw rate rad/s, pitch rad, ground speed
    m/s or NaN when absent) and per-wheel arrays (k, 4) (speeds rad/s, torques N m, forces N); the
    logged torques times ``torque_constant`` (N m per unit of the log's column, PipelineConfig)."""
    if len(samples) != len(normal_forces):
        raise ValueError(f"{len(samples)} samples but {len(normal_forces)} normal-force quads")
    # one array for the scalars and one for the speed and torque quads: a handful of numpy calls whatever k is
    # (the live observer builds one sample's on every message)
    sc = np.array([(s.stamp, s.specific_force[0], s.yaw_rate, s.pitch, np.nan if s.ground_speed is None
                    else s.ground_speed) for s in samples], dtype=float).reshape(-1, 5).T
    q = np.array(([s.wheel_speed for s in samples], [s.wheel_torque for s in samples]), dtype=float).reshape(2, -1, 4)
    torque = q[1]
    if torque_constant != 1.0:
        torque *= torque_constant
    return ObserverInputs(
        stamp=sc[0], specific_force_x=sc[1], yaw_rate=sc[2], pitch=sc[3], ground_speed=sc[4],
        wheel_speed=q[0], wheel_torque=torque, normal_force=_forces(normal_forces),
    )


def _forces(normal_forces) -> np.ndarray:
    """The normal-force quads as a new (k, 4) float array: a solver's (k, 4) block is copied whole (the
    batched service's), anything else stacked quad by quad."""
    if type(normal_forces) is np.ndarray and normal_forces.ndim == 2 and normal_forces.dtype == np.float64:
        return np.array(normal_forces, dtype=float, order="C")
    return np.array([np.asarray(f, dtype=float) for f in normal_forces])


def soil_message(vehicle_id: str, seq: int, stamp: float, inp: SoilInputs, st: SoilState, mu, mu_determined,
                 latency: float, j: int, **where) -> SoilEstimate:
    """The j-th vehicle of a soil-kernel step as the SoilEstimate message: slip (4,) from ``inp``,
    K, its std (and ln K's), class, status and reason from ``st``, the observer's mu (4,), its
    determined flags (4,) and ground-speed latency estimate (s) passed through; ``where=`` the
    estimate's place, where it has one."""
    # the model's validator on the fields (what SoilEstimate(**fields) runs, without the keyword call)
    return _validate_soil(dict(
        vehicle_id=vehicle_id, seq=seq, stamp=stamp, slip=_quad(inp.slip[j]), informative=st.used,
        soil_strength=st.soil_strength, soil_strength_std=st.soil_strength_std, log_k_std=st.log_k_std,
        soil_class=st.soil_class, soil_class_confidence=st.soil_class_confidence, status=st.status,
        reason=st.reason, reason_code=st.reason_code, last_update_stamp=st.last_update_stamp, mu=_quad(mu),
        mu_determined=_bools(mu_determined), ground_speed_latency=float(latency), held_for_s=st.held_for_s,
        unusable=st.unusable, **where,
    ))


_validate_soil = SoilEstimate.__pydantic_validator__.validate_python


class Estimator:
    """The chain of ``n_vehicles`` vehicles (module doc): normal forces come from outside (the
    normal-force stage is per sample and needs no state).

    Parameters
    ----------
    config : PipelineConfig or None
        The physics settings (None: the defaults).
    n_vehicles : int
        Vehicles of the bank, indexed 0 .. N-1.
    priors : sequence of MapPrior or None, optional
        Each vehicle's fleet-map prior (None for a vehicle without one; None: no vehicle has one).  On
        entering a mapped cell the vehicle's belief starts from the map's K and band, and the wheels
        still on the ground left behind do not inform it (:mod:`soilocp.map.prior`).
    """

    def __init__(self, config: PipelineConfig | None = None, n_vehicles: int = 1, priors: Sequence | None = None):
        self.config = cfg = config or PipelineConfig()
        self.n_vehicles = n = check_count(n_vehicles)
        self.priors = list(priors) if priors is not None else None
        if self.priors is not None and len(self.priors) != n:
            raise ValueError(f"priors: {len(self.priors)} given for {n} vehicles")
        self.observer = ObserverBank(cfg.vehicle, cfg.observer, n, bridge_slip=cfg.constants.bridge_slip)
        self.gate = SlipGate(cfg, n)
        # the paper's rule (method "paper") replaces the grid update; it is not in the core, whose chain still
        # holds a grid bank (of the default method's settings, never stepped then)
        self.paper = [PaperSoilEstimator(cfg.constants, cfg.soil) for _ in range(n)] \
            if cfg.soil.method == "paper" else None
        self.soil = SoilBank(cfg.constants, cfg.soil if self.paper is None else
                             cfg.soil.model_copy(update={"method": "bayes"}), n)
        self.scale = TorqueScaleBank(cfg.vehicle, cfg.torque_scale, cfg.soil.gross_scale_sigma, n, cfg.constants,
                                     slip_floor=cfg.slip_floor, gravity=cfg.observer.gravity)
        self.curve = WheelCurve(cfg, n)  # the wheel's learnt curve and the OCP records' rule
        self.chain = _core.ChainCore(self.observer._core, self.gate.core, self.soil.core, self.scale._core,
                                     feed_soil=self.scale.active and cfg.torque_scale.model_resistance)
        # each vehicle's index as the core's (1,) int64 array, for the stage steps (read-only: shared by every call)
        self._ix: list[np.ndarray] = []
        for j in range(n):
            a = np.array([j], dtype=np.int64)
            a.flags.writeable = False
            self._ix.append(a)

    def _one(self, j: int) -> np.ndarray:
        """Vehicle ``j`` as the core's (1,) index array (one out of range goes to the core as it is, which refuses it)."""
        return self._ix[j] if 0 <= j < self.n_vehicles else np.array([j], dtype=np.int64)

    @property
    def feeds_soil(self) -> bool:
        """Whether K goes back to the torque scale (its modelled motion resistance, eq. 4): the scale is
        learnt and ``torque_scale.model_resistance`` is set."""
        return self.chain.feeds_soil

    # ---- the whole step -------------------------------------------------------------------------------

    def step(self, idx, samples: Sequence[SensorSample], normal_forces: Sequence) -> list[OcpEstimate]:
        """One sample per vehicle in ``idx`` (same order): the OCP record of each."""
        return self.step_all(idx, samples, normal_forces)[2]

    def step_all(self, idx, samples: Sequence[SensorSample],
                 normal_forces: Sequence) -> tuple[ObserverBlocks, list[SoilEstimate], list[OcpEstimate]]:
        """The whole step of one sample per vehicle in ``idx`` (same order), in one core call: the
        observer's output (arrays, one row per vehicle), and each vehicle's soil estimate and OCP record.
        ValueError for the paper's soil method (no whole step: run the stage steps)."""
        if self.paper is not None:
            raise ValueError(f"soil method {self.config.soil.method!r}: the whole step implements 'bayes' only")
        ix = self.observer.index(idx)
        inputs = observer_inputs(samples, normal_forces, self.config.torque_constant)
        informing = self._map_prior(ix, samples)
        call = self.chain.step if informing is None else (lambda i, x: self.chain.step(i, x, informing))
        blocks, fields, report, ocp = self.observer.run(call, ix, inputs)
        ob, inp = ObserverBlocks(*blocks), SoilInputs(*fields)
        states = self.soil.states(ix, inputs.stamp, inp, report)
        soils, ocps = [], []
        for j, (sample, st) in enumerate(zip(samples, states)):
            soil = soil_message(sample.vehicle_id, sample.seq, sample.stamp, inp, st, ob.mu[j], ob.mu_determined[j],
                                ob.ground_speed_latency[j], j)
            soils.append(soil)
            ocps.append(self.curve.record(int(ix[j]), soil, [a[j] for a in ocp]))
        return ob, soils, ocps

    def _map_prior(self, ix: np.ndarray, places: Sequence):
        """The map priors' part of a step of the vehicles ``ix`` at ``places`` (anything with ``position``
        and ``geo``): a belief that enters a mapped cell starts from it now (before the update, which is
        the first stage that reads it), and the (k, 4) flags of the wheels that may inform K, or None
        when no wheel is held out."""
        if self.priors is None:
            return None
        informing = None
        for j, place in enumerate(places):
            prior = self.priors[int(ix[j])]
            if prior is None:
                continue
            start = prior(place)
            if start is not None:
                self.soil.start_belief(int(ix[j]), *start)
            on = prior.informing(place)
            if on is not None:
                if informing is None:
                    informing = np.ones((len(places), 4), dtype=bool)
                informing[j] = on
        return informing

    # ---- the stage steps (one vehicle, the live services' messages) -----------------------------------

    def observe(self, j: int, sample: SensorSample, forces: NormalForces) -> ObserverOutput:
        """Vehicle ``j``'s observer stage: the torque scale and one predict + gated update of the
        observer (eqs. 26-35 with the §7 state) on the sample and its normal forces (4,) N, same seq.

        Returns per wheel (4,): net traction mu (eq. 6's F_DP/W) and its variance, motion resistance
        (eq. 4 with |S|, §11), gross traction mu + mu_MR (what eq. 13 sees) and its variance, the
        filtered wheel speeds; the filtered ground speed and yaw rate; whether each mu is determined
        (posterior 1-sigma <= ``mu_std_determined``, §12), any reset's reason, and the torque scale's
        mean and relative 1-sigma once it has left its prior.  ValueError when the forces belong to
        another sample."""
        if forces.seq != sample.seq or forces.vehicle_id != sample.vehicle_id:
            raise ValueError(
                f"normal forces are for {forces.vehicle_id}#{forces.seq}, sample is {sample.vehicle_id}#{sample.seq}"
            )
        ix = self._one(j)
        inputs = observer_inputs((sample,), (forces.normal_force,), self.config.torque_constant)
        blocks, scaled = self.observer.run(self.chain.observe, ix, inputs)
        out = ObserverBlocks(*blocks)
        # the sample's position and geo, for the soil estimate's place (docs/map.md)
        place = sample if sample.position is not None or sample.geo is not None else None
        if scaled is None:
            return observer_message(sample.vehicle_id, sample.seq, sample.stamp, out, 0, place=place)
        return observer_message(sample.vehicle_id, sample.seq, sample.stamp, out, 0, float(scaled[0][0]),
                                float(scaled[1][0]), place=place)

    def update(self, j: int, obs: ObserverOutput) -> SoilEstimate:
        """Vehicle ``j``'s soil stage: slip per wheel (eq. 1) from the filtered speeds, the gate (§9),
        the map prior where the vehicle has one, and one update of the ln K grid with the wheels'
        (slip, gross traction) pairs the gate lets through (or the paper's rule).

        Returns K (>0, dimensionless, the paper's soil strength) and its 1-sigma, the soil class
        with its probability, and a status that says when K is not determined, not observable, or
        not explained by the traction curve (§11-13), with the reason."""
        ix = self._one(j)
        rows = pack_message(obs)  # the observer's output as the one array the core reads
        stamp = np.array([obs.stamp])
        scale_sigma = None if obs.torque_scale_std is None else np.array([obs.torque_scale_std])
        informing = self._map_prior(ix, [obs])
        if self.paper is None:
            fields, report = self.chain.update(ix, stamp, rows, scale_sigma, informing)
            inp = SoilInputs(*fields)
            st = self.soil.states(ix, stamp, inp, report)[0]
        else:
            inp = self.gate.step(ix, stamp, rows)
            use = inp.informative[0] & ~inp.held[0] & ~inp.ground_stale[0]
            if informing is not None:
                use = use & informing[0]
            st = self.paper[j].update(obs.stamp, inp.slip[0], inp.observed[0], inp.variance[0], use,
                                      inp.slip_sigma[0])
        if obs.position is not None or obs.geo is not None:  # where: the informing wheels' contact patches
            return soil_message(obs.vehicle_id, obs.seq, obs.stamp, inp, st, obs.mu, obs.mu_determined,
                                obs.ground_speed_latency, 0,
                                where=estimate_place(self.config.vehicle, obs.position, obs.geo, st.used))
        return soil_message(obs.vehicle_id, obs.seq, obs.stamp, inp, st, obs.mu, obs.mu_determined,
                            obs.ground_speed_latency, 0)

    def feed(self, j: int, soil: SoilEstimate) -> None:
        """Vehicle ``j``'s soil estimate back to its torque scale: the next samples' modelled motion
        resistance (eq. 4) is at this K (None: none, the last is kept) and these slips, as in
        :meth:`step_all`.  Nothing unless :attr:`feeds_soil`."""
        if not self.chain.feeds_soil:
            return
        k = np.array([np.nan if soil.soil_strength is None else soil.soil_strength])
        self.chain.feed(self._one(j), k, np.array([soil.slip], dtype=float))
