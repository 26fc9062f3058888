"""Ordering checks of raw samples, shared by the gateway and `soilocp estimate`."""

import pytest

from schemas.sensor import SensorSample
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


def test_scattered_stragglers_never_open_a_new_session():
    v = SampleValidator(restart_after=5)
    for i in range(100):
        v.check(sample(i, i * 0.01))
    for k in range(20):  # old samples, out of order among themselves
        with pytest.raises(SampleRejected):
            v.check(sample(50 - (k % 3) * 7, 0.5))
    assert v.restarts == 0 and v.last_seq == 99


def test_parse_sample_names_field_and_value():
    with pytest.raises(SampleRejected) as exc:
        parse_sample('{"vehicle_id": "r1", "seq": -1}')
    assert exc.value.code == "schema" and "seq" in exc.value.message
