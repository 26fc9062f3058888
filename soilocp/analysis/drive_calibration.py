"""The wheel's traction constants fitted from drives (``soilocp calibrate --from-drive``).

The paper fitted C1..C6 to a testbed's drawbar-pull tables (:mod:`soilocp.analysis.calibration`); a robot
has no testbed, but its drives show its curve wherever their slips spread over the bend (a traction sweep,
hard accelerations and brakes).  The estimator's own chain gives each wheel-sample's slip and net traction
(the observer's, docs/method.md §7, §11); the core's curve learner (``soilocp._core.CurveBank``, the one
that serves learnt OCPs live) tells the soils apart by where their pairs leave the learnt curve.  Then one
nonlinear least-squares fit, robust to stray pairs (soft-L1 loss), finds the constants shared by every
soil and each soil's K:

    mu_ij = eq. 6 (S_ij, K_j; C1, C2, C3, C4, C5, C6)       (wheel-sample i on soil j)

What the data cannot fix is said, not guessed:

* K's scale: K -> lambda K with C2 / lambda, lambda C5 and sqrt(lambda) C6 leaves every curve as it is, so C2
  keeps its prior value (the paper's) and the K are on that scale;
* C4 cancels from net traction (eq. 6) and keeps its prior;
* with one soil, K and the amplitude, offset and slope (C1, C5, C6) are not separable (docs/method.md §14):
  weak priors around the paper's constants keep the fit determined, and a constant whose posterior spread is
  more than half its prior's is reported as not fitted, with the reason;
* the S_E line (eq. 10's alpha, beta) is not seen by traction and keeps its prior.

A held-out check: every fourth half-second block of each soil is left out of the fit, and the fitted curve's
residuals on it are set against the fit's own and against the paper's curve at its best K for each soil.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from soilocp.estimation.settings_model import core_values
from soilocp import _core
from soilocp.estimation.curve_config import CurveConfig
from soilocp.estimation.estimate import EstimateSummary, estimate_lines
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.model.constants import ModelConstants
from soilocp.model.ocp import ocp_from_soil_strength
from soilocp.model.wheel_curve import WheelCalibration

#: the constants the drives can fit (C2, C4, alpha and beta keep their prior: module doc)
FITTED = ("C1", "C3", "C5", "C6")
#: prior 1-sigma of each fitted constant, in the fit's coordinates (ln C1, ln C3, C5, ln C6) and of ln K:
#: a tyre within a factor ~2 of the paper's testbed wheel, a soil anywhere in 10..2000
PRIOR_SIGMA = {"C1": 0.5, "C3": 0.7, "C5": 5.0, "C6": 0.7, "K": 1.5}
#: ln K's prior mean (K = 100, between the reference soils)
PRIOR_LN_K = math.log(100.0)
#: a constant whose posterior 1-sigma exceeds this share of its prior's is not fitted by the data
UNFITTED_SHARE = 0.5
#: held-out blocks: every HOLD_EVERY-th block of BLOCK_S seconds
BLOCK_S = 0.5
HOLD_EVERY = 4


@dataclass
class SoilPairs:
    """The (slip, net traction) pairs of one soil of one drive, folded onto the driving branch."""

    source: str
    index: int
    t: np.ndarray
    slip: np.ndarray
    mu: np.ndarray
    wheel: np.ndarray

    def __len__(self) -> int:
        return len(self.slip)


@dataclass
class DriveFit:
    """The calibration and the numbers behind it."""

    calibration: WheelCalibration
    soils: list[SoilPairs]
    rms_fit: float
    rms_held_out: float
    rms_held_out_paper: float
    messages: list[str] = field(default_factory=list)


def soil_pairs(records: Iterable[dict], source: str, curve: CurveConfig, min_pairs: int) -> list[SoilPairs]:
    """The informative (slip, net traction) pairs of a drive's estimate records, split into soils where the
    core's curve learner sees a change, each soil with at least ``min_pairs`` pairs.  As in the learner, pairs
    formed under a ground-speed latency estimate more than ``curve.latency_change`` from the soil's last are
    left out: their slips carry the old lag's error."""
    bank = _core.CurveBank(1, core_values(curve, "curve"), 0.0)  # its changes of soil only: no band is read
    rows: list[tuple[int, float, float, float, int, float]] = []
    for r in records:
        used = tuple(bool(i and d) for i, d in zip(r["informative"], r["mu_determined"]))
        latency = float(r["ground_speed_latency"])
        bank.step(0, r["stamp"], tuple(r["slip"]), tuple(r["mu"]), used, latency)
        soil = bank.changes(0)
        for w, (s, m, u) in enumerate(zip(r["slip"], r["mu"], used)):
            if u and curve.slip_min <= abs(s) <= curve.slip_max:
                sign = 1.0 if s > 0 else -1.0
                rows.append((soil, r["stamp"], s * sign, m * sign, w, latency))
    out = []
    for j in sorted({q[0] for q in rows}):
        sel = np.array([q[1:] for q in rows if q[0] == j])
        sel = sel[np.abs(sel[:, 4] - sel[-1, 4]) <= curve.latency_change]
        if len(sel) >= min_pairs:
            out.append(SoilPairs(source, j, sel[:, 0], sel[:, 1], sel[:, 2], sel[:, 3].astype(int)))
    return out


