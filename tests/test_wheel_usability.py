"""Reversing first-class and out-of-model wheels never `ok` (docs/method.md §17): eq. 1 in the direction of
travel, a mirrored (backwards) drive reads the forward drive's K, the unusable codes and their reasons,
the observer's re-anchoring at a stall, and the held value's age and band."""

from __future__ import annotations

import math

import numpy as np
import pytest

from soilocp.estimation.estimate import EstimateSummary, estimate_lines
from soilocp.estimation.observer import ObserverConfig
from soilocp.estimation.observer_bank import ObserverBank
from soilocp.estimation.pipeline import PipelineConfig, observer_inputs
from soilocp.estimation.soil_strength import BayesSoilEstimator
from soilocp.estimation.wheel_usability import (REASONS, SKID_TURN, SLIP_BEYOND_EQ1, STALL, STOPPED_UNPOWERED,
                                                USABLE, describe)
from soilocp.model.constants import DEFAULT_CONSTANTS
from soilocp.model.normal_force import normal_forces
from soilocp.model.traction import gross_traction
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.simulator import simulate


def test_reverse_gross_traction_is_the_mirror_image():
    # a wheel driving backwards at travel slip 0.2 pushes backwards with the gross traction of driving slip 0.2,
    # motion resistance included (§11): in its travel frame the observed coefficient is +g(0.2), and the
    # body-frame -g(0.2) read against the curve at the body-frame slip -0.2 (a braking wheel) is off by 2 mu_MR
    # (rim -0.1875 m/s over ground -0.15 m/s: travel slip 0.2, direction -1, soilocp/_core/src/slip.rs's vectors)
    g = float(gross_traction(0.2, 120.0))
    d = -1.0
    assert d * -g == pytest.approx(g)
    assert abs(float(gross_traction(-0.2, 120.0)) - (-g)) > 0.1


def _mirror(sample):
    """The same drive travelled backwards: x -> -x (front and rear wheels swap, every longitudinal quantity,
    the pitch and the yaw rate change sign)."""
    swap = (1, 0, 3, 2)
    f = sample.specific_force
    return sample.model_copy(update={
        "wheel_speed": tuple(-sample.wheel_speed[i] for i in swap),
        "wheel_torque": tuple(-sample.wheel_torque[i] for i in swap),
        "ground_speed": -sample.ground_speed, "specific_force": (-f[0], f[1], f[2]),
        "pitch": -sample.pitch, "yaw_rate": -sample.yaw_rate,
    })


@pytest.fixture(scope="module")
def grass_drive():
    return list(simulate("grass", duration=8.0, seed=3))


def test_a_drive_travelled_backwards_reads_the_forward_drives_K(grass_drive):
    pairs = grass_drive
    fwd_cfg = PipelineConfig()
    v = DEFAULT_VEHICLE
    back_cfg = PipelineConfig(vehicle=v.model_copy(update={"a": v.b, "b": v.a}))
    fwd = list(estimate_lines((s.model_dump_json() for s, _ in pairs), fwd_cfg))
    back = list(estimate_lines((_mirror(s).model_dump_json() for s, _ in pairs), back_cfg))
    assert len(fwd) == len(back) == len(pairs)
    with_k = [(a, b) for a, b in zip(fwd, back) if a["soil_strength"] is not None]
    assert len(with_k) > 0.5 * len(pairs)
    for a, b in zip(fwd, back):
        assert a["status"] == b["status"]
        if a["soil_strength"] is not None:
            assert b["soil_strength"] == pytest.approx(a["soil_strength"], rel=1e-6)
            assert [b["slip"][i] for i in (1, 0, 3, 2)] == pytest.approx(a["slip"], abs=1e-9)
    last = fwd[-1]["soil_strength"]
    assert abs(last / 200.0 - 1.0) < 0.1  # and it is grass


def test_usability_codes_are_named_and_worded():
    """The codes themselves are the core's (soil/usability.rs, whose tests hold docs/method.md's vectors and the
    skid turns); here their names and words."""
    assert describe([SKID_TURN] * 4).startswith("skid turn") and "wheels 1, 2, 3, 4" in describe([SKID_TURN] * 4)
    # the names are the record's vocabulary (SoilEstimate.unusable, the map, dashboards): the core's table
    assert REASONS == ("", "slip_beyond_eq1", "stopped_unpowered", "stall", "skid_turn")
    assert (USABLE, SLIP_BEYOND_EQ1, STOPPED_UNPOWERED, STALL, SKID_TURN) == (0, 1, 2, 3, 4)


