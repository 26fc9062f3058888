"""Do the front and the rear axle read the same soil?  A check of the normal forces (docs/method.md §16).

K comes from gross traction = wheel torque / (R_w F_z): a wrong mass or centre of mass puts a
wrong F_z under each axle, by a different factor at the front and at the rear, and K is then read
wrong with a narrow band (the robustness variants mass-com+-20: 40-68 % off with status ``ok``).
The pooled belief cannot see it; two more beliefs can: the same grid filter
(:class:`soilocp.estimation.soil_grid.LogKGrid`: the same prediction, the same likelihood) fed by
the front wheels only and by the rear wheels only.  On the same soil they must agree within
their spreads.  When the disagreement, in units of its own 1-sigma, is above ``axle_mismatch_z``
for most of the last ``evidence_window`` s (a share, not a mean: after a terrain change the front
axle reads the new soil b/V s before the rear, a short, large disagreement that is no model
error), the model's normal forces (or one axle's torque constant) are off: the estimate is ``model_mismatch``, and K's band takes the axles' distance in
ln K as a systematic term (one axle is usually near the truth: mass-com-20 reads K 68 % low
pooled, within 2 % on the rear axle).

A torque scale common to all wheels moves both axles alike and is not seen here (§15).
"""

from __future__ import annotations

import math

import numpy as np

from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.soil_grid import LogKGrid

#: per wheel (paper order: left-rear, left-front, right-front, right-rear): 0 front axle, 1 rear
AXLE_OF_WHEEL = np.array([1, 0, 0, 1])


class AxleCheck:
    """Per vehicle, a front-only and a rear-only belief over ln K and the running disagreement."""

    def __init__(self, grid: LogKGrid, cfg: SoilConfig, n_vehicles: int):
        self.grid, self.cfg = grid, cfg
        g = grid.theta.size
        self.p = np.full((n_vehicles, 2, g), 1.0 / g)
        self.informed = np.full((n_vehicles, 2), np.nan)  # stamp of each axle's last informative sample
        # decaying sums over judged samples: of the time with z > axle_mismatch_z, and of all the time
        self.over = np.zeros(n_vehicles)
        self.weight = np.zeros(n_vehicles)

    def beliefs(self, ix: np.ndarray) -> np.ndarray:
        """Both axles' beliefs of vehicles ``ix`` (m,) as rows (2m, G), front then rear of each
        (the soil kernel predicts them in one call with the pooled beliefs)."""
        return self.p[ix].reshape(-1, self.p.shape[2])

    def set_beliefs(self, ix: np.ndarray, rows: np.ndarray) -> None:
        self.p[ix] = rows.reshape(-1, 2, self.p.shape[2])

    def update(self, ix: np.ndarray, stamp: np.ndarray, pair_row: np.ndarray, pair_wheel: np.ndarray,
               loglike: np.ndarray) -> None:
        """Fuse the used wheels' tempered log-likelihoods ``loglike`` (n_pairs, G); pair j belongs to
        vehicle ``ix[pair_row[j]]``, wheel ``pair_wheel[j]``."""
        m, g = ix.size, self.p.shape[2]
        key = pair_row * 2 + AXLE_OF_WHEEL[pair_wheel]
        pick = np.zeros((m * 2, key.size))  # sums the pairs of each (vehicle, axle): one small product
        pick[key, np.arange(key.size)] = 1.0
        acc = (pick @ loglike).reshape(m, 2, g)
        prior = self.p[ix]
        post = prior * np.exp(acc - acc.max(axis=2, keepdims=True))
        total = post.sum(axis=2, keepdims=True)
        ok = (total > 0) & np.isfinite(total)
        self.p[ix] = post / total if ok.all() else np.where(ok, post / np.where(ok, total, 1.0), prior)
        hit = np.zeros((m, 2), dtype=bool)
        hit[pair_row, AXLE_OF_WHEEL[pair_wheel]] = True
        self.informed[ix] = np.where(hit, stamp[:, None], self.informed[ix])

    def judge(self, vehicle: int, stamp: float, dt: float, tolerance: float) -> tuple[bool, float, float, float]:
        """(mismatch, z, ln K front, ln K rear) for one vehicle after this sample's update.

        Judged only while both axles informed their belief within ``hold_after`` s: z is the
        disagreement |d ln K| over the combined 16-84 % half-widths and the ordinary model error
        ``tolerance`` in ln K (``axle_scale_sigma`` through the curve's sensitivity).  A mismatch
        needs ``mismatch_min_evidence`` s of judged samples in the window, z above
        ``axle_mismatch_z`` for more than half of them, and now."""
        cfg = self.cfg
        decay = math.exp(-max(dt, 0.0) / cfg.evidence_window) if math.isfinite(dt) else 0.0
        self.over[vehicle] *= decay
        self.weight[vehicle] *= decay
        front, rear = self.informed[vehicle].tolist()
        if not (stamp - front <= cfg.hold_after and stamp - rear <= cfg.hold_after):  # NaN: never informed
            return False, math.nan, math.nan, math.nan
        p = self.p[vehicle]
        cdf = np.cumsum(p, axis=1) - 0.5 * p
        (k_f, _, s_f), (k_r, _, s_r) = self.grid.summary(cdf[0]), self.grid.summary(cdf[1])
        theta, spread = [math.log(k_f), math.log(k_r)], [s_f, s_r]
        z = abs(theta[0] - theta[1]) / math.sqrt(max(spread[0] ** 2 + spread[1] ** 2 + tolerance**2, 1e-24))
        step = 1.0 - decay if math.isfinite(dt) and dt > 0 else 0.0
        self.weight[vehicle] += step
        self.over[vehicle] += step * (z > cfg.axle_mismatch_z)
        w = self.weight[vehicle]
        enough = w >= 1.0 - math.exp(-cfg.mismatch_min_evidence / cfg.evidence_window)
        flagged = cfg.axle_mismatch_z > 0 and enough and z > cfg.axle_mismatch_z and self.over[vehicle] > 0.5 * w
        return flagged, z, theta[0], theta[1]
