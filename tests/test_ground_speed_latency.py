"""A late ground speed measured against the accelerometer (the core's observer/latency.rs, its numpy
reference in tests/reference_observer.py; docs/method.md §13): the latency is found when there is one, is 0 when there is none (also at
20 Hz and under an accelerometer bias), and the observer's speed no longer lags with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reference_observer import GroundSpeedLatency
from soilocp.estimation.estimate import EstimateSummary, estimate_lines
from soilocp.estimation.observer import ObserverConfig
from soilocp.estimation.observer_bank import ObserverBank, ObserverInputs
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.sim.variants import get_variant


def _latency(lag: float, rate: float = 100.0, refresh: float = 0.1, bias: float = 0.0, seconds: float = 40.0,
             seed: int = 0) -> np.ndarray:
    """Feed a sweep-like acceleration (0.3 Hz and 0.7 Hz sines, +-1.4 m/s^2) sampled at ``rate``
    with a ground speed ``lag`` s late, refreshed every ``refresh`` s (noise 0.01 m/s); the
    estimate after each sample."""
    rng = np.random.default_rng(seed)
    fine = 1000.0
    t_fine = np.arange(0.0, seconds, 1.0 / fine)
    a_fine = np.sin(2 * math.pi * 0.3 * t_fine) + 0.4 * np.sin(2 * math.pi * 0.7 * t_fine + 1.0)
    v_fine = 1.0 + np.cumsum(a_fine) / fine
    est = GroundSpeedLatency(1, window=30.0, max_latency=0.3)
    out, last_refresh, reading, prev_t = [], -1.0, math.nan, math.nan
    for t in np.arange(0.0, seconds, 1.0 / rate):
        i = int(round(t * fine))
        new = t - last_refresh >= refresh - 1e-9
        if new:
            reading = float(np.interp(t - lag, t_fine, v_fine)) + rng.normal(0.0, 0.01)
            last_refresh = t
        acc = a_fine[i] + bias + rng.normal(0.0, 0.03)
        est.step(slice(None), np.array([t - prev_t]), np.array([acc]), np.array([reading]), np.array([new]))
        out.append(float(est.latency[0]))
        prev_t = t
    return np.array(out)


def _latency_core(lag: float, rate: float = 100.0, refresh: float = 0.1, bias: float = 0.0, seconds: float = 40.0,
                  seed: int = 0) -> np.ndarray:
    """:func:`_latency`'s drive through a one-vehicle observer bank (the product's core: its readings clock
    decides which ground speeds are new, its latency fit runs inside the step); the fitted latency after each
    sample."""
    rng = np.random.default_rng(seed)
    fine = 1000.0
    t_fine = np.arange(0.0, seconds, 1.0 / fine)
    a_fine = np.sin(2 * math.pi * 0.3 * t_fine) + 0.4 * np.sin(2 * math.pi * 0.7 * t_fine + 1.0)
    v_fine = 1.0 + np.cumsum(a_fine) / fine
    cfg = PipelineConfig()
    bank = ObserverBank(cfg.vehicle, cfg.observer, 1)
    fz = np.full((1, 4), cfg.vehicle.mass * cfg.observer.gravity / 4)
    out, last_refresh, reading = [], -1.0, math.nan
    for t in np.arange(0.0, seconds, 1.0 / rate):
        i = int(round(t * fine))
        if t - last_refresh >= refresh - 1e-9:
            reading = float(np.interp(t - lag, t_fine, v_fine)) + rng.normal(0.0, 0.01)
            last_refresh = t
        acc = a_fine[i] + bias + rng.normal(0.0, 0.03)
        o = bank.step(None, ObserverInputs(
            stamp=np.array([t]), specific_force_x=np.array([acc]), yaw_rate=np.zeros(1), pitch=np.zeros(1),
            wheel_speed=np.full((1, 4), v_fine[i] / cfg.vehicle.wheel_radius), wheel_torque=np.zeros((1, 4)),
            ground_speed=np.array([reading]), normal_force=fz))
        out.append(float(o.ground_speed_latency[0]))
    return np.array(out)


@pytest.fixture(params=["reference", "core"])
def latency(request):
    """Each drive on the tests' numpy reference and on the product's core."""
    return _latency if request.param == "reference" else _latency_core


@pytest.mark.parametrize("lag, rate, refresh", [(0.05, 100.0, 0.1), (0.1, 50.0, 0.02), (0.05, 20.0, 0.05)])
def test_a_late_ground_speed_is_measured(lag, rate, refresh, latency):
    got = latency(lag, rate, refresh)
    assert got[-1] == pytest.approx(lag, abs=0.012)
    assert np.all(got <= 0.3)


@pytest.mark.parametrize("rate, bias", [(100.0, 0.0), (20.0, 0.0), (100.0, 0.1), (100.0, -0.1)])
def test_no_latency_reads_zero(rate, bias, latency):
    # at 20 Hz the rectangle rule would read dt / 2 = 25 ms; a bias adds b dt to y, uncorrelated with x
    got = latency(0.0, rate, refresh=1.0 / rate, bias=bias)
    assert np.max(got[len(got) // 4:]) < 0.01


def test_no_acceleration_no_latency():
    est = GroundSpeedLatency(1, window=30.0, max_latency=0.3)
    rng = np.random.default_rng(1)
    for i in range(3000):
        est.step(slice(None), np.array([0.01 if i else math.nan]), np.array([rng.normal(0, 0.03)]),
                 np.array([1.0 + rng.normal(0, 0.01)]), np.array([i % 10 == 0]))
    assert est.latency[0] == 0.0  # the fit has no lever: never determined


def _speed_errors(observer: ObserverConfig) -> np.ndarray:
    """|filtered ground speed - true speed| over a 20 s ground-speed-lag drive (50 ms, 10 Hz), after 10 s."""
    cfg = PipelineConfig(observer=observer)
    pairs = list(get_variant("ground-speed-lag").simulate(0, duration=20.0, nominal=cfg.vehicle, constants=cfg.constants))
    est = list(estimate_lines([s.model_dump_json() for s, _ in pairs], cfg, summary=EstimateSummary(), full=True))
    err = np.abs(np.array([e["filtered_ground_speed"] for e in est]) - np.array([t.ground_speed for _, t in pairs]))
    # the observer's output says by how much it led the reading (0 when switched off)
    assert est[-1]["ground_speed_latency"] == (pytest.approx(0.05, abs=0.012) if observer.ground_speed_latency_max else 0.0)
    return err[1000:]


def test_the_observer_speed_no_longer_lags_a_late_ground_speed():
    led, late = _speed_errors(ObserverConfig()), _speed_errors(ObserverConfig(ground_speed_latency_max=0.0))
    print(f"filtered speed error p99: led {np.quantile(led, 0.99):.4f} m/s, as read {np.quantile(late, 0.99):.4f} m/s")
    assert np.quantile(led, 0.99) < 0.7 * np.quantile(late, 0.99)


def test_a_dropout_neither_poisons_the_fit_nor_closes_it():
    # the reading goes missing (NaN) for 0.5 s in the middle: the fit keeps its sums finite and still
    # reads the latency afterwards; a restart (dt NaN) opens a new pair
    rng = np.random.default_rng(2)
    est = GroundSpeedLatency(1, window=30.0, max_latency=0.3)
    lag, prev_t = 0.05, math.nan
    for i in range(4000):
        t = i * 0.01
        a = math.sin(2 * math.pi * 0.3 * t) + 0.4 * math.sin(2 * math.pi * 0.7 * t + 1.0)
        v_then = 1.0 - (math.cos(2 * math.pi * 0.3 * (t - lag)) - 1) / (2 * math.pi * 0.3) \
            - 0.4 * (math.cos(2 * math.pi * 0.7 * (t - lag) + 1.0) - math.cos(1.0)) / (2 * math.pi * 0.7)
        reading = math.nan if 1500 <= i < 1550 else v_then + rng.normal(0, 0.01)
        dt = math.nan if i == 2500 else t - prev_t  # one restart
        est.step(slice(None), np.array([dt]), np.array([a + rng.normal(0, 0.03)]), np.array([reading]),
                 np.array([i % 10 == 0]))
        prev_t = t
        assert np.isfinite(est.sums).all()
    assert est.latency[0] == pytest.approx(lag, abs=0.012)