def test_out_of_model_wheels_make_no_ok_record_and_are_counted(grass_drive):
    """A simulated traction test (ok records), then its wheel speeds read backwards under the moving body:
    the wheels are beyond eq. 1, no record is ok, each says why, and the summary counts them."""
    rng = np.random.default_rng(1)  # encoder noise: a constant reading would be a held one
    samples = [s if s.stamp < 6.0 else s.model_copy(update={"wheel_speed": tuple(-2.0 + 0.02 * rng.standard_normal(4))})
               for s, _ in grass_drive]
    summary = EstimateSummary()
    recs = list(estimate_lines((s.model_dump_json() for s in samples), PipelineConfig(), summary=summary))
    assert any(r["status"] == "ok" for r in recs if r["stamp"] < 6.0)
    tail = [r for r in recs if r["stamp"] >= 6.2]
    assert tail and not [r for r in tail if r["status"] == "ok"]
    flagged = [r for r in tail if "slip_beyond_eq1" in r["unusable"]]
    assert len(flagged) >= 0.9 * len(tail)
    held = [r for r in flagged if r["status"] == "holding"]
    assert held and all("beyond eq. 1" in r["reason"] and r["held_for_s"] >= 0.15 for r in held)
    assert summary.unusable.get("slip_beyond_eq1", 0) >= len(flagged)


def test_observer_speed_stays_on_its_encoder_at_a_stall():
    """A stall under torque: the encoder reads 0.48 rad/s while a large torque acts and the body creeps.
    The speed state must not leave the encoder (the closed-loop stall on firm soil ran to 7 rad/s)."""
    v = DEFAULT_VEHICLE
    fz = normal_forces(v, (0.0, 0.0, 9.81)).tolist()
    bank = ObserverBank(v, ObserverConfig(), 1)
    worst = 0.0
    rng = np.random.default_rng(0)
    from soilocp.schemas.sensor import SensorSample

    for i in range(300):
        # encoder noise (a constant reading would be a held one), and a few spikes, which the gate rejects
        w = 0.48 + 0.01 * rng.standard_normal() + (3.0 if i % 37 == 20 else 0.0)
        s = SensorSample(vehicle_id="r", seq=i, stamp=i * 0.01, specific_force=(0.0, 0.0, 9.81), roll=0.0, pitch=0.0,
                         yaw_rate=0.0, wheel_speed=(w, w, w, w), wheel_torque=(38.0,) * 4,
                         ground_speed=0.03 + 0.005 * rng.standard_normal())
        out = bank.step(None, observer_inputs([s], [fz]))
        if i % 37 != 20 and i > 5:
            worst = max(worst, float(np.max(np.abs(out.wheel_speed[0] - w))))
    assert worst < 0.5


def test_a_held_encoder_reading_the_prediction_left_makes_the_wheel_uninformative():
    """docs/method.md §18, "A repeated reading the prediction has left": stall-draft (seed 2) runs at a steady
    0.5 m/s with zero torque before its draft; two wheels' quantised encoders flicker between 3.298 and 3.336
    rad/s and the reading clock judges their repeats held, so the observer predicts them, and the prediction ran
    to 3.78 rad/s (slip 0.12 for a true 0) and took K to 14.5 +- 16.5 on K = 300 soil.  Every held wheel whose
    filtered speed is beyond gate_sigma of the encoder's noise from its reading says speed_rejected, and no held
    wheel within it does."""
    from soilocp.estimation.pipeline import VehiclePipeline
    from soilocp.sim.variants import get_variant

    cfg = PipelineConfig()
    pipeline = VehiclePipeline(cfg)
    limit = cfg.observer.gate_sigma * cfg.observer.r_wheel_speed  # a held reading carries no encoder lead
    left = 0
    for sample, truth in get_variant("stall-draft").simulate(2, duration=3.0, nominal=cfg.vehicle,
                                                             constants=cfg.constants):
        _, obs, _, _ = pipeline.process_all(sample)
        off = np.abs(np.subtract(obs.wheel_speed, sample.wheel_speed))
        for w in range(4):
            if obs.speed_age[w] > 0:  # a held reading: the rule's, not the innovation gate's
                left += off[w] > limit
                assert obs.speed_rejected[w] == (off[w] > limit), (truth.stamp, w, obs.wheel_speed, sample.wheel_speed)
    assert left >= 10  # the drive has such samples: without them the test would check nothing


def test_held_value_says_its_age_and_widens():
    est = BayesSoilEstimator(DEFAULT_CONSTANTS)
    g = gross_traction(np.full(4, 0.2), 80.0, DEFAULT_CONSTANTS)
    t = 0.0
    for _ in range(200):
        st = est.update(t, np.full(4, 0.2), g, np.full(4, 1e-4), [True] * 4)
        t += 0.01
    assert st.held_for_s == 0.0
    informed = st.log_k_std
    ages, stds = [], []
    for _ in range(600):
        st = est.update(t, np.full(4, 0.01), g, np.full(4, 1e-4), [True] * 4)
        t += 0.01
        ages.append(st.held_for_s)
        stds.append(st.log_k_std)
    assert ages[-1] == pytest.approx(6.0, abs=0.02) and st.status == "holding"
    assert all(b >= a - 1e-12 for a, b in zip(stds, stds[1:]))  # the band never narrows while held
    assert stds[-1] >= math.hypot(informed, 0.1 * math.sqrt(6.0)) - 1e-9
