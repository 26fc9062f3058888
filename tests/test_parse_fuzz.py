"""The one sample parser under 10^5 mutated payloads, and the byte limit it shares with the offline reader.

Whatever a sender puts on the raw key or in a sensor log, :func:`soilocp.validation.parse_sample`
returns a sample or raises ``SampleRejected``, and the gateway's checker returns a sample or a
``Rejection``; nothing else escapes.  The payloads are a seeded generator's
(:func:`soilocp.services.bench.hostile.mutate`, which the live flood of tests/test_live_stress.py uses too;
reproducible, the failing payload is in the message): oversized,
truncated, byte-flipped, invalid UTF-8, non-finite, wrongly typed, deeply nested, huge numbers,
another vehicle's id.  The slowest parse is measured and printed; the bound asserted is generous
(a shared machine's scheduling is not the parser's cost), the figure is what the report quotes.
"""

from __future__ import annotations

import gc
import io
import json
import random
import time

import pytest

from soilocp.schemas.messages import Rejection
from soilocp.schemas.sensor import SensorSample
from soilocp.services.bench.hostile import good_sample, mutate as _mutate
from soilocp.services.stages.gateway import RawSampleChecker
from soilocp.validation import (MAX_PAYLOAD_BYTES, REJECTION_CODES, OversizedLine, SampleRejected, capped_lines,
                                check_size, parse_sample, payload_size)

N_PAYLOADS = 100_000


def _good(seq: int, vehicle_id: str = "rover1") -> dict:
    return SensorSample.model_validate(good_sample(seq, vehicle_id)).model_dump(mode="json")


def test_capped_lines_gives_oversized_lines_unread_and_the_rest_as_text():
    """Lines at the limit, one byte over, far over, with \\r\\n, and a last line without newline."""
    at = b"a" * MAX_PAYLOAD_BYTES
    data = (at + b"\n" + b"b" * (MAX_PAYLOAD_BYTES + 1) + b"\r\n" + at + b"\r\n" + b"c" * 300_000 + b"\n"
            + "é".encode() * 3 + b"\xff\n" + b"tail")
    lines = list(capped_lines(io.BytesIO(data)))
    assert len(lines) == 6
    assert lines[0] == at.decode() + "\n" and not isinstance(lines[0], OversizedLine)
    assert payload_size(lines[1]) == MAX_PAYLOAD_BYTES + 1  # short enough to read whole; refused all the same
    assert not isinstance(lines[2], OversizedLine) and payload_size(lines[2]) == MAX_PAYLOAD_BYTES
    assert isinstance(lines[3], OversizedLine) and lines[3].size == 300_000 and len(lines[3]) <= 256
    assert lines[4] == "ééé\ufffd\n" and payload_size(lines[4]) == 9  # UTF-8 bytes, the replacement char's 3
    assert lines[5] == "tail"
    for line in lines:
        big = payload_size(line) > MAX_PAYLOAD_BYTES
        with pytest.raises(SampleRejected) if big else _no_raise():
            check_size(line)


class _no_raise:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_estimate_refuses_an_oversized_line_before_parsing_and_counts_it(tmp_path):
    """``soilocp estimate``'s reader: a line of a megabyte (a valid sample padded with spaces, which
    would parse) is rejected as too_large with its size, the lines around it are estimated."""
    from soilocp.estimation.pipeline import PipelineConfig
    from soilocp.export.estimate_out import estimate_to

    good = [json.dumps(_good(i)) for i in range(6)]
    padded = good[3][:-1] + " " * 1_000_000 + "}"
    log = tmp_path / "sensors.jsonl"
    log.write_text("\n".join(good[:3] + [padded] + good[4:]) + "\n")
    err = io.StringIO()
    summary = estimate_to(log, tmp_path / "est.jsonl", PipelineConfig(), err=err)
    assert summary.rejected_by_code() == {"too_large": 1}
    assert summary.rejected[0][0] == 4 and f"{len(padded)} bytes" in summary.rejected[0][2]
    assert summary.estimates == 5
    assert "sensors.jsonl:4: rejected (too_large)" in err.getvalue()
    # the same line at the limit's side of the gateway: the same code, the same size
    rej = RawSampleChecker("rover1").check(padded.encode(), received_at=1.0)
    assert isinstance(rej, Rejection) and rej.code == "too_large" and f"{len(padded)} bytes" in rej.message


