"""Observer service: joins clean samples with their normal forces by seq and runs the torque scale
and the Kalman observer (``ObserverStage``, the estimator's observer stage) on every sample, in order.

Inputs ``soilocp/<vid>/sensors/clean`` and ``soilocp/<vid>/normal_forces``, both fed into the
same bounded worker queue (so arrival order is kept); output ``soilocp/<vid>/observer``.
The join buffer is bounded: a sample whose normal forces never come (normal-force service down)
is dropped after ``join_timeout_s`` once later forces have arrived, or when the buffer is full,
and counted (``dropped``, detail ``unjoined``).

When the torque scale models the motion resistance at the soil's K (``torque_scale.model_resistance``)
the service also subscribes ``soilocp/<vid>/soil``: K goes back to the scale as in the estimator's whole
step (offline, batched), where sample n is stepped with the K and slips of sample n - 1.  So each joined
sample waits (:class:`SoilFeedback`) until the soil estimate of the sample stepped before it has come
back, for at most ``soil_feed_timeout_s``.  Past that (soil-strength service down or slow) the sample
is stepped with the last K fed, counted (detail ``soil_feed_late``), and the samples after it no longer
wait until a soil estimate arrives again; a soil estimate that comes late is still fed, if newer than the
last.  So live equals offline while every soil estimate comes back within the timeout, and otherwise a
sample's K is that of an earlier sample, never a later one.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from typing import Any, Callable, Optional

from soilocp.schemas.pipeline import NormalForces, SoilEstimate
from soilocp.schemas.sensor import SensorSample
from soilocp.services.runtime.worker import Counters, WorkItem
from soilocp.services.stages.graph import BY_NAME
from soilocp.services.stages.stage_service import StageService


class SeqJoiner:
    """Pairs samples with normal forces by seq; emits pairs in sample order, never out of order.

    Samples arrive in seq order (the gateway enforces it); forces arrive later, in order too.
    ``emit(sample, forces)`` is called for each complete pair at the head of the queue.
    """

    def __init__(self, emit: Callable[[SensorSample, NormalForces], None], counters: Counters, *,
                 capacity: int = 256, timeout_s: float = 0.2, clock: Callable[[], float] = time.monotonic):
        self.emit = emit
        self.c = counters
        self.capacity = int(capacity)
        self.timeout_s = float(timeout_s)
        self.clock = clock
        self.samples: deque[tuple[SensorSample, float]] = deque()
        self.forces: OrderedDict[int, NormalForces] = OrderedDict()
        self.last_emitted: Optional[int] = None

    def add_sample(self, sample: SensorSample) -> None:
        tail = self.samples[-1][0].seq if self.samples else self.last_emitted
        if tail is not None and sample.seq <= tail:
            # only after a gateway restart: the observer must not see time run backwards
            self._drop("out_of_order")
            return
        self.samples.append((sample, self.clock()))
        self._drain()

    def add_forces(self, forces: NormalForces) -> None:
        if self.last_emitted is not None and forces.seq <= self.last_emitted:
            self.c.bump("late_forces")
            return
        self.forces[forces.seq] = forces
        while len(self.forces) > self.capacity:
            self.forces.popitem(last=False)
            self.c.bump("forces_overflow")
        self._drain()

    def _drop(self, why: str) -> None:
        self.c.dropped += 1
        self.c.bump(why)

    def _drain(self) -> None:
        now = self.clock()
        while self.samples:
            sample, t_in = self.samples[0]
            f = self.forces.pop(sample.seq, None)
            if f is not None:
                self.samples.popleft()
                self.last_emitted = sample.seq
                self.emit(sample, f)
                continue
            later = bool(self.forces) and next(reversed(self.forces)) > sample.seq
            if len(self.samples) > self.capacity or (later and now - t_in > self.timeout_s):
                self.samples.popleft()  # its forces are lost: the observer moves on (and logs the gap)
                self._drop("unjoined")
                continue
            break
        # forces for samples already skipped can never join
        head = self.samples[0][0].seq if self.samples else None
        if head is not None:
            while self.forces and next(iter(self.forces)) < head:
                self.forces.popitem(last=False)
                self.c.bump("orphan_forces")

    def pending(self) -> int:
        return len(self.samples)


class SoilFeedback:
    """One vehicle's joined samples, each stepped once the soil estimate of the sample stepped before it
    has come back and been fed to the torque scale (module doc).

    ``step(sample, forces)`` steps the observer stage; ``feed(soil)`` passes a soil estimate to its torque
    scale.  ``capacity`` samples wait at most (more: the oldest is stepped without its K, counted late),
    each for at most ``timeout_s`` after the sample before it was stepped.
    """

    def __init__(self, step: Callable[[SensorSample, NormalForces], None], feed: Callable[[SoilEstimate], None],
                 counters: Counters, *, capacity: int = 256, timeout_s: float = 0.2,
                 clock: Callable[[], float] = time.monotonic):
        self.step, self.feed, self.c = step, feed, counters
        self.capacity = int(capacity)
        self.timeout_s = float(timeout_s)
        self.clock = clock
        self.held: deque[tuple[SensorSample, NormalForces]] = deque()
        #: the seq of the last sample stepped whose soil estimate has not come back (None: none awaited)
        self.awaiting: Optional[int] = None
        self.stepped_at = 0.0  # clock of that step
        self.fed_seq: Optional[int] = None
        #: False after a timeout: the samples do not wait until a soil estimate arrives again
        self.waiting = True
        self.c.detail.setdefault("soil_feed_late", 0)
        self.c.detail.setdefault("soil_fed", 0)

    def add_pair(self, sample: SensorSample, forces: NormalForces) -> None:
        self.held.append((sample, forces))
        self.drain()

    def add_soil(self, soil: SoilEstimate) -> None:
        if self.fed_seq is None or soil.seq > self.fed_seq:
            self.feed(soil)
            self.fed_seq = soil.seq
            self.c.detail["soil_fed"] += 1
        self.waiting = True
        if self.awaiting is not None and soil.seq >= self.awaiting:
            self.awaiting = None
        self.drain()

    def due(self, now: float) -> bool:
        """Whether a held sample has waited past the timeout (:meth:`drain` would step it)."""
        return bool(self.held) and self.awaiting is not None and now - self.stepped_at > self.timeout_s

    def drain(self) -> None:
        while self.held:
            if self.awaiting is not None and self.waiting:
                if self.clock() - self.stepped_at <= self.timeout_s and len(self.held) <= self.capacity:
                    return
                self.c.detail["soil_feed_late"] += 1
                self.waiting = False
            sample, forces = self.held.popleft()
            self.step(sample, forces)
            self.awaiting, self.stepped_at = sample.seq, self.clock()

    def pending(self) -> int:
        return len(self.held)


class ObserverService(StageService):
    """The observer row: its two inputs are joined by seq before the stage steps."""

    spec = BY_NAME["observer"]

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        # K back to the torque scale, where it models the motion resistance at it (module doc)
        self.feedback: dict[str, SoilFeedback] = {
            vid: SoilFeedback(lambda s, f, _vid=vid: self._step(_vid, s, f), self.stages[vid].feed, self.counters[vid],
                              capacity=cfg.join_buffer, timeout_s=cfg.soil_feed_timeout_s)
            for vid in cfg.vehicle_ids if vid in self.stages and self.stages[vid].feeds_soil  # a relay has none
        }
        self.joiners = {
            vid: SeqJoiner(self.feedback[vid].add_pair if vid in self.feedback else
                           (lambda s, f, _vid=vid: self._step(_vid, s, f)), self.counters[vid],
                           capacity=cfg.join_buffer, timeout_s=cfg.join_timeout_s)
            for vid in cfg.vehicle_ids
        }

    def declare(self, session, vehicle_id: str) -> None:
        super().declare(session, vehicle_id)
        if vehicle_id in self.feedback:
            for inp in self.spec.feedback:  # the soil estimates
                self.subscribe(session, inp.key(vehicle_id), vehicle_id, inp.kind)

    def handle(self, item: WorkItem) -> None:
        if item.kind == "soil":
            self.feedback[item.vehicle_id].add_soil(self.parsers["soil"](item.payload))
        elif item.kind == "feed_timeout":
            self.feedback[item.vehicle_id].drain()
        else:
            super().handle(item)

    def ticks(self) -> bool:
        return bool(self.feedback)  # the soil feed's timeouts: nothing to time without a feedback

    def tick(self, now: float) -> None:
        mono = time.monotonic()
        for vid, fb in self.feedback.items():
            if fb.due(mono):  # the worker steps it: the stages are the worker's
                self.worker.offer(WorkItem(vid, "feed_timeout", b"", now, ""))

    def accept(self, vehicle_id: str, kind: str, message) -> None:
        if kind == "sample":
            self.joiners[vehicle_id].add_sample(message)
        else:
            self.joiners[vehicle_id].add_forces(message)

    def _step(self, vid: str, sample: SensorSample, forces: NormalForces) -> None:
        out = self.stages[vid].step(sample, forces)
        if out.reset_reason in ("non_finite_state", "state_out_of_physics"):
            self.log.warning("observer_reset", vehicle_id=vid, seq=out.seq, reason=out.reset_reason)
        self.emit(vid, out)

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        resets = {f"reset_{why}": n for why, n in self.stages[vehicle_id].bank.resets_by_reason.items() if n}
        bank = self.stages[vehicle_id].bank
        fb = self.feedback.get(vehicle_id)
        return {"detail": {**self.counters[vehicle_id].detail, **resets, "wheel_speed_anchored": bank.anchored,
                           "join_pending": self.joiners[vehicle_id].pending(),
                           **({} if fb is None else {"soil_feed_pending": fb.pending()})}}
