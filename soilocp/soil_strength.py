"""Soil strength K from per-wheel slip and observed traction (paper §3.2, eqs. 36-37, corrected).

Two estimators share one interface (``update(stamp, slip, observed, variance, informative)``):

* :class:`PaperSoilEstimator` — the paper's numerical rule, kept for reproduction:
  K_n+1 = K_n + lambda * eta_E (eq. 36), eta_E = E / S_a with E = mu_e - mu_ref(S_a, K_n)
  (eq. 37).  Corrections (method-notes §4): the printed absolute value |E/S_a| can only increase
  K, so the sign is kept (K grows when the observed traction exceeds the curve's prediction); and
  the update is gated on informative slip (|S| in [s_min, s_max], so that dividing by S_a cannot
  blow up) and on d mu/dK > 0 at the current K (at small slip mu is not monotone in K).
* :class:`BayesSoilEstimator` — the default.  A grid (histogram) Bayes filter over ln K fuses all
  four wheels over time: each informative wheel contributes a robust likelihood of its observed
  coefficient given the model at its slip; between samples the belief diffuses (random walk in
  ln K) and mixes with a small uniform hazard, so abrupt terrain changes are picked up within a
  fraction of a second.  Working on a grid handles what an EKF cannot: mu(S, K) is not monotone
  in K at small slip, and above K ~ 300 the curve saturates (method-notes §9), which shows up as a
  wide posterior (status ``uncertain``), not false precision.  When slip carries no information
  (flat ground at cruise, standstill) nothing updates: the last estimate is held and flagged
  ``holding``, and after ``expire_after`` seconds it is withdrawn (``no_estimate``) — never a
  drifting number.

The observed coefficient is by default the gross traction mu + mu_xR (what the wheel torque
balance, eq. 13, measures; monotone in K) against eq. 3; ``measurement="net"`` uses the net mu
against eq. 6, as the paper does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from .checks import as_float_array
from .constants import DEFAULT_CONSTANTS, ModelConstants
from .traction import curve_unchecked, gross_traction_with_derivatives, net_traction_with_derivatives

Status = Literal["ok", "uncertain", "holding", "no_estimate"]


class SoilConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    method: Literal["bayes", "paper"] = Field("bayes", description="bayes (default) or paper (eqs. 36-37, sign fixed)")
    measurement: Literal["gross", "net"] = Field("gross", description="Compare gross (eq. 3) or net (eq. 6) traction")
    slip_min: float = Field(0.04, gt=0, lt=1, description="|S| below this carries no usable information")
    slip_max: float = Field(0.95, gt=0, le=1, description="|S| above this is wheel spin / lock")
    k_min: float = Field(5.0, gt=0, description="Lower end of the K grid")
    k_max: float = Field(5000.0, gt=0, description="Upper end of the K grid")
    grid_points: int = Field(241, ge=20, le=5000)
    q_log_k: float = Field(0.1, ge=0, description="Random walk of ln K, 1/sqrt(s)")
    change_rate: float = Field(0.5, ge=0, description="Hazard of an abrupt terrain change, 1/s (mixing with uniform)")
    model_sigma: float = Field(0.03, gt=0, description="Model / unmodelled error of the coefficient, 1-sigma")
    slip_sigma: float = Field(0.005, ge=0, description="Uncertainty of the filtered slip at speed, 1-sigma")
    speed_sigma: float = Field(
        0.008, ge=0, description="Error of the filtered speeds, m/s: slip error grows as speed_sigma / speed at low speed"
    )
    slip_snr: float = Field(3.0, ge=0, description="A wheel is used only when |S| >= slip_snr x its slip uncertainty")
    gate_smoothing: float = Field(
        0.15, ge=0, description="Time constant (s) of the low-pass slip the gate looks at: gating on the raw, noisy "
        "slip keeps the samples whose noise pushed |S| up and biases K low (method-notes §9)"
    )
    outlier_prob: float = Field(0.02, ge=0, lt=1, description="Weight of the outlier component of the likelihood")
    temper: float = Field(0.15, gt=0, le=1, description="Likelihood exponent: 100 Hz observer outputs are correlated")
    uncertain_log_sigma: float = Field(0.2, gt=0, description="ln K 1-sigma above which the estimate is 'uncertain'")
    hold_after: float = Field(0.5, gt=0, description="s without an informative update before status 'holding'")
    expire_after: float = Field(10.0, gt=0, description="s of 'holding' after which the estimate is withdrawn")
    learning_rate: float = Field(0.5, gt=0, le=1, description="lambda of eq. 36 (paper method)")
    k_initial: float = Field(120.0, gt=0, description="K_0 of the paper method")


@dataclass(frozen=True)
class SoilState:
    """What an estimator reports after each step: K is the belief's median, soil_strength_std
    and log_k_std half its 16-84 % interval (in K and in ln K)."""

    soil_strength: Optional[float]
    soil_strength_std: Optional[float]
    log_k_std: Optional[float]
    soil_class: Optional[str]
    soil_class_confidence: Optional[float]
    status: Status
    reason: str
    last_update_stamp: Optional[float]
    used: tuple[bool, bool, bool, bool]


def class_bounds(constants: ModelConstants) -> tuple[list[str], np.ndarray]:
    """Soil classes ordered by K and their boundaries in ln K (geometric means of neighbours)."""
    names = list(constants.soils)
    logs = np.log([constants.soils[n] for n in names])
    edges = np.concatenate([[-np.inf], (logs[:-1] + logs[1:]) / 2.0, [np.inf]])
    return names, edges


def classify(soil_strength: float, log_k_std: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> tuple[str, float]:
    """Most probable soil class for ln K ~ N(ln K, sigma^2), and its probability."""
    names, edges = class_bounds(constants)
    mu = math.log(soil_strength)
    sig = max(log_k_std, 1e-6)
    cdf = [0.5 * (1 + math.erf((e - mu) / (sig * math.sqrt(2)))) if np.isfinite(e) else (0.0 if e < 0 else 1.0)
           for e in edges]
    probs = np.diff(cdf)
    i = int(np.argmax(probs))
    return names[i], float(probs[i])


def _checked_quads(**arrays) -> list[np.ndarray]:
    """Per-wheel float arrays of shape (4,), finite; one vectorised check on the happy path."""
    out = [np.asarray(v, dtype=float) for v in arrays.values()]
    if all(a.shape == (4,) for a in out) and np.isfinite(np.concatenate(out)).all():
        return out
    return [as_float_array(name, v, shape=(4,)) for name, v in arrays.items()]  # raises, naming the argument


def slip_uncertainty(speed, cfg: SoilConfig) -> np.ndarray:
    """1-sigma slip error of eq. 1 at a wheel moving at ``speed`` (m/s): a speed error dV gives
    dS ~ dV / V, which dominates at low speed (method-notes §6, §9)."""
    v = np.maximum(np.abs(np.asarray(speed, dtype=float)), 1e-3)
    return np.hypot(cfg.slip_sigma, cfg.speed_sigma / v)


def _gate(slip: np.ndarray, informative: np.ndarray, cfg: SoilConfig, slip_sigma=None) -> np.ndarray:
    a = np.abs(slip)
    ok = informative & (a >= cfg.slip_min) & (a <= cfg.slip_max)
    if slip_sigma is not None:
        ok &= a >= cfg.slip_snr * slip_sigma
    return ok


class _HoldLogic:
    """Shared 'holding' / expiry bookkeeping (method-notes §9: hold, flagged; never drift)."""

    def __init__(self, cfg: SoilConfig):
        self.cfg = cfg
        self.last_update: Optional[float] = None
        self.held: Optional[tuple[float, float | None, float | None]] = None

    def status(self, stamp: float, k: float, k_std, log_std) -> tuple[Status, str, tuple]:
        cfg = self.cfg
        if self.last_update is None:
            return "no_estimate", "slip has not been informative yet (need |slip| >= %.2f)" % cfg.slip_min, (None, None, None)
        age = stamp - self.last_update
        if age < 0:  # stamps went backwards (a restarted source): the old update time means nothing
            self.last_update = self.held = None
            return "no_estimate", "stamp went backwards (source restarted): estimate withdrawn", (None, None, None)
        if age > cfg.hold_after + cfg.expire_after:
            return "no_estimate", f"slip uninformative for {age:.1f} s: estimate withdrawn", (None, None, None)
        if age == 0.0 or self.held is None:
            self.held = (k, k_std, log_std)  # fresh: this sample updated the belief
        else:
            # no information this sample: report the last informed estimate, not the belief
            # that is diffusing towards the change prior (method-notes §9: never drift)
            k, _, _ = self.held
            k_std, log_std = k_std if k_std is None else max(k_std, self.held[1] or 0.0), log_std
        if age > cfg.hold_after:
            return "holding", f"slip uninformative for {age:.1f} s: holding the last estimate", (k, k_std, log_std)
        if log_std is not None and log_std > cfg.uncertain_log_sigma:
            return "uncertain", f"ln K 1-sigma {log_std:.2f} > {cfg.uncertain_log_sigma}: K poorly determined", (k, k_std, log_std)
        return "ok", "", (k, k_std, log_std)


class LogKGrid:
    """The ln K grid of the Bayes estimator and what is computed on it: the observation curve
    (eq. 3 or 6, factorised), the belief's prediction (random walk + change prior) and its robust
    summaries.  One object serves :class:`BayesSoilEstimator` and the batched ``soilocp.batch``."""

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
        # Slip-independent factors of eqs. 3 / 6 on the grid, so an update costs one exp per wheel.
        c = constants
        self._amp = c.C1 * -np.expm1(-c.C2 * self.k_grid)  # C1 (1 - e^{-C2 K})
        self._offset = np.full_like(self.k_grid, c.C4) if self.kind == "gross" else -c.C5 / self.k_grid
        self._slope = np.zeros_like(self.k_grid) if self.kind == "gross" else -c.C6 / np.sqrt(self.k_grid)

    def curve(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h(S, K_grid) and d h/dS for slips s (n, 1): eq. 3 (gross) or eq. 6 (net), odd in S.

        Equal to :func:`soilocp.traction.curve_unchecked` (tested); outside the zero-slip bridge
        the printed curve factorises into grid constants and one exp per wheel.
        """
        a = np.abs(s)
        if np.any(a < self.c.bridge_slip):
            h, d, _ = curve_unchecked(self.kind, s, self.k_grid[None, :], self.c)
            return h, d
        e = np.exp(-self.c.C3 * a)
        sign = np.where(s < 0, -1.0, 1.0)
        h = sign * (self._amp * (1.0 - e) + self._offset + self._slope * a)
        d = self._amp * self.c.C3 * e + self._slope
        return h, d

    def predict(self, p: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Beliefs p (k, G) after dt (k,) > 0 seconds: diffusion of ln K (random walk) and mixing
        with the uniform change prior.  After a long gap nothing survives: uniform at once."""
        cfg = self.cfg
        lost = (cfg.change_rate * dt >= 1.0) | (cfg.q_log_k**2 * dt >= self.span**2)
        if lost.any():
            p = p.copy()
            p[lost] = 1.0 / p.shape[1]
        eps = np.where(lost, 0.0, cfg.q_log_k**2 * dt / (2 * self.dtheta**2))
        while np.any(eps > 0):
            e = np.where(eps > 0, np.minimum(eps, 0.25), 0.0)[:, None]  # 3-tap kernel valid for eps <= 1/4
            q = (1 - 2 * e) * p
            q[:, 1:] += e * p[:, :-1]
            q[:, :-1] += e * p[:, 1:]
            q[:, :1] += e * p[:, :1]  # reflecting ends keep the mass
            q[:, -1:] += e * p[:, -1:]
            p = q
            eps = eps - e[:, 0]
        h = np.minimum(cfg.change_rate * dt, 1.0)[:, None]
        return (1 - h) * p + h / p.shape[1]

    def summary(self, cdf_row: np.ndarray) -> tuple[float, float, float]:
        """(K, K 1-sigma, ln K 1-sigma) from a belief's mid-point CDF: the median and half the
        16-84 % interval.  Moments would be dominated by the small uniform "terrain may change"
        mass spread over K = 5..5000."""
        t16, t50, t84 = np.interp((0.15865, 0.5, 0.84135), cdf_row, self.theta)
        return math.exp(t50), float((math.exp(t84) - math.exp(t16)) / 2.0), float((t84 - t16) / 2.0)


class BayesSoilEstimator:
    """Grid Bayes filter over ln K fusing the four wheels (default estimator; see module doc)."""

    def __init__(self, constants: ModelConstants = DEFAULT_CONSTANTS, config: SoilConfig | None = None):
        self.c = constants
        self.cfg = cfg = config or SoilConfig()
        self.grid = LogKGrid(constants, cfg)
        self.theta, self.k_grid = self.grid.theta, self.grid.k_grid
        self.p = np.full(cfg.grid_points, 1.0 / cfg.grid_points)
        self._names, self._class_idx = self.grid.names, self.grid.class_idx
        self._hold = _HoldLogic(cfg)
        self._last_stamp: Optional[float] = None

    def _curve(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.grid.curve(s)

    def _predict(self, dt: float) -> None:
        if dt > 0:
            self.p = self.grid.predict(self.p[None, :], np.array([dt]))[0]

    def update(self, stamp: float, slip, observed, variance, informative, slip_sigma=None,
               gate_slip=None, gate_sigma=None) -> SoilState:
        """Fuse one sample: slip (4,), observed coefficient (4,), its variance (4,), which wheels
        may be used (4,) and optionally each slip's 1-sigma (4,; default ``cfg.slip_sigma``).
        ``gate_slip`` / ``gate_sigma``: the (smoothed) slip and its 1-sigma the gate decides on
        (default: ``slip`` / ``slip_sigma``)."""
        cfg = self.cfg
        slip, obs, var, s_sig = _checked_quads(slip=slip, observed=observed, variance=variance,
                                               slip_sigma=np.full(4, cfg.slip_sigma) if slip_sigma is None else slip_sigma)
        g_slip = slip if gate_slip is None else np.asarray(gate_slip, dtype=float)
        g_sig = s_sig if gate_sigma is None else np.asarray(gate_sigma, dtype=float)
        use = _gate(g_slip, np.asarray(informative, dtype=bool), cfg, g_sig) & (np.sign(g_slip) == np.sign(slip))
        if self._last_stamp is not None:
            self._predict(stamp - self._last_stamp)
        self._last_stamp = stamp
        any_info = False
        if use.any():
            s = slip[use][:, None]
            h, dh_ds = self._curve(s)
            sig2 = var[use][:, None] + cfg.model_sigma**2 + (dh_ds * s_sig[use][:, None]) ** 2
            r2 = (obs[use][:, None] - h) ** 2 / sig2
            like = (1 - cfg.outlier_prob) * np.exp(-0.5 * r2) / np.sqrt(sig2) + cfg.outlier_prob
            # Where the curve is insensitive to K (saturation, small slip) the likelihood is flat
            # over the grid and the update changes nothing: the grid gates on d h/dK by itself.
            loglike = np.log(np.prod(like, axis=0)) * cfg.temper
            post = self.p * np.exp(loglike - loglike.max())
            total = post.sum()
            if total > 0 and np.isfinite(total):
                self.p = post / total
                any_info = True
        used = use
        if any_info:
            self._hold.last_update = stamp
        k, k_std, log_std = self.grid.summary(np.cumsum(self.p) - 0.5 * self.p)
        status, reason, (rk, rs, rl) = self._hold.status(stamp, k, k_std, log_std)
        cls = conf = None
        if rk is not None:
            if not any_info:
                cls, conf = classify(rk, rl, self.c)
            else:
                masses = np.bincount(self._class_idx, weights=self.p, minlength=len(self._names))
                i = int(np.argmax(masses))
                cls, conf = self._names[i], float(masses[i])
        return SoilState(rk, rs, rl, cls, conf, status, reason, self._hold.last_update, tuple(bool(u) for u in used))


class PaperSoilEstimator:
    """The paper's update rule, eqs. 36-37, with the sign of eq. 37 restored and gated (module doc)."""

    def __init__(self, constants: ModelConstants = DEFAULT_CONSTANTS, config: SoilConfig | None = None):
        self.c = constants
        self.cfg = config or SoilConfig(method="paper", measurement="net")
        self.k = float(self.cfg.k_initial)
        self._hold = _HoldLogic(self.cfg)

    def update(self, stamp: float, slip, observed, variance=None, informative=(True,) * 4, slip_sigma=None) -> SoilState:
        cfg = self.cfg
        slip = as_float_array("slip", slip, shape=(4,))
        obs = as_float_array("observed", observed, shape=(4,))
        use = _gate(slip, np.asarray(informative, dtype=bool), cfg,
                    None if slip_sigma is None else as_float_array("slip_sigma", slip_sigma, shape=(4,)))
        model = gross_traction_with_derivatives if cfg.measurement == "gross" else net_traction_with_derivatives
        used = np.zeros(4, dtype=bool)
        for i in np.flatnonzero(use):
            ref, _, dk = model(slip[i], self.k, self.c)
            # eq. 37 assumes |mu| grows with K: not so at small slip (method-notes §4); the curve is
            # odd in S, so for a braking wheel d mu/dK < 0 is the normal, monotone case
            if float(dk) * np.sign(slip[i]) <= 0:
                continue
            # eq. 37 without |.|: E / S_a keeps the sign of the error (eq. 6 is odd in S, so a
            # braking wheel's E and S_a are both negated and the ratio is unchanged)
            eta = (obs[i] - float(ref)) / slip[i]
            self.k = float(np.clip(self.k + cfg.learning_rate * eta, cfg.k_min, cfg.k_max))  # eq. 36
            used[i] = True
        if used.any():
            self._hold.last_update = stamp
        status, reason, (rk, _, _) = self._hold.status(stamp, self.k, None, None)
        cls = conf = None
        if rk is not None:
            cls, conf = classify(rk, 0.1, self.c)
        return SoilState(rk, None, None, cls, conf, status, reason, self._hold.last_update, tuple(bool(u) for u in used))


def make_soil_estimator(constants: ModelConstants, config: SoilConfig):
    if config.method == "paper":
        return PaperSoilEstimator(constants, config)
    return BayesSoilEstimator(constants, config)
