"""A GNSS-grade ground speed (fixes at 10 Hz, 0.1 s late, 3 cm/s of noise, held between fixes) strays from the
accelerometer's course beyond the noise the observer assumes, and the slip made of it is that much less certain
(docs/method.md §20); a clean ground speed leaves the slip's uncertainty as it was."""

from __future__ import annotations

import numpy as np

from soilocp.estimation.pipeline import NormalForceStage, ObserverStage, PipelineConfig, SlipGate
from soilocp.estimation.slip_gate import pack_message
from soilocp.sim.variants import ROBUST_DRIVE, Variant, gnss


def _run(transforms, seconds=8.0):
    cfg = PipelineConfig()
    nf, ob, gate = NormalForceStage(cfg), ObserverStage(cfg), SlipGate(cfg, 1)
    excess, sigma = [], []
    variant = Variant("probe", "probe", scenario=ROBUST_DRIVE, transforms=transforms)
    for sample, truth in variant.simulate(3, duration=seconds):
        out = ob.step(sample, nf.step(sample))
        inp = gate.step(np.zeros(1, dtype=int), np.array([sample.stamp]), pack_message(out))
        if truth.stamp > 3.0:  # past the start's ramp
            excess.append(out.ground_speed_excess)
            sigma.append(float(np.median(inp.slip_sigma[0])))
    return np.array(excess), np.array(sigma)


def test_a_gnss_speed_widens_the_slip_band_and_a_clean_one_does_not():
    clean_excess, clean_sigma = _run(())
    gnss_excess, gnss_sigma = _run((gnss(),))
    # the simulator's own ground speed (1 cm/s white noise at 100 Hz) is within the assumed 2 cm/s
    assert np.mean(clean_excess == 0.0) > 0.9, np.quantile(clean_excess, [0.5, 0.9])
    # the GNSS-grade one strays by about its noise and its lag's share of the speed swings
    assert np.median(gnss_excess) > 0.015, np.quantile(gnss_excess, [0.1, 0.5, 0.9])
    assert np.median(gnss_sigma) > 1.5 * np.median(clean_sigma), (np.median(gnss_sigma), np.median(clean_sigma))