def _constants(theta: np.ndarray, prior: ModelConstants) -> ModelConstants:
    c1, c3, c5, c6 = math.exp(theta[0]), math.exp(theta[1]), float(theta[2]), math.exp(theta[3])
    return prior.model_copy(update={"C1": c1, "C3": c3, "C5": c5, "C6": c6})


def _theta0(prior: ModelConstants) -> np.ndarray:
    return np.array([math.log(prior.C1), math.log(prior.C3), prior.C5, math.log(prior.C6)])


def _net(slip: np.ndarray, k: np.ndarray, constants: ModelConstants) -> np.ndarray:
    """eq. 6 from the core (one definition), at each (slip, K)."""
    return _core.traction_value("net", slip, k, constants.kernel)


def _correlation_inflation(res: np.ndarray, wheel: np.ndarray) -> float:
    """(1 + rho) / (1 - rho) of the residuals' lag-1 correlation along each wheel's samples."""
    num = den = 0.0
    for w in np.unique(wheel):
        r = res[wheel == w]
        num += float(np.dot(r[:-1], r[1:]))
        den += float(np.dot(r, r))
    rho = min(max(num / den, 0.0), 0.99) if den > 0 else 0.0
    return (1 + rho) / (1 - rho)


def fit_soils(soils: Sequence[SoilPairs], prior: ModelConstants, masks: Sequence[np.ndarray] | None = None):
    """The robust least-squares fit of (ln C1, ln C3, C5, ln C6) and each soil's ln K, with weak priors.

    Returns (theta, ln K per soil, covariance of all parameters, residual 1-sigma, the scipy result)."""
    from scipy.optimize import least_squares

    masks = masks or [np.ones(len(s), dtype=bool) for s in soils]
    slips = [s.slip[m] for s, m in zip(soils, masks)]
    mus = [s.mu[m] for s, m in zip(soils, masks)]
    theta0 = _theta0(prior)
    n_soil = len(soils)
    # start each soil at the K the prior's curve reads best (a 1-D grid), so the fit starts near a solution
    ln_k0 = []
    for s, m in zip(slips, mus):
        grid = np.log(np.geomspace(10, 2000, 60))
        err = [np.mean((m - _net(s, np.full_like(s, math.exp(g)), prior)) ** 2) for g in grid]
        ln_k0.append(grid[int(np.argmin(err))])
    x0 = np.concatenate([theta0, ln_k0])
    sig_theta = np.array([PRIOR_SIGMA[n] for n in FITTED])
    noise = [0.02]  # residual 1-sigma, refined once

    def residuals(x):
        c = _constants(x[:4], prior)
        parts = [(m - _net(s, np.full_like(s, math.exp(lk)), c)) / noise[0] for s, m, lk in zip(slips, mus, x[4:])]
        # the priors, each worth one sample at its own sigma (weak against thousands of pairs)
        parts.append((x[:4] - theta0) / sig_theta)
        parts.append((x[4:] - PRIOR_LN_K) / PRIOR_SIGMA["K"])
        return np.concatenate(parts)

    res = least_squares(residuals, x0, loss="soft_l1", f_scale=2.0, method="trf")
    n_data = sum(len(s) for s in slips)
    raw = res.fun[:n_data] * noise[0]
    noise[0] = float(1.4826 * np.median(np.abs(raw))) or 0.02
    res = least_squares(residuals, res.x, loss="soft_l1", f_scale=2.0, method="trf")
    raw = res.fun[:n_data] * noise[0]
    wheels = np.concatenate([s.wheel[m] for s, m in zip(soils, masks)])
    inflation = _correlation_inflation(raw, wheels)
    jac = res.jac
    # data rows inflated for their correlation in time; the prior rows as they are
    jd, jp = jac[:n_data] / math.sqrt(inflation), jac[n_data:]
    info = jd.T @ jd + jp.T @ jp
    cov = np.linalg.pinv(info)
    return res.x[:4], res.x[4:], cov, noise[0], res, n_soil


