"""The joint belief of the soil kernel: a grid over ln K, and at each grid node a Gaussian belief
over the gross-traction scale of the two axles (docs/method.md §9, §16).

The measured gross traction of wheel i is  y_i = c_a(i) h(S_i, K) + noise  (eq. 3, §11 for
S < 0), where c = (c_front, c_rear) is the factor by which the torque balance misreads gross
traction: a torque constant (current -> torque) that is off scales both axles alike, a mass or
CoM that differs from the configured vehicle scales each axle's normal force, so each axle's.
Given K, y is linear in c, so the 3-D posterior over (ln K, c_f, c_r) is kept exactly in the
c-direction as one Gaussian per ln K node (a Rao-Blackwellised grid filter):

* the node weights p (N, G) are the marginal posterior of ln K, whatever c is;
* the node's mean m (N, 2, G) and covariance V (N, 3, G) = (V_ff, V_fr, V_rr) are c's belief given
  that K.

Prediction (random walk of ln K, terrain-change hazard, drift of c) and the robust likelihood
are the same operations as on the 1-D grid, applied to the raw moments p, p m, p (V + m m^T): the
ln K kernel mixes neighbouring nodes and the hazard mixes every node with the uniform prior over
ln K, whose c-belief is the current marginal one (a terrain change does not change the sensors).
The mixed Gaussians are collapsed to their first two moments.
"""

from __future__ import annotations

import math

import numpy as np

from soilocp.model.constants import ModelConstants
from soilocp.estimation.soil_config import SoilConfig, class_bounds
from soilocp.model.traction import curve_unchecked

#: Axle of each wheel in the paper's order (1 left-rear, 2 left-front, 3 right-front, 4 right-rear):
#: 0 front, 1 rear (docs/method.md, Conventions).
AXLE = (1, 0, 0, 1)
#: Index in V = (V_ff, V_fr, V_rr) of (axle a, axle b).
_VIDX = ((0, 1), (1, 2))
_TINY = 1e-300


