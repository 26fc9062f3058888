"""Soil strength K from per-wheel slip and observed traction (paper §3.2, eqs. 36-37, corrected).

Two estimators share one interface (``update(stamp, slip, observed, variance, informative)``):

* :class:`PaperSoilEstimator` — the paper's numerical rule, kept for reproduction:
  K_n+1 = K_n + lambda * eta_E (eq. 36), eta_E = E / S_a with E = mu_e - mu_ref(S_a, K_n)
  (eq. 37).  Corrections (docs/method.md §4): the printed absolute value |E/S_a| can only increase
  K, so the sign is kept (K grows when the observed traction exceeds the curve's prediction); and
  the update is gated on informative slip (|S| in [s_min, s_max], so that dividing by S_a cannot
  blow up) and on d mu/dK > 0 at the current K (at small slip mu is not monotone in K).
* :class:`BayesSoilEstimator` — the default.  A grid (histogram) Bayes filter over ln K fuses all
  four wheels over time: each informative wheel contributes a robust likelihood of its observed
  coefficient given the model at its slip; between samples the belief diffuses (random walk in
  ln K) and mixes with a small uniform hazard, so abrupt terrain changes are picked up within a
  fraction of a second.  Working on a grid handles what an EKF cannot: mu(S, K) is not monotone
  in K at small slip, and above K ~ 300 the curve saturates (docs/method.md §9), which shows up as a
  wide posterior (status ``uncertain``), not false precision.  When slip carries no information
  (flat ground at cruise, standstill) nothing updates: the last estimate is held and flagged
  ``holding``, and after ``expire_after`` seconds it is withdrawn (``no_estimate``) — never a
  drifting number.  The gross-traction scale of each axle (torque constant, normal-force split)
  is estimated with K and marginalised out of K's band (:mod:`soilocp.estimation.soil_grid`, docs/method.md
  §16).

The observed coefficient is by default the gross traction mu + mu_xR (what the wheel torque
balance, eq. 13, measures; monotone in K) against eq. 3; ``measurement="net"`` uses the net mu
against eq. 6, as the paper does.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from soilocp.model.checks import as_float_array, check_count, check_index
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.estimation.soil_config import SoilConfig, SoilState, Status, class_bounds, classify
from soilocp.estimation.soil_grid import AXLE, LogKGrid, fuse_wheel, psd
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives

__all__ = ["SoilConfig", "SoilState", "Status", "class_bounds", "classify", "LogKGrid", "SoilBank",
           "BayesSoilEstimator", "PaperSoilEstimator", "make_soil_estimator", "slip_uncertainty"]

def _checked_quads(**arrays) -> list[np.ndarray]:
    """Per-wheel float arrays of shape (4,), finite; one vectorised check on the happy path."""
    out = [np.asarray(v, dtype=float) for v in arrays.values()]
    if all(a.shape == (4,) for a in out) and np.isfinite(np.concatenate(out)).all():
        return out
    return [as_float_array(name, v, shape=(4,)) for name, v in arrays.items()]  # raises, naming the argument


def slip_uncertainty(speed, cfg: SoilConfig) -> np.ndarray:
    """1-sigma slip error of eq. 1 at a wheel moving at ``speed`` (m/s): a speed error dV gives
    dS ~ dV / V, which dominates at low speed (docs/method.md §6, §9)."""
    v = np.maximum(np.abs(np.asarray(speed, dtype=float)), 1e-3)
    return np.hypot(cfg.slip_sigma, cfg.speed_sigma / v)


def _gate(slip: np.ndarray, informative: np.ndarray, cfg: SoilConfig, slip_sigma=None) -> np.ndarray:
    a = np.abs(slip)
    ok = informative & (a >= cfg.slip_min) & (a <= cfg.slip_max)
    if slip_sigma is not None:
        ok &= a >= cfg.slip_snr * slip_sigma
    return ok


class _HoldLogic:
    """Shared 'holding' / expiry bookkeeping (docs/method.md §9: hold, flagged; never drift)."""

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
            # that is diffusing towards the change prior (docs/method.md §9: never drift)
            k, _, _ = self.held
            k_std, log_std = k_std if k_std is None else max(k_std, self.held[1] or 0.0), log_std
        if age > cfg.hold_after:
            return "holding", f"slip uninformative for {age:.1f} s: holding the last estimate", (k, k_std, log_std)
        if log_std is not None and log_std > cfg.uncertain_log_sigma:
            return "uncertain", f"ln K 1-sigma {log_std:.2f} > {cfg.uncertain_log_sigma}: K poorly determined", (k, k_std, log_std)
        return "ok", "", (k, k_std, log_std)


class SoilBank:
    """N joint grid Bayes filters over (ln K, gross-traction scale) (the soil kernel; module doc,
    :mod:`soilocp.estimation.soil_grid`), stepped together.

    Per vehicle it also keeps, over ``evidence_window`` seconds of informative samples:

    * the mean normalised residual (NIS) of the used wheels at the posterior median, against the
      predictive spread (noise and the scale's uncertainty): when the traction curve cannot
      explain the (slip, traction) pairs at any K and scale, the status is ``model_mismatch``
      rather than a confident class;
    * the systematic part of K's error budget from a wheel-radius error (``radius_sigma``, common
      to every sample, so it does not average out): its effect on ln K is the weighted
      least-squares shift  d lnK = eps sum(w h_K h_S dS/dlnR) / sum(w h_K^2), added in quadrature
      to the belief's own spread.  (The gross-traction scale, which used to be budgeted the same
      way, is now a second hypothesis whose K widens the band: docs/method.md §16.)
    """

    def __init__(self, constants: ModelConstants, config: SoilConfig | None, n_vehicles: int):
        self.c = constants
        self.cfg = cfg = config or SoilConfig()
        if cfg.method != "bayes":
            raise ValueError(f"soil method {cfg.method!r}: the soil kernel implements 'bayes' only")
        self.n_vehicles = n = check_count(n_vehicles)
        self.grid = LogKGrid(constants, cfg)
        self.theta, self.k_grid = self.grid.theta, self.grid.k_grid
        # Two hypotheses per vehicle (docs/method.md §16), rows 2i and 2i + 1: the configured scale
        # (c = 1 exactly: K as the configured vehicle and torque constant imply) and the fitted one
        # (c estimated with K).  K is reported from the first; their disagreement enters K's band.
        self.p, self.m, self.v = self.grid.initial(2 * n)
        self.v[0::2] = 0.0
        self._holds = [_HoldLogic(cfg) for _ in range(n)]
        # half the weakest reference soil's K: the traction constants were fitted on soils from there
        # up; a belief mostly below it is an extrapolation that a wrong torque scale produces, not a soil
        self.k_floor = math.exp(class_bounds(constants)[1][0])
        self._floor_idx = int(np.searchsorted(self.k_grid, self.k_floor))
        self.last_stamp = np.full(2 * n, np.nan)
        # window statistics: evidence (s of informative samples), NIS sum, and the radius budget's
        # sums  sum w h_K^2, sum w h_K h_S dS
        self.stats = np.zeros((2 * n, 4))

    def update(self, idx, stamp, slip, observed, variance, informative, slip_sigma, gate_slip=None,
               gate_sigma=None, held=None, identifiable=None) -> list[SoilState]:
        """Fuse one sample per vehicle in ``idx``: stamp (k,) [s]; slip (k, 4) (eq. 1); observed
        coefficient (k, 4) (gross, or net with ``measurement="net"``) and its variance (k, 4);
        informative (k, 4) bool; slip_sigma (k, 4) each slip's 1-sigma; ``gate_slip`` /
        ``gate_sigma``: the smoothed slip and its 1-sigma the gate decides on (default: the raw);
        ``held`` (k, 4) bool: the wheel's speed or torque reading is stale (not a measurement now);
        ``identifiable`` (k,) bool: False when the sample has no independent ground speed."""
        cfg = self.cfg
        ix = check_index(idx, self.n_vehicles)
        k = ix.size
        stamp = np.asarray(stamp, dtype=float).reshape(k)
        slip, obs, var, s_sig = (np.asarray(a, dtype=float) for a in (slip, observed, variance, slip_sigma))
        for name, a in (("slip", slip), ("observed", obs), ("variance", var), ("slip_sigma", s_sig)):
            if a.shape != (k, 4) or not np.isfinite(a).all():
                raise ValueError(f"{name} must be a finite array of shape ({k}, 4), got {a!r}")
        g_slip = slip if gate_slip is None else np.asarray(gate_slip, dtype=float)
        g_sig = s_sig if gate_sigma is None else np.asarray(gate_sigma, dtype=float)
        # the gate decides on the smoothed slip (no selection bias from noise), but the slip the curve
        # is evaluated at must itself be away from zero: a fast reversal leaves the smoothed slip behind
        gated = (_gate(g_slip, np.asarray(informative, dtype=bool), cfg, g_sig) & (np.sign(g_slip) == np.sign(slip))
                 & (np.abs(slip) >= 0.5 * cfg.slip_min))
        # a wheel whose torque balance does not determine its gross traction cannot inform K (§12)
        determined = var <= cfg.observable_max_gross_sigma**2
        held = np.zeros((k, 4), dtype=bool) if held is None else np.asarray(held, dtype=bool)
        ident = np.ones(k, dtype=bool) if identifiable is None else np.asarray(identifiable, dtype=bool)
        use0 = gated & determined & ~held & ident[:, None]
        # two hypotheses per vehicle, stepped as rows 2i (configured scale) and 2i + 1 (fitted scale)
        ir = (2 * ix[:, None] + np.arange(2)).ravel()
        stamp, slip, obs, var, s_sig, use = (np.repeat(a, 2, axis=0) for a in (stamp, slip, obs, var, s_sig, use0))
        p, m, v = self.p[ir], self.m[ir], self.v[ir]
        last = self.last_stamp[ir]
        with np.errstate(invalid="ignore"):
            dt = stamp - last
            pred = ~np.isnan(last) & (dt > 0)
        if pred.any():
            p[pred], m[pred], v[pred] = self.grid.predict(p[pred], m[pred], v[pred], dt[pred], (ir % 2 == 1)[pred])
        self.last_stamp[ir] = stamp
        stats = self.stats[ir]
        decay = np.where(pred, np.exp(-np.where(pred, dt, 0.0) / cfg.evidence_window), 1.0)
        stats *= decay[:, None]
        info = np.zeros(2 * k, dtype=bool)
        rows = np.flatnonzero(use.any(axis=1))
        if rows.size:
            rr, ww = np.nonzero(use[rows])  # the used wheels, stacked: row (in rows) and wheel
            at = (rows[rr], ww)
            h, dh_ds = self.grid.curve(slip[at][:, None])  # (M, G)
            sig2 = var[at][:, None] + cfg.model_sigma**2 + (dh_ds * s_sig[at][:, None]) ** 2
            y = obs[at][:, None]
            nis = np.empty_like(h)
            pu, mu_, vu = p[rows], m[rows], v[rows]
            p_log = np.zeros_like(pu)
            for i in range(4):  # wheels in turn: those of an axle share its scale (soilocp.estimation.soil_grid)
                sel = np.flatnonzero(ww == i)
                if sel.size == rows.size:  # every row uses this wheel: work on the arrays themselves
                    nis[sel] = fuse_wheel(p_log, mu_, vu, AXLE[i], y[sel], h[sel], sig2[sel], cfg)
                elif sel.size:
                    r = rr[sel]
                    lp, mm, vv = p_log[r], mu_[r], vu[r]
                    nis[sel] = fuse_wheel(lp, mm, vv, AXLE[i], y[sel], h[sel], sig2[sel], cfg)
                    p_log[r], mu_[r], vu[r] = lp, mm, vv
            post = pu * np.exp(p_log - p_log.max(axis=1, keepdims=True))
            total = post.sum(axis=1)
            ok = (total > 0) & np.isfinite(total) & np.isfinite(mu_).all(axis=(1, 2)) & np.isfinite(vu).all(axis=(1, 2))
            good = rows[ok]
            p[good] = post[ok] / total[ok][:, None]
            m[good], v[good] = mu_[ok], psd(vu[ok])
            info[good] = True
            self._window_stats(stats, rows, rr, ok, p, h, dh_ds, sig2, nis, slip[at], dt)
        self.p[ir], self.m[ir], self.v[ir] = p, m, v
        self.stats[ir] = stats
        return self._summaries(ix, stamp[::2], p, m, v, info[::2], use0, gated & ~determined, gated & held, ident,
                               stats[::2])

    def _window_stats(self, stats, rows, rr, ok, p, h, dh_ds, sig2, nis, s_used, dt) -> None:
        """Accumulate the NIS at the posterior median and the radius budget's sums (class doc)."""
        G = self.theta.size
        cdf = np.cumsum(p[rows], axis=1) - 0.5 * p[rows]
        j = np.clip([int(np.searchsorted(c, 0.5)) for c in cdf], 1, G - 2)[rr]
        w = np.arange(rr.size)
        h_k = (h[w, j + 1] - h[w, j - 1]) / (2.0 * self.grid.dtheta)  # d h / d ln K at the median
        wt = 1.0 / sig2[w, j]
        ds = 1.0 - np.minimum(np.abs(s_used), 1.0)  # d S / d ln R_w (eq. 1, both slip signs)
        step = np.where(np.isnan(dt[rows]) | (dt[rows] <= 0) | ~ok, 0.0, np.minimum(dt[rows], 1.0))
        n_used = np.bincount(rr, minlength=rows.size)[rr]
        rows_w, step_w = rows[rr], step[rr]
        np.add.at(stats[:, 0], rows, step)
        np.add.at(stats[:, 1], rows_w, step_w * nis[w, j] / n_used)
        np.add.at(stats[:, 2], rows_w, step_w * wt * h_k**2)
        np.add.at(stats[:, 3], rows_w, step_w * wt * h_k * dh_ds[w, j] * ds)

    def _scales(self, p, m, v) -> tuple[np.ndarray, np.ndarray]:
        """The marginal mean and 1-sigma of each axle's gross-traction scale, (k, 2) each."""
        mean = np.einsum("kg,kag->ka", p, m)
        second = np.stack([np.einsum("kg,kg->k", p, v[:, 0] + m[:, 0] ** 2),
                           np.einsum("kg,kg->k", p, v[:, 2] + m[:, 1] ** 2)], axis=1)
        return mean, np.sqrt(np.maximum(second - mean**2, 0.0))

    def _summaries(self, ix, stamp, p, m, v, info, use, undetermined, held, ident, stats) -> list[SoilState]:
        """Per vehicle: K and its band from the configured-scale belief (rows 2j), widened by the
        distance to the fitted-scale belief's K (rows 2j + 1, docs/method.md §16), statuses, reasons."""
        cfg, k = self.cfg, ix.size
        cdf = np.cumsum(p, axis=1) - 0.5 * p
        c_mean, c_std = self._scales(p[1::2], m[1::2], v[1::2])
        out = []
        for j in range(k):
            hold = self._holds[int(ix[j])]
            st = float(stamp[j])
            if info[j]:
                hold.last_update = st
            k_med, _, log_stat = self.grid.summary(cdf[2 * j])
            k_fit, _, log_fit = self.grid.summary(cdf[2 * j + 1])
            # the data cannot tell a scale error from a different soil: the band must reach over the
            # fitted-scale belief too (its distance and its own spread, in quadrature)
            d_scale = math.hypot(math.log(k_med / k_fit), log_fit)
            evidence, nis_sum, s_kk, s_ks = stats[j]
            sys = cfg.radius_sigma * abs(s_ks) / s_kk if s_kk > 0 else 0.0
            log_std = math.sqrt(log_stat**2 + sys**2 + d_scale**2)
            k_std = k_med * math.sinh(log_std)
            status, reason, (rk, rs, rl) = hold.status(st, k_med, k_std, log_std)
            cm, cs = c_mean[j], c_std[j]
            scale_txt = f"front {cm[0]:.2f} +- {cs[0]:.2f}, rear {cm[1]:.2f} +- {cs[1]:.2f}"
            if status == "uncertain" and d_scale > max(log_stat, sys):
                reason = (f"ln K 1-sigma {log_std:.2f} > {cfg.uncertain_log_sigma}, mostly the torque scale: K = "
                          f"{k_med:.0f} at the configured torque constant and loads, {k_fit:.0f} if the gross traction "
                          f"is scaled by ({scale_txt}) as the traction curve's shape suggests; these data cannot "
                          "tell the two apart (docs/method.md §16)")
            elif status == "uncertain" and sys > log_stat:
                reason = (f"ln K 1-sigma {log_std:.2f}, mostly systematic: a {100 * cfg.radius_sigma:.0f} % "
                          "wheel-radius uncertainty moves K this much where the traction curve saturates")
            elif rk is not None and status in ("ok", "holding") and (np.abs(cm - 1.0) > np.maximum(2.0 * cs, 0.05)).any():
                reason = (reason + "; " if reason else "") + (
                    f"the traction curve's shape suggests a gross-traction scale of {scale_txt} (torque constant "
                    f"or mass / CoM differ from the configuration?); K at it: {k_fit:.0f} (docs/method.md §16)")
            nis = nis_sum / evidence if evidence > 0 else 0.0
            if not ident[j]:
                status = "not_observable"
                reason = ("not identifiable: no independent ground speed (slip, eq. 1, compares the wheel speed "
                          "with it; wheel odometry cannot stand in)")
            elif rk is not None and evidence >= cfg.mismatch_min_evidence and nis > cfg.mismatch_nis:
                status = "model_mismatch"
                reason = (f"the traction curve does not explain the (slip, gross traction) pairs: mean NIS {nis:.1f} "
                          f"> {cfg.mismatch_nis:g} over the last {cfg.evidence_window:g} s (torque scale, sensor or model)")
            elif rk is not None and cdf[2 * j][self._floor_idx] > 0.5:
                status = "model_mismatch"
                reason = (f"gross traction is below what the model's weakest soil gives at this slip (K under "
                          f"{self.k_floor:g}, half the weakest reference soil's): torque scale or units?")
            elif status in ("no_estimate", "holding") and held[j].any() and not use[j].any():
                status = "not_observable"
                reason = (f"slip is informative but the wheel speed / torque readings are held longer than "
                          f"{cfg.max_input_age:g} s (sensor refresh too slow to measure traction)")
            elif status in ("no_estimate", "holding") and undetermined[j].any() and not use[j].any():
                status = "not_observable"
                reason = "slip is informative but the wheel torque balance does not determine gross traction"
            if status == "not_observable":  # the data do not determine K now: no number (docs/method.md §12)
                rk = rs = rl = None
            cls = conf = None
            if rk is not None and status != "model_mismatch":
                # the class from the whole band (statistical and systematic), as reported
                cls, conf = classify(rk, rl, self.c)
            scale = scale_sd = None
            if hold.last_update is not None:
                scale, scale_sd = (float(cm[0]), float(cm[1])), (float(cs[0]), float(cs[1]))
            out.append(SoilState(rk, rs, rl, cls, conf, status, reason, hold.last_update,
                                 tuple(bool(u) for u in use[j]), scale, scale_sd))
        return out


