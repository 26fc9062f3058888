"""Validation of raw sensor samples beyond the schema: the checks that need per-vehicle history.

Used by the live gateway and by the offline ``soilocp estimate`` alike, so both reject the same
samples for the same reasons.  Each rejection carries a machine-readable ``code``.  A lean module
(json, math, pydantic and the sensor schema): the gateway process imports it without numpy or the
estimation package.
"""

from __future__ import annotations

import json
import math
from typing import IO, Iterator, Optional

from pydantic import ValidationError

from soilocp.schemas.sensor import SensorSample, format_validation_error

#: Byte limit of one raw sample (a gateway payload, a line of a sensor log), checked before any parsing.
#: The largest valid SensorSample (a 64-character vehicle id, every number at full float precision) is
#: about 550 bytes as compact JSON and 750 pretty-printed, so 4 KiB leaves a 5x margin for any writer's
#: formatting.  Parsing is what a hostile payload costs below the limit: a 4 KiB array of numbers is
#: refused in ~0.1 ms, a 64 KiB one in ~13 ms and a 500 KB one in over 50 ms, so a stream (or a log) of
#: them would stall the chain.  The gateway's ``max_payload_bytes`` setting defaults to it.
MAX_PAYLOAD_BYTES = 4096

#: Machine-readable rejection codes.
REJECTION_CODES = (
    "too_large",  # longer than the byte limit: refused before parsing
    "malformed_json",  # not JSON, or not a JSON object
    "non_finite",  # NaN / Infinity anywhere
    "schema",  # missing / extra / wrongly typed field
    "out_of_range",  # physically impossible value
    "vehicle_mismatch",  # payload vehicle_id differs from the key's
    "stamp_backwards",  # stamp earlier than the previous accepted sample's
    "duplicate_seq",  # same seq as the previous accepted sample
    "old_seq",  # seq lower than the previous accepted sample's
)


class SampleRejected(ValueError):
    """A sample that must not be used, with a machine-readable ``code`` and a human reason."""

    def __init__(self, code: str, message: str, seq: Optional[int] = None):
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.seq = seq


class OversizedLine(str):
    """A line of a sensor log that :func:`capped_lines` did not read in full: its first bytes only
    (decoded), and its whole length in bytes as ``size``.  :func:`parse_sample` refuses it as
    ``too_large`` without looking at the text."""

    size: int

    def __new__(cls, head: str, size: int) -> "OversizedLine":
        obj = super().__new__(cls, head)
        obj.size = int(size)
        return obj


def payload_size(payload: bytes | str) -> int:
    """Bytes of ``payload`` as the limit counts them: a line's end (``\\n``, ``\\r\\n``) does not count,
    a str counts its UTF-8 bytes."""
    if isinstance(payload, OversizedLine):
        return payload.size
    n = len(payload)
    if isinstance(payload, str):
        end = 2 if payload.endswith("\r\n") else 1 if payload.endswith("\n") else 0
        n -= end
        if not payload.isascii():
            n = len(payload.encode("utf-8", "surrogatepass")) - end
        return n
    return n - (2 if payload.endswith(b"\r\n") else 1 if payload.endswith(b"\n") else 0)


def check_size(payload: bytes | str, max_bytes: int = MAX_PAYLOAD_BYTES) -> None:
    """Raise SampleRejected ``too_large`` if ``payload`` is longer than ``max_bytes``: the check that
    comes before any parsing, live and offline."""
    n = payload_size(payload)
    if n > max_bytes:
        raise SampleRejected("too_large", f"payload: {n} bytes exceeds the limit of {max_bytes} bytes")


def capped_lines(fobj: IO[bytes], max_bytes: int = MAX_PAYLOAD_BYTES) -> Iterator[str]:
    """The lines of a binary file as text (invalid UTF-8 replaced), never holding more than about
    ``max_bytes`` of one line in memory: a longer line is skipped to its end and given as an
    :class:`OversizedLine`, which :func:`parse_sample` refuses before parsing.

    Offline, this is what the gateway's size check is live: a sensor log with a line of megabytes
    costs neither the memory nor the parse."""
    want = max_bytes + 3  # the limit, a line end (\r\n) and one byte more
    while True:
        chunk = fobj.readline(want)
        if not chunk:
            return
        if len(chunk) < want or chunk.endswith(b"\n"):
            yield chunk.decode("utf-8", errors="replace")
            continue
        size, tail = len(chunk), chunk
        while not tail.endswith(b"\n"):
            tail = fobj.readline(1 << 16)
            if not tail:
                break
            size += len(tail)
        size -= 2 if tail.endswith(b"\r\n") else 1 if tail.endswith(b"\n") else 0
        yield OversizedLine(chunk[:256].decode("utf-8", errors="replace"), size)


