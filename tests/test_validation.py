"""Ordering checks of raw samples, shared by the gateway and `soilocp estimate`."""

import pytest

from soilocp.schemas.sensor import SensorSample
from soilocp.validation import SampleRejected, SampleValidator, parse_sample


def sample(seq, stamp):
    return SensorSample(vehicle_id="r1", seq=seq, stamp=stamp, specific_force=(0, 0, 9.81), roll=0, pitch=0,
                        yaw_rate=0, wheel_speed=(0, 0, 0, 0), wheel_torque=(0, 0, 0, 0), ground_speed=0)


def test_duplicates_old_and_backwards_samples_are_rejected_with_codes():
    v = SampleValidator()
    v.check(sample(10, 1.0))
    for s, code in ((sample(10, 1.1), "duplicate_seq"), (sample(9, 1.1), "old_seq"), (sample(11, 0.5), "stamp_backwards")):
        with pytest.raises(SampleRejected) as exc:
            v.check(s)
        assert exc.value.code == code
    v.check(sample(11, 1.1))


def test_a_restarted_source_is_adopted_after_a_run_of_ordered_samples_only():
    v = SampleValidator(restart_after=5)
    for i in range(100):
        v.check(sample(i, i * 0.01))
    rejected = 0
    for i in range(10):  # the source restarts: seq and stamp from 0 again
        try:
            v.check(sample(i, i * 0.01))
        except SampleRejected as exc:
            assert exc.code == "old_seq"
            rejected += 1
    assert rejected == 4 and v.restarts == 1 and v.last_seq == 9


def test_a_replay_beside_the_live_stream_is_never_adopted_but_a_real_restart_is():
    """Live (arrival times given): 80 old samples in order between two live ones, as a replay at a high
    rate brings them, are all refused; the live stream goes on.  When the live source falls silent for
    the quiet time, its new session (seq from 0) is adopted as before."""
    v = SampleValidator(restart_after=5, restart_quiet_s=0.5)
    t, live_seq = 100.0, 1000
    v.check(sample(live_seq - 1, (live_seq - 1) * 0.01), received_at=t)
    old = 0
    for _ in range(20):
        for _ in range(80):  # the replay: in order among themselves, 0.1 ms apart
            t += 1e-4
            with pytest.raises(SampleRejected):
                v.check(sample(old, old * 0.01), received_at=t)
            old = (old + 1) % 900  # a recorded stream, older than the live one
        t += 0.01
        v.check(sample(live_seq, live_seq * 0.01), received_at=t)  # the live stream: never refused
        live_seq += 1
    assert v.restarts == 0 and v.last_seq == live_seq - 1
    t += 0.6  # the live source stops; it comes back from seq 0 (a restart)
    adopted = None
    for i in range(10):
        t += 0.01
        try:
            v.check(sample(i, i * 0.01), received_at=t)
            adopted = i if adopted is None else adopted
        except SampleRejected:
            assert adopted is None
    assert adopted == 4 and v.restarts == 1 and v.last_seq == 9


def test_a_forged_jump_ahead_is_refused_and_a_run_of_them_is_a_restart():
    """One sample with a seq of 10^300 (or a stamp a year ahead) does not become the vehicle's last:
    it is out_of_range and the stream goes on; a source that really jumps (its new session's seqs)
    is adopted after a run, as any restart."""
    v = SampleValidator(restart_after=5)
    for i in range(10):
        v.check(sample(i, i * 0.01))
    for bad in (sample(10**300, 0.1), sample(10, 3.2e7)):
        with pytest.raises(SampleRejected) as exc:
            v.check(bad)
        assert exc.value.code == "out_of_range"
    v.check(sample(10, 0.1))
    adopted = []
    for i in range(8):
        try:
            v.check(sample(5_000_000 + i, 0.11 + i * 0.01))
            adopted.append(i)
        except SampleRejected as exc:
            assert exc.code == "out_of_range"
    assert adopted == [4, 5, 6, 7] and v.restarts == 1


def test_scattered_stragglers_never_open_a_new_session():
    v = SampleValidator(restart_after=5)
    for i in range(100):
        v.check(sample(i, i * 0.01))
    for k in range(20):  # old samples, out of order among themselves
        with pytest.raises(SampleRejected):
            v.check(sample(50 - (k % 3) * 7, 0.5))
    assert v.restarts == 0 and v.last_seq == 99


