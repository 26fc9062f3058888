"""Offline estimation: a sensor log (JSON Lines) in, one OCP record per valid sample out.

The same validation and the same pipeline stages as the live services.  Invalid lines are
reported with their line number and skipped, never fatal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, Optional

from schemas.sensor import SensorSample
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
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


def estimate_lines(
    lines: Iterable[str],
    config: PipelineConfig,
    *,
    on_reject: Optional[Callable[[int, SampleRejected], None]] = None,
    full: bool = False,
    summary: Optional[EstimateSummary] = None,
) -> Iterator[dict]:
    """Yield one record (a dict) per valid sample; ``full`` adds the intermediate stage outputs."""
    for _, rec in estimate_samples(lines, config, on_reject=on_reject, full=full, summary=summary):
        yield rec


def estimate_samples(
    lines: Iterable[str],
    config: PipelineConfig,
    *,
    on_reject: Optional[Callable[[int, SampleRejected], None]] = None,
    full: bool = False,
    summary: Optional[EstimateSummary] = None,
) -> Iterator[tuple[SensorSample, dict]]:
    """:func:`estimate_lines`, each record with the validated sensor sample it was estimated from
    (the MCAP export writes both, so the file carries the same channels as the live server)."""
    pipelines: dict[str, VehiclePipeline] = {}
    validators: dict[str, SampleValidator] = {}
    summary = summary if summary is not None else EstimateSummary()
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
        pipe = pipelines.get(sample.vehicle_id)
        if pipe is None:
            pipe = pipelines[sample.vehicle_id] = VehiclePipeline(config)
        try:
            nf, ob, so, oc = pipe.process_all(sample)
        except Exception as exc:  # no exception escapes a stage: restart this vehicle's chain, keep going
            summary.stage_errors.append((lineno, f"{type(exc).__name__}: {exc}"[:300]))
            pipelines[sample.vehicle_id] = VehiclePipeline(config)
            continue
        if ob.reset_reason:
            summary.resets[ob.reset_reason] = summary.resets.get(ob.reset_reason, 0) + 1
        summary.estimates += 1
        summary.vehicles.add(sample.vehicle_id)
        summary.statuses[oc.status] = summary.statuses.get(oc.status, 0) + 1
        for why in so.unusable:
            if why:
                summary.unusable[why] = summary.unusable.get(why, 0) + 1
        rec = oc.model_dump()
        if full:
            rec["normal_force"] = list(nf.normal_force)
            rec["gross"] = list(ob.gross)
            rec["resistance"] = list(ob.resistance)
            rec["mu_var"] = list(ob.mu_var)
            rec["filtered_ground_speed"] = ob.ground_speed
            rec["ground_speed_latency"] = ob.ground_speed_latency
            rec["informative"] = list(so.informative)
        yield sample, rec

