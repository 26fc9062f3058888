"""Sensor gateway: validates raw samples, publishes clean ones, rejects the rest with a reason.

Input ``soilocp/<vid>/sensors/raw``; output ``soilocp/<vid>/sensors/clean`` (SensorSample JSON)
and ``soilocp/<vid>/rejected`` (Rejection JSON).  The checks are the library's
(:func:`soilocp.validation.parse_sample`, :class:`soilocp.validation.SampleValidator`), the same
that ``soilocp estimate`` applies offline, with the same size limit before any parsing
(:data:`soilocp.validation.MAX_PAYLOAD_BYTES`, configurable as ``max_payload_bytes``), plus a transport
check: the key.  Nothing a sender puts on the raw key can crash it: every failure becomes a
Rejection, counted per code in the service's health (``rejected_too_large``, ...).  The process
imports neither numpy nor the estimation package (tests/test_gateway_lean.py).
"""

from __future__ import annotations

import time
from typing import Any, Optional, Union

from soilocp.schemas import keys
from soilocp.schemas.messages import REJECTION_PAYLOAD_MAX, REJECTION_PUBLISH_RATE, Rejection
from soilocp.schemas.sensor import SensorSample
from soilocp.validation import MAX_PAYLOAD_BYTES, SampleRejected, SampleValidator, parse_sample

from soilocp.services.runtime.worker import WorkItem
from soilocp.services.stages.graph import BY_NAME
from soilocp.services.stages.stage_service import StageService




def _peek(payload: bytes) -> dict:
    """Best-effort read of the top-level fields of a rejected payload (for the Rejection): one parse."""
    import json

    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return {}
    return obj if isinstance(obj, dict) else {}


class RawSampleChecker:
    """The gateway's decision for one vehicle, without any transport: sample or Rejection."""

    def __init__(self, vehicle_id: str, *, max_payload_bytes: int = MAX_PAYLOAD_BYTES):
        self.vehicle_id = keys.check_vehicle_id(vehicle_id)
        self.raw_key = keys.raw(vehicle_id)
        self.max_payload_bytes = int(max_payload_bytes)
        self.validator = SampleValidator()

    def check(self, payload: bytes, key: Optional[str] = None, received_at: Optional[float] = None
              ) -> Union[SensorSample, Rejection]:
        key = self.raw_key if key is None else key
        received_at = time.time() if received_at is None else received_at
        try:
            if key != self.raw_key:
                raise SampleRejected("bad_key", f"key: sample arrived on {key!r}, expected exactly {self.raw_key!r}")
            # the size first, then the parse: the library's, with the limit of soilocp estimate unless configured
            sample = parse_sample(payload, expected_vehicle_id=self.vehicle_id, max_bytes=self.max_payload_bytes)
            self.validator.check(sample, received_at)  # updates the ordering state only when accepted
            return sample
        except SampleRejected as rej:
            return self._rejection(rej.code, rej.message, rej.seq, payload, key, received_at)

    def _rejection(self, code: str, message: str, seq, payload: bytes, key: str, received_at: float) -> Rejection:
        fields = _peek(payload) if len(payload) <= self.max_payload_bytes else {}
        if seq is None:
            s = fields.get("seq")
            seq = s if isinstance(s, int) and not isinstance(s, bool) and s >= 0 else None
        stamp = fields.get("stamp")
        stamp = float(stamp) if isinstance(stamp, (int, float)) and not isinstance(stamp, bool) else None
        if stamp is not None and not (stamp == stamp and abs(stamp) < float("inf")):
            stamp = None
        field = message.split(":", 1)[0] if ":" in message else None
        if field is not None and (" " in field or len(field) > 80):
            field = None
        text = payload[: REJECTION_PAYLOAD_MAX * 4].decode("utf-8", errors="replace")[:REJECTION_PAYLOAD_MAX]
        return Rejection(
            vehicle_id=self.vehicle_id,
            seq=seq,
            stamp=stamp,
            code=code,
            field=field,
            message=message[:1000],
            payload=text,
            payload_size=len(payload),
            key=key[:300],
            received_at=received_at,
        )


class PublishBudget:
    """A token bucket: at most ``rate`` events a second, in bursts of up to ``burst``.

    Parameters
    ----------
    rate : float
        Tokens added per second.
    burst : float
        The bucket's size (and its content at the start).
    """

    def __init__(self, rate: float, burst: float):
        self.rate, self.burst = rate, burst
        self.tokens, self.last = burst, time.monotonic()

    def take(self, now: Optional[float] = None) -> bool:
        """Whether an event may pass now (it takes a token)."""
        now = time.monotonic() if now is None else now
        self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
        self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class GatewayService(StageService):
    """The gateway row: raw bytes are checked here (no model parses them first); a rejection goes
    to ``soilocp/<vid>/rejected`` with its reason, at most ``REJECTION_PUBLISH_RATE`` a second per vehicle
    (the next published one counts those not published in ``suppressed``)."""

    spec = BY_NAME["gateway"]
    needs_key = True  # the raw sample's own key is checked (bad_key)

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        self.checkers = {vid: RawSampleChecker(vid, max_payload_bytes=cfg.max_payload_bytes) for vid in cfg.vehicle_ids}
        self.pub_rejected: dict[str, Any] = {}
        self.budgets = {vid: PublishBudget(REJECTION_PUBLISH_RATE, REJECTION_PUBLISH_RATE) for vid in cfg.vehicle_ids}
        self.suppressed = dict.fromkeys(cfg.vehicle_ids, 0)

    def declare(self, session, vehicle_id: str) -> None:
        self.pub_rejected[vehicle_id] = self.publisher(session, keys.rejected(vehicle_id))
        super().declare(session, vehicle_id)

    def handle(self, item: WorkItem) -> None:
        vid = item.vehicle_id
        c = self.counters[vid]
        c.last_input_wall = item.wall
        checker = self.checkers[vid]
        conflicts = checker.validator.conflicts
        result = checker.check(item.payload, item.key, item.wall)
        if isinstance(result, Rejection):
            c.rejected += 1
            c.bump(f"rejected_{result.code}")
            if checker.validator.conflicts != conflicts:  # a second publisher on the key (SampleValidator)
                c.bump("source_conflicts")
            if c.rejected <= 50 or c.rejected % 100 == 0:  # a flood of garbage must not flood the log
                self.log.warning("rejected", vehicle_id=vid, code=result.code, seq=result.seq,
                                 message=result.message[:300], rejected_total=c.rejected)
            if not self.budgets[vid].take():
                self.suppressed[vid] += 1
                c.bump("rejections_unpublished")
                return
            if self.suppressed[vid]:
                result = result.model_copy(update={"suppressed": self.suppressed[vid]})
                self.suppressed[vid] = 0
            self.pub_rejected[vid].put(result.model_dump_json())
            return
        self.emit(vid, result)
