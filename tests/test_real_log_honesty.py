"""scripts/real_log_honesty.py on a slice of a real Warthog log: its condition detectors (raw sensor fields,
not the estimator's flags) find the conditions eq. 1 does not describe, the estimator says `ok` in none of
them, and the check fails when a record there does say `ok`."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("real_log_honesty", ROOT / "scripts" / "real_log_honesty.py")
rl = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rl)

DATA = rl.default_data()
needs_data = pytest.mark.skipif(not (DATA / "warthog").is_dir(), reason="real logs not present (shared/data/real)")


@pytest.fixture(scope="module")
def asphalt_slice():
    """100-125 s of the asphalt log: a skid turn in place, stalls, reversing with spin, |slip| > 1."""
    logs = {name: (samples, cfg) for name, samples, cfg in rl.warthog(DATA, (100.0, 125.0))}
    return logs["warthog_asphalt_20240925"]


@needs_data
def test_no_ok_record_in_any_condition_on_a_real_slice(asphalt_slice):
    samples, cfg = asphalt_slice
    counts = rl.count(samples, cfg)
    print(rl.table(counts))
    assert sum(counts["all"].values()) == len(samples)
    for cond in ("skid_turn", "stall", "reversing_with_spin", "slip_beyond_1"):
        assert sum(counts.get(cond, {}).values()) >= 5, cond  # the raw detectors find them here
    assert rl.failures(counts) == {}


@needs_data
def test_the_check_fails_when_a_record_in_a_condition_says_ok(asphalt_slice, monkeypatch):
    samples, cfg = asphalt_slice
    real = rl.estimate_lines

    def all_ok(lines, config):
        for rec in real(lines, config):
            yield {**rec, "status": "ok"}

    monkeypatch.setattr(rl, "estimate_lines", all_ok)
    bad = rl.failures(rl.count(samples[:200], cfg))
    assert bad and all(n > 0 for n in bad.values())


def test_detectors_read_the_raw_fields():
    from soilocp.model.vehicle import VehicleParams

    v = VehicleParams(wheel_radius=0.165, c=0.2775, d=0.2775)
    base = {"yaw_rate": 0.0, "wheel_torque": [0.0] * 4, "ground_speed": 0.5}
    w = lambda rim: [r / 0.165 for r in rim]  # noqa: E731
    # the Husky records: reversing with spin; a skid turn; a wheel stopped under no torque
    assert "reversing_with_spin" in rl.conditions({**base, "ground_speed": -0.04, "wheel_speed": w([-0.45, -0.45, -0.26, -0.26])}, v, 1.0)
    assert "skid_turn" in rl.conditions({**base, "ground_speed": 0.0, "yaw_rate": -0.21,
                                         "wheel_speed": [1.15, 1.15, -1.15, -1.15]}, v, 1.0)
    assert "stopped_unpowered" in rl.conditions({**base, "ground_speed": 0.33, "wheel_speed": [0.0, 0.0, 2.0, 2.0],
                                                 "wheel_torque": [0.0, 0.0, 5.0, 5.0]}, v, 1.0)
    assert "stall" in rl.conditions({**base, "ground_speed": 0.05, "wheel_speed": w([0.3] * 4),
                                     "wheel_torque": [5.0] * 4}, v, 1.0)
    assert "slip_beyond_1" in rl.conditions({**base, "ground_speed": 0.3, "wheel_speed": w([-0.2] * 4)}, v, 1.0)
    assert rl.conditions({**base, "ground_speed": 1.0, "wheel_speed": w([1.1] * 4), "wheel_torque": [5.0] * 4}, v, 1.0) == set()
    assert rl.conditions({**base, "ground_speed": None, "yaw_rate": 0.5, "wheel_speed": w([0.3, 0.3, -0.3, -0.3])}, v, 1.0) \
        == {"skid_turn"}
