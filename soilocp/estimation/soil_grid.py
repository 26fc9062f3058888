"""The ln K grid of the Bayes soil estimator: the grid, its prediction (random walk in ln K with a
small hazard) and the traction curve at each grid point (docs/method.md §9, §11)."""

from __future__ import annotations

import math

import numpy as np

from soilocp.model.constants import ModelConstants
from soilocp.model.traction import curve_unchecked
from soilocp.estimation.soil_config import SoilConfig, class_bounds


class LogKGrid:
    """The ln K grid of the Bayes estimator and what is computed on it: the observation curve
    (eq. 3 or 6, factorised), the belief's prediction (random walk + change prior) and its robust
    summaries.  One object serves :class:`BayesSoilEstimator` and the batched ``soilocp.estimation.batch``."""

    def __init__(self, constants: ModelConstants, cfg: SoilConfig):
        if cfg.k_max <= cfg.k_min:
            raise ValueError(f"k_max ({cfg.k_max}) must exceed k_min ({cfg.k_min})")
        self.c, self.cfg, self.kind = constants, cfg, cfg.measurement
        self.theta = np.linspace(math.log(cfg.k_min), math.log(cfg.k_max), cfg.grid_points)
        self.k_grid = np.exp(self.theta)
        self.dtheta = self.theta[1] - self.theta[0]
        self.span = self.theta[-1] - self.theta[0]
        self.names, edges = class_bounds(constants)
        self.class_idx = np.clip(np.searchsorted(edges, self.theta, side="right") - 1, 0, len(self.names) - 1)
        # Slip-independent factors of the curve on the grid, per side of S = 0, so an update costs
        # one exp per wheel: h = sign (amp (1 - e^{-C3 |S|})) + offset_side + slope_side |S|
        c = constants
        k = self.k_grid
        self._amp = c.C1 * -np.expm1(-c.C2 * k)  # C1 (1 - e^{-C2 K})
        if self.kind == "gross":
            # S > 0: eq. 3.  S < 0 (docs/method.md §11): -mu(|S|) + r(|S|) = -g(|S|) + 2 r(|S|)
            self._offset = np.stack([np.full_like(k, c.C4), c.C4 + 2.0 * c.C5 / k])
            self._slope = np.stack([np.zeros_like(k), 2.0 * c.C6 / np.sqrt(k)])
        else:  # eq. 6, odd
            self._offset = np.stack([-c.C5 / k, c.C5 / k])
            self._slope = np.stack([-c.C6 / np.sqrt(k), c.C6 / np.sqrt(k)])
        # rows indexed by side (0: S >= 0, 1: S < 0): the odd part's sign and d(slope |S|)/dS
        self._sign = np.array([[1.0], [-1.0]])
        self._dslope = self._slope * self._sign

    def curve(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h(S, K_grid) and d h/dS for slips s (n, 1): gross traction g = mu + r (eq. 3 for S > 0,
        docs/method.md §11 for S < 0) or net traction (eq. 6).

        Equal to :func:`soilocp.model.traction.curve_unchecked` (tested); outside the zero-slip bridge
        the curve factorises into grid constants and one exp per wheel.
        """
        a = np.abs(s)
        if (a < self.c.bridge_slip).any():
            h, d, _ = curve_unchecked(self.kind, s, self.k_grid[None, :], self.c)
            return h, d
        e = np.exp(-self.c.C3 * a)
        side = (s[:, 0] < 0).astype(np.intp)
        rise = self._amp * (1.0 - e)
        h = self._sign[side] * rise + self._offset[side] + self._slope[side] * a
        d = self._amp * self.c.C3 * e + self._dslope[side]
        return h, d

    def predict(self, p: np.ndarray, dt: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """Beliefs p (k, G) after dt (k,) > 0 seconds over ``distance`` (k,) metres travelled:
        diffusion of ln K (random walk in time: slow drift, moisture) and mixing with the uniform
        change prior (a hazard per metre: the soil changes where the robot goes, so a robot that
        stands keeps its belief).  After a long gap or a long way nothing survives: uniform at once."""
        cfg = self.cfg
        h = cfg.change_per_metre * distance
        lost = (h >= 1.0) | (cfg.q_log_k**2 * dt >= self.span**2)
        if lost.any():
            p = p.copy()
            p[lost] = 1.0 / p.shape[1]
        eps = np.where(lost, 0.0, cfg.q_log_k**2 * dt / (2 * self.dtheta**2))
        while True:
            on = eps > 0
            if not on.any():
                break
            e = np.where(on, np.minimum(eps, 0.25), 0.0)[:, None]  # 3-tap kernel valid for eps <= 1/4
            q = (1 - 2 * e) * p
            q[:, 1:] += e * p[:, :-1]
            q[:, :-1] += e * p[:, 1:]
            q[:, :1] += e * p[:, :1]  # reflecting ends keep the mass
            q[:, -1:] += e * p[:, -1:]
            p = q
            eps = eps - e[:, 0]
        h = np.minimum(h, 1.0)[:, None]
        return (1 - h) * p + h / p.shape[1]

    def median_nodes(self, cdf: np.ndarray, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Index (k,) of each belief's first node whose mid-point CDF (k, G) reaches 1/2, kept within
        [lo, hi] (default: the grid): the node the median lies at or just below.  The one definition of
        "the median's node" (the likelihood's slip term, the window's NIS and slope, :meth:`medians`)."""
        g = self.theta.size
        i = (cdf < 0.5).sum(axis=1)
        return np.minimum(np.maximum(i, lo), g - 1 if hi is None else hi)

    def medians(self, cdf: np.ndarray) -> np.ndarray:
        """ln K at the median of each belief (k,) from their mid-point CDFs (k, G): np.interp(0.5, row,
        theta) for every row at once (a CDF is non-decreasing; beyond its ends, the end node)."""
        i = self.median_nodes(cdf, 1)
        r = np.arange(cdf.shape[0])
        c0, c1 = cdf[r, i - 1], cdf[r, i]
        f = np.clip((0.5 - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.0, 1.0)
        return self.theta[i - 1] + f * (self.theta[i] - self.theta[i - 1])

    def summary(self, cdf_row: np.ndarray) -> tuple[float, float, float]:
        """(K, K 1-sigma, ln K 1-sigma) from a belief's mid-point CDF: the median and half the
        16-84 % interval.  Moments would be dominated by the small uniform "terrain may change"
        mass spread over K = 5..5000."""
        t16, t50, t84 = np.interp((0.15865, 0.5, 0.84135), cdf_row, self.theta)
        return math.exp(t50), float((math.exp(t84) - math.exp(t16)) / 2.0), float((t84 - t16) / 2.0)