def _find_non_finite(obj, path="") -> Optional[str]:
    if isinstance(obj, float) and not math.isfinite(obj):
        return path or "<sample>"
    if isinstance(obj, dict):
        for k, v in obj.items():
            r = _find_non_finite(v, f"{path}.{k}" if path else str(k))
            if r:
                return r
    if isinstance(obj, list):
        for i, v in enumerate(obj):
            r = _find_non_finite(v, f"{path}.{i}")
            if r:
                return r
    return None


_RANGE_TYPES = {"less_than_equal", "greater_than_equal", "less_than", "greater_than"}


def parse_sample(payload: bytes | str, expected_vehicle_id: Optional[str] = None, *,
                 max_bytes: int = MAX_PAYLOAD_BYTES) -> SensorSample:
    """Parse and schema-check one raw payload; SampleRejected says which field, which value, why.

    The one parser of the gateway and of ``soilocp estimate``: whatever the payload, it returns a
    sample or raises SampleRejected, never anything else (a deeply nested payload, an integer of
    thousands of digits included).  A payload longer than ``max_bytes`` is refused (``too_large``)
    before it is parsed."""
    check_size(payload, max_bytes)
    # a good payload costs one call into pydantic-core (JSON parsed and validated in Rust, 5x cheaper
    # than json.loads + a walk + model_validate); a payload it refuses takes the path below, which words
    # the rejection (malformed JSON, the non-finite value's path, the schema or range error)
    try:
        sample = SensorSample.model_validate_json(payload)
    except ValidationError:
        sample = None
    if sample is not None:
        _check_vehicle(sample, expected_vehicle_id)
        return sample
    try:
        return _parse_sample(payload, expected_vehicle_id)
    except RecursionError:
        raise SampleRejected("malformed_json", "payload: JSON nested too deeply") from None
    except SampleRejected:
        raise
    except (ValueError, TypeError, OverflowError) as exc:
        # what the parser itself refuses beyond JSON syntax, e.g. an integer of 5000 digits
        raise SampleRejected("malformed_json", f"payload: cannot be parsed: {exc}"[:300]) from None


def _check_vehicle(sample: SensorSample, expected_vehicle_id: Optional[str]) -> None:
    if expected_vehicle_id is not None and sample.vehicle_id != expected_vehicle_id:
        raise SampleRejected(
            "vehicle_mismatch",
            f"vehicle_id: payload says {sample.vehicle_id!r} but it arrived for {expected_vehicle_id!r}",
            sample.seq,
        )