def _held_out_masks(soils: Sequence[SoilPairs]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    train, held = [], []
    for s in soils:
        block = np.floor((s.t - s.t[0]) / BLOCK_S).astype(int)
        h = (block % HOLD_EVERY) == HOLD_EVERY - 1
        train.append(~h)
        held.append(h)
    return train, held


def calibrate_from_drives(logs: Sequence[tuple[str, Iterable[str]]], config: PipelineConfig,
                          min_pairs: int | None = None) -> DriveFit:
    """Fit the wheel's constants to drives: ``logs`` are (name, sensor-log lines), ``config`` the estimator's
    (vehicle, settings; its constants are the prior).  ValueError, saying what to drive, when no soil shows
    enough of the curve."""
    cfg = config.model_copy(update={"vehicle": config.vehicle.model_copy(update={"traction_curve": None})})
    min_pairs = min_pairs or 2 * cfg.curve.min_pairs
    soils: list[SoilPairs] = []
    messages = []
    for name, lines in logs:
        summary = EstimateSummary()
        records = list(estimate_lines(lines, cfg, full=True, summary=summary))
        if not records:
            raise ValueError(f"{name}: no sample could be estimated ({len(summary.rejected)} rejected); check the log "
                             "with soilocp estimate first")
        found = soil_pairs(records, name, cfg.curve, min_pairs)
        top = max((float(np.quantile(s.slip, 0.98)) for s in found), default=0.0)
        messages.append(f"{name}: {len(records)} samples, {len(found)} soil(s) with >= {min_pairs} informative "
                        f"wheel-samples, slips up to {top:.2f}")
        soils.extend(found)
    if not soils:
        raise ValueError("no soil in these drives has enough informative wheel-samples to fit a curve: drive a traction "
                         "sweep (one axle sweeping its slip 0.05..0.7 while the other holds the speed), or hard "
                         "accelerations and brakes, for at least 10 s on each soil")
    prior = cfg.constants
    train, held = _held_out_masks(soils)
    theta, ln_k, cov, noise, res, n_soil = fit_soils(soils, prior, train)

    # the held-out blocks: the fitted curve, and the paper's at each soil's best K (fitted on the same blocks)
    c_fit = _constants(theta, prior)
    held_res, paper_res = [], []
    for s, h, t_mask, lk in zip(soils, held, train, ln_k):
        if not h.any():
            continue
        held_res.append(s.mu[h] - _net(s.slip[h], np.full(h.sum(), math.exp(lk)), c_fit))
        grid = np.geomspace(5, 5000, 200)
        err = [np.mean((s.mu[t_mask] - _net(s.slip[t_mask], np.full(t_mask.sum(), g), prior)) ** 2) for g in grid]
        k_paper = grid[int(np.argmin(err))]
        paper_res.append(s.mu[h] - _net(s.slip[h], np.full(h.sum(), k_paper), prior))
    rms = lambda parts: float(np.sqrt(np.mean(np.concatenate(parts) ** 2))) if parts else float("nan")  # noqa: E731
    fit_rms = float(np.sqrt(np.mean((res.fun[:sum(m.sum() for m in train)] * noise) ** 2)))

    # the final fit on every pair
    theta, ln_k, cov, noise, res, n_soil = fit_soils(soils, prior)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # the soils the curve was fitted over (their K within 2 sigma): beyond them the OCPs are extrapolated
    lo = float(np.min(np.exp(ln_k - 2 * sd[4:])))
    hi = float(np.max(np.exp(ln_k + 2 * sd[4:])))
    constants = _constants(theta, prior).model_copy(update={"k_range": (round(lo, 2), round(hi, 2))})
    # 1-sigma in the constants' own units (delta method through exp for the logs)
    values = {"C1": constants.C1, "C3": constants.C3, "C5": constants.C5, "C6": constants.C6}
    std = {"C1": constants.C1 * sd[0], "C3": constants.C3 * sd[1], "C5": sd[2], "C6": constants.C6 * sd[3]}
    corr_m = cov[:4, :4] / np.outer(sd[:4], sd[:4]).clip(min=1e-300)
    correlation = {a: {b: round(float(corr_m[i, j]), 3) for j, b in enumerate(FITTED) if j != i}
                   for i, a in enumerate(FITTED)}
    not_fitted = {
        "C2": "sets the scale of K with C5 and C6 (K -> lambda K leaves every curve unchanged): kept at its prior, so "
              "K is on that scale",
        "C4": "cancels from net traction (eq. 6), the only traction the drives show: kept at its prior",
        "alpha": "eq. 10's S_E line is not seen by traction: kept at its prior",
        "beta": "eq. 10's S_E line is not seen by traction: kept at its prior",
    }
    for i, name in enumerate(FITTED):
        if sd[i] > UNFITTED_SHARE * PRIOR_SIGMA[name]:
            why = ("one soil cannot separate K from C1, C5 and C6 (docs/method.md §14): drive two soils of different "
                   "strength" if n_soil == 1 else "the drives do not determine it")
            not_fitted[name] = f"{why}; kept near its prior ({values[name]:.4g} +- {std[name]:.2g})"
    soils_out = []
    for j, (s, lk) in enumerate(zip(soils, ln_k)):
        k = math.exp(lk)
        o = ocp_from_soil_strength(k, constants)
        soils_out.append({"source": s.source, "soil": s.index, "K": round(k, 2), "K_std": round(float(k * sd[4 + j]), 2),
                          "pairs": len(s), "slip_top": round(float(np.quantile(s.slip, 0.98)), 3),
                          "mu_T": round(o.mu_T, 4), "S_T": round(o.S_T, 4)})
    cal = WheelCalibration(
        constants=constants,
        std={k: round(float(v), 6) for k, v in std.items() if k not in not_fitted},
        correlation=correlation,
        not_fitted=not_fitted,
        soils=soils_out,
        held_out={"rms_fit": round(fit_rms, 5), "rms_held_out": round(rms(held_res), 5),
                  "rms_held_out_paper_curve": round(rms(paper_res), 5), "block_s": BLOCK_S, "held_every": HOLD_EVERY},
        sources=[name for name, _ in logs],
    )
    return DriveFit(cal, list(soils), fit_rms, rms(held_res), rms(paper_res), messages)
