"""Offline estimation: a sensor log (JSON Lines) in, one OCP record per valid sample out.

The same validation as the live services, and the same chain: each vehicle's is the estimator's
whole step, one core call per sample (:class:`soilocp.estimation.estimator.Estimator` with N = 1: the
stage steps the live services run one each, called in order, without the messages between them),
or, for the paper's soil method, those stage steps with their messages
(:class:`soilocp.estimation.pipeline.VehiclePipeline`).  A fleet-map prior per vehicle is optional
(``map_prior``).  Invalid lines are
reported with their line number and skipped, never fatal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Iterator, NamedTuple, Optional

import numpy as np

from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate
from soilocp.schemas.sensor import SensorSample
from soilocp.estimation.batch import BatchPipeline
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
from soilocp.estimation.vehicle_check import VehicleFit
from soilocp.model.normal_force import NormalForceSolver
from soilocp.validation import SampleRejected, SampleValidator, parse_sample


@dataclass
class EstimateSummary:
    lines: int = 0
    estimates: int = 0
    rejected: list[tuple[int, str, str]] = field(default_factory=list)  # (line number, code, message)
    vehicles: set[str] = field(default_factory=set)
    statuses: dict[str, int] = field(default_factory=dict)
    #: samples whose processing raised (line number, error): that vehicle's chain restarts, the log goes on
    stage_errors: list[tuple[int, str]] = field(default_factory=list)
    #: observer resets by reason, over all vehicles (start, time_gap, non_finite_state, ...)
    resets: dict[str, int] = field(default_factory=dict)
    #: wheel-samples the longitudinal model did not describe (no K from them), by reason (docs/method.md §17)
    unusable: dict[str, int] = field(default_factory=dict)
    #: records per (status, reason code): what ``soilocp estimate`` ends with (soilocp.estimation.next_steps)
    reasons: dict[tuple[str, str], int] = field(default_factory=dict)
    #: what the validated samples say of the vehicle (soilocp.estimation.vehicle_check)
    fit: VehicleFit = field(default_factory=VehicleFit)

    def rejected_by_code(self) -> dict[str, int]:
        """The rejected lines counted per rejection code (soilocp.validation.REJECTION_CODES)."""
        out: dict[str, int] = {}
        for _, code, _ in self.rejected:
            out[code] = out.get(code, 0) + 1
        return out

    def rejected_by_code(self) -> dict[str, int]:
        """How many lines were rejected, per rejection code (``too_large``, ``schema``, ...)."""
        out: dict[str, int] = {}
        for _, code, _ in self.rejected:
            out[code] = out.get(code, 0) + 1
        return out


class Observed(NamedTuple):
    """What a record takes from the observer (``full``) and the summary counts (its reset)."""

    reset_reason: str
    gross: list[float]
    resistance: list[float]
    mu_var: list[float]
    ground_speed: float
    ground_speed_latency: float


class _Chain:
    """One vehicle's chain in one core call per sample (``BatchPipeline``, N = 1), after the normal-force
    stage's solver (eqs. 21-25)."""

    _ONE = np.zeros(1, dtype=np.int64)

    def __init__(self, config: PipelineConfig, prior=None):
        self._solve = NormalForceSolver(config.vehicle)
        self._batch = BatchPipeline(config, 1, None if prior is None else [prior])

    def process_all(self, sample: SensorSample) -> tuple[list[float], Observed, SoilEstimate, OcpEstimate]:
        fz = self._solve(sample.specific_force)
        # (a non-finite observer output, which the stages' ObserverOutput message refuses, the chain refuses too)
        ob, soils, ocps = self._batch.step_all(self._ONE, [sample], [fz])
        seen = Observed(ob.reset_reason[0], ob.gross[0].tolist(), ob.resistance[0].tolist(), ob.mu_var[0].tolist(),
                        float(ob.ground_speed[0]), float(ob.ground_speed_latency[0]))
        return fz.tolist(), seen, soils[0], ocps[0]