def _parse_sample(payload: bytes | str, expected_vehicle_id: Optional[str]) -> SensorSample:
    try:
        obj = json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SampleRejected("malformed_json", f"not valid JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise SampleRejected("malformed_json", f"expected a JSON object, got {type(obj).__name__}")
    seq = obj.get("seq") if isinstance(obj.get("seq"), int) and not isinstance(obj.get("seq"), bool) else None
    bad = _find_non_finite(obj)
    if bad:
        raise SampleRejected("non_finite", f"{bad}: must be finite, got {obj_get(obj, bad)!r}", seq)
    try:
        sample = SensorSample.model_validate(obj)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        code = "out_of_range" if errors and all(e.get("type") in _RANGE_TYPES for e in errors) else "schema"
        raise SampleRejected(code, format_validation_error(exc), seq) from None
    _check_vehicle(sample, expected_vehicle_id)
    return sample


def obj_get(obj, path: str):
    cur = obj
    for part in path.split("."):
        cur = cur[int(part)] if isinstance(cur, list) else cur.get(part)
    return cur


class SampleValidator:
    """Per-vehicle ordering checks: stamps must not go backwards, seq must strictly increase.

    A sensor source that restarts begins again at a low seq and an earlier stamp.  Those samples
    are rejected (old_seq / stamp_backwards) — a replayed or reordered sample must never be
    accepted — but when ``restart_after`` consecutive rejected samples are themselves in order
    (seq and stamp increasing), they are a new session of the source, not stragglers: the
    validator adopts it, accepts the sample and counts a restart (``restarts``).  Downstream
    stages see the stamp go backwards and re-initialise.

    Live, the checks are given each sample's arrival time (``received_at``), and a restart is adopted
    only once no sample has been accepted for ``restart_quiet_s``: a source that restarted has left
    its old session, whereas a recorded stream replayed at a high rate beside the live one (50 old
    samples arrive between two live ones at 5 kHz) would otherwise be taken for a restart, and every
    replayed sample after it fed downstream.  Offline (no arrival time) the run alone decides.

    ``conflicts`` counts the samples refused for their order (old, duplicate, earlier stamp, or a
    jump far ahead) that arrived less than ``restart_quiet_s`` after an accepted one.  One source on
    an in-order link never sends such a sample while its own stream is live, and a restarted source
    comes back after its old session went quiet; so a conflict means a second publisher on the
    vehicle's key: a forger with a valid sample of this vehicle (whichever of the two streams is
    ahead, the other one's samples are refused) or a replay beside the live stream.  Live only.
    """

    #: A sample further ahead of the last accepted one than this (seq, stamp in s) is refused as out_of_range
    #: (unless a run of them adopts it, as a restart): no recorded drive jumps so far, and one forged sample
    #: with a seq of 10^300 would otherwise make every later sample of the vehicle an old one.
    MAX_SEQ_JUMP = 1_000_000
    MAX_STAMP_JUMP_S = 86_400.0

    def __init__(self, restart_after: int = 50, restart_quiet_s: float = 0.5) -> None:
        if restart_after < 2:
            raise ValueError(f"restart_after must be >= 2, got {restart_after!r}")
        self.restart_after = restart_after
        self.restart_quiet_s = float(restart_quiet_s)
        self.last_seq: Optional[int] = None
        self.last_stamp: Optional[float] = None
        self.restarts = 0
        self.conflicts = 0
        self._run: list[tuple[int, float]] = []  # consecutive ordered rejected samples (the latest restart_after)
        self._accepted_at: Optional[float] = None  # arrival time of the last accepted sample (live)

    def check(self, sample: SensorSample, received_at: Optional[float] = None) -> None:
        """Raise SampleRejected if ``sample`` cannot follow the last accepted one; else accept it.
        ``received_at``: its arrival time, s (live; class doc)."""
        try:
            self._check_order(sample)
        except SampleRejected as rej:
            candidate = rej.code in ("old_seq", "stamp_backwards") or getattr(rej, "jump", False)
            if (candidate or rej.code == "duplicate_seq") and self._live(received_at):
                self.conflicts += 1  # a second publisher on this vehicle's key (class doc)
            if candidate and self._extends_run(sample):
                self._run.append((sample.seq, sample.stamp))
                if len(self._run) >= self.restart_after and self._quiet(received_at):
                    self.restarts += 1
                    self._run.clear()
                    self.last_seq, self.last_stamp = sample.seq, sample.stamp
                    self._accepted_at = received_at
                    return  # a restarted source: accepted as the start of its new session
                del self._run[:-self.restart_after]
            elif candidate:
                self._run = [(sample.seq, sample.stamp)]
            raise
        self._run.clear()
        self.last_seq = sample.seq
        self.last_stamp = sample.stamp
        self._accepted_at = received_at

    def _live(self, received_at: Optional[float]) -> bool:
        """A sample accepted less than ``restart_quiet_s`` before ``received_at`` (live only)."""
        return received_at is not None and self._accepted_at is not None \
            and received_at - self._accepted_at < self.restart_quiet_s

    def _quiet(self, received_at: Optional[float]) -> bool:
        if received_at is None or self._accepted_at is None:
            return True
        return received_at - self._accepted_at >= self.restart_quiet_s

    def _extends_run(self, sample: SensorSample) -> bool:
        if not self._run:
            return True
        seq, stamp = self._run[-1]
        return sample.seq > seq and sample.stamp >= stamp

    def _check_order(self, sample: SensorSample) -> None:
        if self.last_seq is None:
            return
        if sample.seq == self.last_seq:
            raise SampleRejected("duplicate_seq", f"seq: {sample.seq} was already accepted", sample.seq)
        if sample.seq < self.last_seq:
            raise SampleRejected(
                "old_seq", f"seq: {sample.seq} is older than the last accepted {self.last_seq}", sample.seq
            )
        if sample.stamp < self.last_stamp:
            raise SampleRejected(
                "stamp_backwards",
                f"stamp: {sample.stamp!r} is before the last accepted {self.last_stamp!r}",
                sample.seq,
            )
        if sample.seq - self.last_seq > self.MAX_SEQ_JUMP or sample.stamp - self.last_stamp > self.MAX_STAMP_JUMP_S:
            field, value, last, most = (("seq", sample.seq, self.last_seq, self.MAX_SEQ_JUMP)
                                        if sample.seq - self.last_seq > self.MAX_SEQ_JUMP else
                                        ("stamp", sample.stamp, self.last_stamp, self.MAX_STAMP_JUMP_S))
            rej = SampleRejected("out_of_range", f"{field}: {value!r:.60} is more than {most:g} ahead of the last "
                                 f"accepted {last!r}", sample.seq if sample.seq < 2**63 else None)
            rej.jump = True
            raise rej