class BayesSoilEstimator:
    """One vehicle's grid Bayes soil estimator: the kernel :class:`SoilBank` with N = 1."""

    def __init__(self, constants: ModelConstants = DEFAULT_CONSTANTS, config: SoilConfig | None = None):
        self.bank = SoilBank(constants, config, 1)
        self.c, self.cfg, self.grid = constants, self.bank.cfg, self.bank.grid
        self.theta, self.k_grid = self.grid.theta, self.grid.k_grid

    @property
    def p(self) -> np.ndarray:
        return self.bank.p[0]

    def update(self, stamp: float, slip, observed, variance, informative, slip_sigma=None,
               gate_slip=None, gate_sigma=None, held=None) -> SoilState:
        """Fuse one sample: arrays (4,) as :meth:`SoilBank.update` (``slip_sigma`` default
        ``cfg.slip_sigma``)."""
        slip, obs, var = _checked_quads(slip=slip, observed=observed, variance=variance)
        s_sig = np.full(4, self.cfg.slip_sigma) if slip_sigma is None else np.asarray(slip_sigma, dtype=float)
        one = (lambda a: None if a is None else np.asarray(a, dtype=float)[None])
        return self.bank.update(np.zeros(1, dtype=int), [stamp], slip[None], obs[None], var[None],
                                np.asarray(informative, dtype=bool)[None], s_sig[None], one(gate_slip), one(gate_sigma),
                                None if held is None else np.asarray(held, dtype=bool)[None])[0]


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
            # eq. 37 assumes |mu| grows with K: not so at small slip (docs/method.md §4); the curve is
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