class _Stages:
    """One vehicle's four stages with their messages (the paper's soil method, which the core's bank does not run)."""

    def __init__(self, config: PipelineConfig, prior=None):
        self._pipe = VehiclePipeline(config, prior)

    def process_all(self, sample: SensorSample) -> tuple[list[float], Observed, SoilEstimate, OcpEstimate]:
        nf, ob, so, oc = self._pipe.process_all(sample)
        seen = Observed(ob.reset_reason, list(ob.gross), list(ob.resistance), list(ob.mu_var), ob.ground_speed,
                        ob.ground_speed_latency)
        return list(nf.normal_force), seen, so, oc


def vehicle_chain(config: PipelineConfig, prior=None):
    """The offline chain of one vehicle for ``config`` (module doc), with its fleet-map ``prior``
    (:class:`soilocp.map.prior.MapPrior`, or None)."""
    return _Chain(config, prior) if config.soil.method == "bayes" else _Stages(config, prior)


def estimate_lines(lines: Iterable[str], config: PipelineConfig, **options: Any) -> Iterator[dict]:
    """Yield one record (a dict) per valid sample: :func:`estimate_samples` without the samples, with its
    keyword options (``on_reject``, ``full``: the intermediate stage outputs too, ``summary``, ``map_prior``:
    a vehicle's fleet-map prior by its id)."""
    return (rec for _, rec in estimate_samples(lines, config, **options))


def estimate_samples(
    lines: Iterable[str],
    config: PipelineConfig,
    *,
    on_reject: Optional[Callable[[int, SampleRejected], None]] = None,
    full: bool = False,
    summary: Optional[EstimateSummary] = None,
    map_prior: Optional[Callable[[str], object]] = None,
) -> Iterator[tuple[SensorSample, dict]]:
    """:func:`estimate_lines`, each record with the validated sensor sample it was estimated from
    (the MCAP export writes both, so the file carries the same channels as the live server)."""
    pipelines: dict[str, _Chain | _Stages] = {}
    validators: dict[str, SampleValidator] = {}
    summary = summary if summary is not None else EstimateSummary()
    radius, mass, k_torque = config.vehicle.wheel_radius, config.vehicle.mass, config.torque_constant
    for lineno, line in enumerate(lines, start=1):
        summary.lines += 1
        if not line.strip():
            continue
        try:
            sample = parse_sample(line)
            validators.setdefault(sample.vehicle_id, SampleValidator()).check(sample)
        except SampleRejected as exc:
            summary.rejected.append((lineno, exc.code, exc.message))
            if on_reject:
                on_reject(lineno, exc)
            continue
        summary.fit.add(sample, radius, mass, k_torque)
        pipe = pipelines.get(sample.vehicle_id)
        if pipe is None:
            pipe = pipelines[sample.vehicle_id] = vehicle_chain(config, map_prior and map_prior(sample.vehicle_id))
        try:
            nf, ob, so, oc = pipe.process_all(sample)
        except Exception as exc:  # no exception escapes a stage: restart this vehicle's chain, keep going
            summary.stage_errors.append((lineno, f"{type(exc).__name__}: {exc}"[:300]))
            pipelines[sample.vehicle_id] = vehicle_chain(config, map_prior and map_prior(sample.vehicle_id))
            continue
        if ob.reset_reason:
            summary.resets[ob.reset_reason] = summary.resets.get(ob.reset_reason, 0) + 1
        summary.estimates += 1
        summary.vehicles.add(sample.vehicle_id)
        summary.statuses[oc.status] = summary.statuses.get(oc.status, 0) + 1
        why = (oc.status, oc.reason_code)
        summary.reasons[why] = summary.reasons.get(why, 0) + 1
        for why in so.unusable:
            if why:
                summary.unusable[why] = summary.unusable.get(why, 0) + 1
        rec = oc.model_dump()
        if full:
            rec["normal_force"] = nf
            rec["gross"] = ob.gross
            rec["resistance"] = ob.resistance
            rec["mu_var"] = ob.mu_var
            rec["filtered_ground_speed"] = ob.ground_speed
            rec["ground_speed_latency"] = ob.ground_speed_latency
            rec["informative"] = list(so.informative)
        yield sample, rec