def test_gateway_and_offline_share_the_limit():
    from soilocp.services.runtime.config import ServiceConfig

    assert "too_large" in REJECTION_CODES
    assert ServiceConfig().max_payload_bytes == MAX_PAYLOAD_BYTES
    assert RawSampleChecker("rover1").max_payload_bytes == MAX_PAYLOAD_BYTES


def test_fuzzed_payloads_raise_nothing_unexpected_and_parse_fast():
    """10^5 mutated payloads through the offline parser (the line as ``capped_lines`` gives it) and
    the gateway's checker: only SampleRejected / Rejection, every code a known one; the slowest
    call's thread CPU time is printed and held under a generous bound."""
    rng = random.Random(20240541)
    validator_codes: dict[str, int] = {}
    live_codes: dict[str, int] = {}
    slowest: list[tuple[float, float, str, int, bytes]] = []  # (cpu s, wall s, path, size, head)
    checker = RawSampleChecker("rover1")
    accepted = 0
    unexpected: list[str] = []

    def timed(path: str, fn, payload: bytes):
        w0, c0 = time.perf_counter(), time.thread_time()
        try:
            return fn()
        finally:
            c, w = time.thread_time() - c0, time.perf_counter() - w0
            if len(slowest) < 5 or c > slowest[-1][0]:
                slowest.append((c, w, path, len(payload), payload[:60]))
                slowest.sort(key=lambda r: -r[0])
                del slowest[5:]

    # as a service does once started (soilocp.services.runtime.service.run_service): the long-lived objects out of
    # the collector's sight, so that a full collection pass is not billed to whichever parse it falls on
    gc.collect()
    gc.freeze()
    try:
        for i in range(N_PAYLOADS):
            payload = _mutate(rng, seq=i + 1)
            line = next(capped_lines(io.BytesIO(payload + b"\n")), "")
            try:
                timed("offline", lambda: parse_sample(line), payload)
                accepted += 1
            except SampleRejected as rej:
                validator_codes[rej.code] = validator_codes.get(rej.code, 0) + 1
                if rej.code not in REJECTION_CODES:
                    unexpected.append(f"offline code {rej.code!r} for {payload[:200]!r}")
            except Exception as exc:  # noqa: BLE001 - what the test is looking for
                unexpected.append(f"offline {type(exc).__name__}: {exc!s:.200} for {payload[:200]!r}")
            try:
                res = timed("live", lambda: checker.check(payload, received_at=1.0), payload)
                if isinstance(res, Rejection):
                    live_codes[res.code] = live_codes.get(res.code, 0) + 1
                elif not isinstance(res, SensorSample):
                    unexpected.append(f"live returned {type(res).__name__}")
            except Exception as exc:  # noqa: BLE001
                unexpected.append(f"live {type(exc).__name__}: {exc!s:.200} for {payload[:200]!r}")
    finally:
        gc.unfreeze()
    print(f"\nfuzz: {N_PAYLOADS} payloads, {accepted} accepted offline, rejected by code {dict(sorted(validator_codes.items()))}; "
          f"live (gateway) rejections by code {dict(sorted(live_codes.items()))}")
    for c, w, path, size, head in slowest:
        print(f"fuzz: slowest {path}: {c * 1e3:.2f} ms CPU ({w * 1e3:.2f} ms wall), {size} bytes, {head!r}")
    assert not unexpected, unexpected[:5]
    assert {"too_large", "malformed_json", "non_finite", "schema", "out_of_range"} <= set(validator_codes)
    assert set(validator_codes) | {"vehicle_mismatch"} <= set(live_codes)
    assert accepted > 0
    assert slowest[0][0] < 0.025, slowest[0]  # generous: the figure goes in the report, the target is 10 ms
