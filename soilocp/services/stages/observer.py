"""Observer service: joins clean samples with their normal forces by seq and runs the Kalman
observer (``ObserverStage``) on every sample, in order.

Inputs ``soilocp/<vid>/sensors/clean`` and ``soilocp/<vid>/normal_forces``, both fed into the
same bounded worker queue (so arrival order is kept); output ``soilocp/<vid>/observer``.
The join buffer is bounded: a sample whose normal forces never come (normal-force service down)
is dropped after ``join_timeout_s`` once later forces have arrived, or when the buffer is full,
and counted (``dropped``, detail ``unjoined``).
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from typing import Any, Callable, Optional

from soilocp.schemas.pipeline import NormalForces
from soilocp.schemas.sensor import SensorSample
from soilocp.services.runtime.worker import Counters
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


class ObserverService(StageService):
    """The observer row: its two inputs are joined by seq before the stage steps."""

    spec = BY_NAME["observer"]

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        self.joiners = {
            vid: SeqJoiner(lambda s, f, _vid=vid: self._step(_vid, s, f), self.counters[vid],
                           capacity=cfg.join_buffer, timeout_s=cfg.join_timeout_s)
            for vid in cfg.vehicle_ids
        }

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
        return {"detail": {**self.counters[vehicle_id].detail, **resets, "wheel_speed_anchored": bank.anchored,
                           "join_pending": self.joiners[vehicle_id].pending()}}