class LogKGrid:
    """The ln K grid and what is computed on it: the observation curve (eq. 3 or 6, factorised),
    the belief's prediction and its robust summaries.  One object serves
    :class:`soilocp.estimation.soil_strength.SoilBank` (and through it the batched ``soilocp.estimation.batch``)."""

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
        # prior covariance of c: a common part (torque constant) plus each axle's own (its load)
        st, sa = cfg.gross_scale_sigma, cfg.axle_scale_sigma
        self.scale_prior = np.array([st**2 + sa**2, st**2, st**2 + sa**2])
        tot = self.scale_prior[0]
        self._drift = self.scale_prior / tot if tot > 0 else np.array([1.0, 0.0, 1.0])
        # Slip-independent factors of the curve on the grid, per side of S = 0, so an update costs
        # one exp per wheel: h = sign (amp (1 - e^{-C3 |S|})) + offset_side + slope_side |S|
        c = constants
        k = self.k_grid
        self._amp = c.C1 * -np.expm1(-c.C2 * k)  # C1 (1 - e^{-C2 K})
        if self.kind == "gross":
            # S > 0: eq. 3.  S < 0 (docs/method.md §11): -mu(|S|) + r(|S|) = -g(|S|) + 2 r(|S|)
            self._offset = (np.full_like(k, c.C4), c.C4 + 2.0 * c.C5 / k)
            self._slope = (np.zeros_like(k), 2.0 * c.C6 / np.sqrt(k))
        else:  # eq. 6, odd
            self._offset = (-c.C5 / k, c.C5 / k)
            self._slope = (-c.C6 / np.sqrt(k), c.C6 / np.sqrt(k))

    def initial(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The prior of n vehicles: uniform in ln K, c ~ N((1, 1), scale_prior) at every node."""
        G = self.theta.size
        p = np.full((n, G), 1.0 / G)
        m = np.ones((n, 2, G))
        v = np.broadcast_to(self.scale_prior[None, :, None], (n, 3, G)).copy()
        return p, m, v

    def curve(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h(S, K_grid) and d h/dS for slips s (n, 1): gross traction g = mu + r (eq. 3 for S > 0,
        docs/method.md §11 for S < 0) or net traction (eq. 6).

        Equal to :func:`soilocp.model.traction.curve_unchecked` (tested); outside the zero-slip bridge
        the curve factorises into grid constants and one exp per wheel.
        """
        a = np.abs(s)
        if np.any(a < self.c.bridge_slip):
            h, d, _ = curve_unchecked(self.kind, s, self.k_grid[None, :], self.c)
            return h, d
        e = np.exp(-self.c.C3 * a)
        neg = s < 0
        rise = self._amp * (1.0 - e)
        off = np.where(neg, self._offset[1], self._offset[0])
        slope = np.where(neg, self._slope[1], self._slope[0])
        h = np.where(neg, -rise, rise) + off + slope * a
        d = self._amp * self.c.C3 * e + np.where(neg, -slope, slope)
        return h, d

    def predict(self, p: np.ndarray, m: np.ndarray, v: np.ndarray, dt: np.ndarray, free=True):
        """Beliefs (p (k, G), m (k, 2, G), V (k, 3, G)) after dt (k,) > 0 seconds: diffusion of ln K
        (random walk), mixing with the uniform change prior over ln K (c keeps its marginal
        belief), drift of c where ``free`` (k,) (a row whose scale is fixed keeps V = 0).  After a
        long gap no ln K information survives: uniform at once."""
        cfg = self.cfg
        G = p.shape[1]
        # raw moments per node: p, p m_f, p m_r, p (V_ff + m_f^2), p (V_fr + m_f m_r), p (V_rr + m_r^2)
        a = np.empty((p.shape[0], 6, G))
        a[:, 0] = p
        a[:, 1:3] = p[:, None] * m
        a[:, 3] = p * (v[:, 0] + m[:, 0] ** 2)
        a[:, 4] = p * (v[:, 1] + m[:, 0] * m[:, 1])
        a[:, 5] = p * (v[:, 2] + m[:, 1] ** 2)
        lost = (cfg.change_rate * dt >= 1.0) | (cfg.q_log_k**2 * dt >= self.span**2)
        if lost.any():
            a[lost] = a[lost].sum(axis=2, keepdims=True) / G
        eps = np.where(lost, 0.0, cfg.q_log_k**2 * dt / (2 * self.dtheta**2))
        while np.any(eps > 0):
            e = np.where(eps > 0, np.minimum(eps, 0.25), 0.0)[:, None, None]  # 3-tap kernel valid for eps <= 1/4
            q = (1 - 2 * e) * a
            q[..., 1:] += e * a[..., :-1]
            q[..., :-1] += e * a[..., 1:]
            q[..., :1] += e * a[..., :1]  # reflecting ends keep the mass
            q[..., -1:] += e * a[..., -1:]
            a = q
            eps = eps - e[:, 0, 0]
        h = np.minimum(cfg.change_rate * dt, 1.0)[:, None, None]
        a = (1 - h) * a + h * a.sum(axis=2, keepdims=True) / G
        p = a[:, 0]
        safe = np.maximum(p, _TINY)
        m = a[:, 1:3] / safe[:, None]
        v = np.empty_like(v)
        v[:, 0] = a[:, 3] / safe - m[:, 0] ** 2
        v[:, 1] = a[:, 4] / safe - m[:, 0] * m[:, 1]
        v[:, 2] = a[:, 5] / safe - m[:, 1] ** 2
        v += (cfg.scale_drift**2 * dt * free)[:, None, None] * self._drift[None, :, None]
        return p, m, psd(v)

    def summary(self, cdf_row: np.ndarray) -> tuple[float, float, float]:
        """(K, K 1-sigma, ln K 1-sigma) from a belief's mid-point CDF: the median and half the
        16-84 % interval.  Moments would be dominated by the small uniform "terrain may change"
        mass spread over K = 5..5000."""
        t16, t50, t84 = np.interp((0.15865, 0.5, 0.84135), cdf_row, self.theta)
        return math.exp(t50), float((math.exp(t84) - math.exp(t16)) / 2.0), float((t84 - t16) / 2.0)


def psd(v: np.ndarray) -> np.ndarray:
    """Keep each node's 2x2 covariance positive semi-definite (moment collapses round off)."""
    v[:, 0] = np.maximum(v[:, 0], 0.0)
    v[:, 2] = np.maximum(v[:, 2], 0.0)
    lim = np.sqrt(v[:, 0] * v[:, 2])
    v[:, 1] = np.clip(v[:, 1], -lim, lim)
    return v


def fuse_wheel(p_log: np.ndarray, m: np.ndarray, v: np.ndarray, axle: int, y: np.ndarray, h: np.ndarray,
               sig2: np.ndarray, cfg: SoilConfig) -> np.ndarray:
    """One wheel's robust, tempered likelihood of y = c_axle h(S, K) + noise (variance sig2), for
    k vehicles at every node: adds its log-weight to p_log (k, G) and updates the node Gaussians
    m (k, 2, G), V (k, 3, G) in place.  Returns the normalised squared innovation against the
    predictive spread (for the mismatch check, docs/method.md §16).

    Tempering (exponent ``temper``: 100 Hz samples are correlated) of a Gaussian in c is a Gaussian
    with variance sig2 / temper; the outlier mixture (weight ``outlier_prob``) is applied to the
    c-marginal likelihood as on the 1-D grid, and its posterior (updated with probability rho,
    untouched with 1 - rho) is collapsed to two moments.  With V = 0 this is exactly the 1-D
    grid's likelihood [(1 - o) N(y; h, sig2) + o]^temper.
    """
    tau, o = cfg.temper, cfg.outlier_prob
    ia, ib = _VIDX[axle]  # V indices of (a, front) and (a, rear): column a of V
    v_af, v_ar = v[:, ia].copy(), v[:, ib].copy()  # cov(c_f, c_a), cov(c_r, c_a), before this update
    v_aa = v_af if axle == 0 else v_ar
    innov = y - h * m[:, axle]
    h2v = h * h * v_aa
    pt = h2v + sig2 / tau  # predictive variance of the tempered Gaussian
    ratio = sig2 / (tau * pt)
    # the c-marginal of N(y; c h, sig2)^tau, written as an untempered Gaussian g so that the
    # outlier mixture and the exponent are those of the 1-D grid
    g = np.exp(-0.5 * innov**2 / (tau * pt) + np.log(ratio) / (2 * tau) - 0.5 * np.log(sig2))
    like = (1 - o) * g + o
    p_log += tau * np.log(like)
    rho = (1 - o) * g / like
    gain_f, gain_r = v_af * h / pt, v_ar * h / pt
    d_f, d_r = gain_f * innov, gain_r * innov
    m[:, 0] += rho * d_f
    m[:, 1] += rho * d_r
    both = rho * (1 - rho)
    v[:, 0] += both * d_f * d_f - rho * gain_f * h * v_af
    v[:, 1] += both * d_f * d_r - rho * gain_f * h * v_ar
    v[:, 2] += both * d_r * d_r - rho * gain_r * h * v_ar  # kept PSD by the caller (psd) after all wheels
    return innov**2 / (sig2 + h2v)