def test_a_second_publisher_is_counted_as_a_conflict_and_a_restart_is_not():
    """Live (arrival times given): a forger interleaved with the vehicle's stream, behind it or ahead
    of it, makes ordering refusals while the accepted stream is live: counted in ``conflicts``.  The
    vehicle alone, and the vehicle restarting (its new session begins after the old one went quiet),
    make none."""
    def drive(v, seqs, t0):  # at 100 Hz from arrival time t0
        for k, q in enumerate(seqs):
            try:
                v.check(sample(q, q * 0.01), received_at=t0 + k * 0.01)
            except SampleRejected:
                pass

    v = SampleValidator(restart_after=5, restart_quiet_s=0.5)
    drive(v, range(1, 201), 100.0)  # the vehicle alone, 100 Hz
    drive(v, range(1, 101), 103.0)  # it restarts 1 s after its last sample: seq from 1 again
    assert v.conflicts == 0 and v.restarts == 1

    behind = SampleValidator(restart_after=5, restart_quiet_s=0.5)
    ahead = SampleValidator(restart_after=5, restart_quiet_s=0.5)
    for k in range(1, 101):
        t = 200.0 + k * 0.01
        behind.check(sample(1000 + k, 10 + k * 0.01), received_at=t)
        with pytest.raises(SampleRejected):  # a forger replaying the vehicle's samples 0.5 s late
            behind.check(sample(1000 + k - 50, 10 + (k - 50) * 0.01), received_at=t + 0.002)
        ahead.check(sample(5000 + k, 50 + k * 0.01), received_at=t)  # a forger ahead of the vehicle
        with pytest.raises(SampleRejected):
            ahead.check(sample(1000 + k, 10 + k * 0.01), received_at=t + 0.002)  # the vehicle's own
    assert behind.conflicts == 100 and ahead.conflicts == 100
    assert behind.restarts == 0 and ahead.restarts == 0


def test_parse_sample_names_field_and_value():
    with pytest.raises(SampleRejected) as exc:
        parse_sample('{"vehicle_id": "r1", "seq": -1}')
    assert exc.value.code == "schema" and "seq" in exc.value.message


@pytest.mark.parametrize("payload", [
    "[" * 5000 + "]" * 5000,
    '{"seq": ' + "[" * 5000 + "]" * 5000 + "}",
    '{"a":' * 5000 + "1" + "}" * 5000,
])
def test_deeply_nested_payload_is_a_rejection_not_a_recursion_error(payload):
    with pytest.raises(SampleRejected) as exc:  # the limit raised: what the parser does past the size check
        parse_sample(payload, max_bytes=len(payload))
    assert exc.value.code == "malformed_json" and "nested too deeply" in exc.value.message


def test_deep_line_in_a_log_loses_no_good_line_around_it():
    from soilocp.estimation.estimate import EstimateSummary, estimate_lines
    from soilocp.estimation.pipeline import PipelineConfig

    good = [sample(i, i * 0.01).model_dump_json() for i in range(6)]
    lines = good[:3] + ["[" * 2000 + "]" * 2000] + good[3:]  # under the byte limit, past the recursion limit
    summary = EstimateSummary()
    recs = list(estimate_lines(lines, PipelineConfig(), summary=summary))
    assert [r["seq"] for r in recs] == list(range(6))
    assert [(n, code) for n, code, _ in summary.rejected] == [(4, "malformed_json")]


def test_mutated_payloads_only_ever_raise_sample_rejected():
    from hypothesis import given, settings, strategies as st

    base = sample(3, 0.03).model_dump_json()

    @settings(max_examples=2000, deadline=None)
    @given(st.integers(0, len(base)), st.integers(0, 40), st.text(alphabet='[]{}":,0123456789.eE-+ntrufalse\\', max_size=60),
           st.integers(0, 3000))
    def run(pos, cut, insert, depth):
        payload = base[:pos] + insert + "[" * depth + base[pos + cut:]
        try:
            parse_sample(payload)
        except SampleRejected:
            pass

    run()


def test_the_fast_parser_accepts_and_refuses_exactly_what_the_wording_parser_does():
    """parse_sample tries pydantic-core's JSON validation first and words a refusal with the slow path
    (json.loads, the non-finite walk, model_validate): on mutated payloads both must give the same
    sample or the same rejection."""
    from hypothesis import given, settings, strategies as st

    from soilocp.validation import _parse_sample

    base = sample(3, 0.03).model_copy(update={"ground_speed": 0.5, "wheel_speed": (1.5, -2.0, 3e-7, 4.0)})
    base = base.model_dump_json()

    def outcome(fn, payload):
        try:
            return ("ok", fn(payload).model_dump())
        except SampleRejected as rej:
            return (rej.code, rej.message, rej.seq)
        except RecursionError:
            return ("malformed_json", "payload: JSON nested too deeply", None)

    def same(payload):
        assert outcome(parse_sample, payload) == outcome(lambda p: _parse_sample(p, None), payload), payload

    @settings(max_examples=3000, deadline=None)
    @given(st.integers(0, len(base)), st.integers(0, 12),
           st.text(alphabet='[]{}":,0123456789.eE-+ntrufalseNaIiy\\ ', max_size=20))
    def run(pos, cut, insert):
        same(base[:pos] + insert + base[pos + cut:])

    run()
    for payload in (base, base.replace("0.5", "NaN"), base.replace("0.5", "1e999"), base.replace("0.5", "Infinity"),
                    base.replace('"seq":3', '"seq":3.0'), base.replace('"seq":3', '"seq":true'),
                    base.replace('"r1"', '"r2"'), base.encode(), base[:-1] + ',"extra":1}', base + " ",
                    base + "x", "\ufeff" + base, base.replace('"r1"', '"r\\ud800"')):
        same(payload)
    with pytest.raises(SampleRejected) as exc:
        parse_sample(base, expected_vehicle_id="r2")
    assert exc.value.code == "vehicle_mismatch" and exc.value.seq == 3
