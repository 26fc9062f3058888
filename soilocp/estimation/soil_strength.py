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
  ln K) and mixes with a uniform hazard per metre travelled, so abrupt terrain changes are picked
  up within a fraction of a second of informative slip, and a robot that stands keeps its soil.
  K is reported from a second, no-change belief until the data take a change (the mixture's
  median leaves a learnt soil on the first weak samples after a hold: :meth:`SoilBank._report_median`),
  and the likelihood's slip term is evaluated at the belief's median, the same for every K.
  Working on a grid handles what an EKF cannot: mu(S, K) is not monotone in K at small slip, and
  above K ~ 300 the curve saturates (docs/method.md §9), which shows up as a wide posterior
  (status ``uncertain``), not false precision.  When slip carries no information
  (flat ground at cruise, standstill) nothing updates: the last estimate is held and flagged
  ``holding``, and after ``expire_after`` seconds it is withdrawn (``no_estimate``) — never a
  drifting number.

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
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives
from soilocp.estimation.soil_config import SoilConfig, SoilState, Status, class_bounds, classify, classify_many
from soilocp.estimation.soil_axles import AxleCheck
from soilocp.estimation.soil_grid import LogKGrid
from soilocp.estimation.wheel_usability import REASONS, SKID_TURN, describe

#: m/s: the speed the terrain-change hazard assumes when a caller gives none (a typical rover's)
UNKNOWN_SPEED = 1.0


def _checked_quads(**arrays) -> list[np.ndarray]:
    """Per-wheel float arrays of shape (4,), finite; one vectorised check on the happy path."""
    out = [np.asarray(v, dtype=float) for v in arrays.values()]
    if all(a.shape == (4,) for a in out) and np.isfinite(np.concatenate(out)).all():
        return out
    return [as_float_array(name, v, shape=(4,)) for name, v in arrays.items()]  # raises, naming the argument


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
            k, _, held_log = self.held
            if log_std is not None and held_log is not None:
                # a held band never narrower than the soil's own drift allows since the update (q_log_k per
                # sqrt(s)): the belief's spread widens with the change hazard per metre, and at a standstill
                # with the random walk only; the age is in the record (SoilState.held_for_s)
                log_std = max(log_std, math.hypot(held_log, cfg.q_log_k * math.sqrt(age)))
            k_std = k_std if k_std is None else max(k_std, self.held[1] or 0.0, k * math.sinh(log_std or 0.0))
        if age > cfg.hold_after:
            return "holding", f"slip uninformative for {age:.1f} s: holding the last estimate", (k, k_std, log_std)
        if log_std is not None and log_std > cfg.uncertain_log_sigma:
            return "uncertain", f"ln K 1-sigma {log_std:.2f} > {cfg.uncertain_log_sigma}: K poorly determined", (k, k_std, log_std)
        return "ok", "", (k, k_std, log_std)


class SoilBank:
    """N grid Bayes filters over ln K (the soil kernel; module doc), stepped together.

    Per vehicle it also keeps, over ``evidence_window`` seconds of informative samples:

    * the mean normalised residual (NIS) of the used wheels at the posterior median: when the
      traction curve cannot explain the (slip, traction) pairs at any K, the status is
      ``model_mismatch`` rather than a confident class;
    * the systematic part of K's error budget: a gross-traction scale error c (the torque constant;
      prior 1-sigma ``gross_scale_sigma``) and a wheel-radius error (``radius_sigma``) are common to
      every sample, so they do not average out like noise.  The scale's effect on ln K is propagated
      exactly through the curve, under c's posterior given the window's samples
      (:meth:`_scale_shift`); the radius's is the linearised weighted least-squares shift
      d lnK = eps sum(w h_K h_S dS/dlnR) / sum(w h_K^2).  Both add in quadrature to the belief's own
      spread.  The window restarts when a change is taken: its samples are the current soil's;
    * a front-only and a rear-only belief (:class:`soilocp.estimation.soil_axles.AxleCheck`): when
      the axles read different soils the normal forces are off (``model_mismatch``, docs/method.md
      §16), and their distance in ln K joins the systematic part of the band.
    """

    def __init__(self, constants: ModelConstants, config: SoilConfig | None, n_vehicles: int):
        self.c = constants
        self.cfg = cfg = config or SoilConfig()
        if cfg.method != "bayes":
            raise ValueError(f"soil method {cfg.method!r}: the soil kernel implements 'bayes' only")
        self.n_vehicles = n = check_count(n_vehicles)
        self.grid = LogKGrid(constants, cfg)
        self.theta, self.k_grid = self.grid.theta, self.grid.k_grid
        self.p = np.full((n, cfg.grid_points), 1.0 / cfg.grid_points)
        # the belief that the soil has not changed since the change last taken, that hypothesis'
        # posterior probability, and the data's recent log-evidence for it against the pooled belief
        # (_report_median)
        self.p_stay = self.p.copy()
        self.w_stay = np.ones(n)
        self.stay_llr = np.zeros(n)
        self._holds = [_HoldLogic(cfg) for _ in range(n)]
        # half the weakest reference soil's K: the traction constants were fitted on soils from there
        # up; a belief mostly below it is an extrapolation that a wrong torque scale produces, not a soil
        self.k_floor = math.exp(class_bounds(constants)[1][0])
        self._floor_idx = int(np.searchsorted(self.k_grid, self.k_floor))
        self.last_stamp = np.full(n, np.nan)
        # window statistics: evidence (s of informative samples), NIS sum, and the sums of the
        # systematic budget: sum w h_K^2, sum w h_K h, sum w h_K h_S dS
        self.stats = np.zeros((n, 5))
        # the same window's weighted sums per node for the scale profile (_scale_shift): sum w obs h(theta)
        # and sum w h(theta)^2
        self.profile = np.zeros((n, 2, cfg.grid_points))
        # _scale_shift of the last informative sample (no new data, no new value): the systematic 1-sigma of
        # ln K, and the scale's posterior mean and 1-sigma
        self.scale_sys = np.tile([0.0, 1.0, cfg.gross_scale_sigma], (n, 1))
        # _scale_shift's nodes of the common scale c over +-4 sigma, and their log prior N(1, gross_scale_sigma)
        self._scale_c = 1.0 + cfg.gross_scale_sigma * np.linspace(-4.0, 4.0, 25)
        self._scale_log_prior = -0.5 * np.linspace(-4.0, 4.0, 25) ** 2
        self._lean_since = np.full(n, np.nan)  # stamp since which the data lean to a wrong torque constant
        self.scale_prior = np.full(n, cfg.gross_scale_sigma)  # the scale's 1-sigma: the prior, or the online state's
        self.axles = AxleCheck(self.grid, cfg, n)  # front-only and rear-only beliefs (normal-force check)
        #: wheel-samples the longitudinal model did not describe, by wheel_usability's reason (the health counters)
        self.unusable_by_reason: dict[str, int] = {r: 0 for r in REASONS if r}


    def start_belief(self, i: int, log_k: float, log_k_std: float, floor: float = 1e-3) -> None:
        """Start vehicle i's belief over again from N(log_k, log_k_std^2) on the grid, with a uniform
        ``floor`` (the fleet map's cell and its band, opt-in: soilocp.map.prior, docs/map.md)."""
        g = np.exp(-0.5 * ((self.theta - log_k) / max(log_k_std, 1e-3)) ** 2)
        g = (1.0 - floor) * g / g.sum() + floor / g.size
        self.p[i], self.p_stay[i], self.w_stay[i], self.stay_llr[i] = g, g, 1.0, 0.0
        self.stats[i], self.profile[i] = 0.0, 0.0  # the evidence window restarts, as when a change is taken

    def update(self, idx, stamp, slip, observed, variance, informative, slip_sigma, gate_slip=None,
               gate_sigma=None, held=None, identifiable=None, speed=None, ground_stale=None,
               span=None, slip_ends=None, scale_sigma=None, unusable=None) -> list[SoilState]:
        """Fuse one sample per vehicle in ``idx``: stamp (k,) [s]; slip (k, 4) (eq. 1); observed
        coefficient (k, 4) (gross, or net with ``measurement="net"``) and its variance (k, 4);
        informative (k, 4) bool; slip_sigma (k, 4) each slip's 1-sigma; ``gate_slip`` /
        ``gate_sigma``: the smoothed slip and its 1-sigma the gate decides on (default: the raw);
        ``held`` (k, 4) bool: the wheel's speed or torque reading is stale (not a measurement now);
        ``identifiable`` (k,) bool: False when the sample has no independent ground speed;
        ``speed`` (k,) m/s: the vehicle's ground speed, which sets the distance over which the soil
        may have changed since the last sample (None: ``UNKNOWN_SPEED``, m/s); ``ground_stale`` (k,)
        bool: the ground speed's last reading is older than ``max_input_age`` (no wheel informs K,
        and the reason names the ground speed, not the wheels' readings); ``span`` (k, 4) s: a pair that
        stands for a longer interval than the sample's own (a slow wheel-speed or torque stream's refresh,
        :mod:`soilocp.estimation.refresh_traction`) weighs that interval's exponent, at most 1; 0 or None:
        the sample's;
        ``slip_ends`` (k, 4, 2): such a pair's slip at its interval's start and end: its mean gross traction
        is compared with the curve averaged over that slip path (Simpson's rule); ``scale_sigma`` (k,) or None:
        the torque scale's relative 1-sigma now (the online state, :mod:`soilocp.estimation.torque_scale`,
        whose mean the torques already carry), instead of the prior ``gross_scale_sigma``; ``unusable`` (k, 4)
        int: a wheel the longitudinal model does not describe now (:mod:`soilocp.estimation.wheel_usability`'s
        code, 0: usable): it informs no K, the record is never ``ok`` and says why, and the code is counted
        (:attr:`unusable_by_reason`)."""
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
        stale = np.zeros(k, dtype=bool) if ground_stale is None else np.asarray(ground_stale, dtype=bool).reshape(k)
        held = held | stale[:, None]
        ident = np.ones(k, dtype=bool) if identifiable is None else np.asarray(identifiable, dtype=bool)
        use = gated & determined & ~held & ident[:, None]
        codes = None
        if unusable is not None:
            codes = np.asarray(unusable).reshape(k, 4)
            if codes.any():
                use &= codes == 0
                for c, n in zip(*np.unique(codes[codes > 0], return_counts=True)):
                    self.unusable_by_reason[REASONS[int(c)]] += int(n)
            else:
                codes = None
        p, p_stay, w_stay, stay_llr = self.p[ix], self.p_stay[ix], self.w_stay[ix], self.stay_llr[ix]
        last = self.last_stamp[ix]
        with np.errstate(invalid="ignore"):
            dt = stamp - last
            pred = ~np.isnan(last) & (dt > 0)
        if pred.any():
            v = (np.full(k, UNKNOWN_SPEED) if speed is None
                 else np.abs(np.nan_to_num(np.asarray(speed, dtype=float).reshape(k), nan=UNKNOWN_SPEED)))
            # the pooled beliefs, the no-change beliefs (diffusion, no change prior: no distance) and both axles'
            # (soil_axles) in one prediction: rows m, m, then 2m
            m, ixp = int(pred.sum()), ix[pred]
            dist = v[pred] * dt[pred]
            rows = self.grid.predict(np.concatenate([p[pred], p_stay[pred], self.axles.beliefs(ixp)]),
                                     np.concatenate([dt[pred], dt[pred], np.repeat(dt[pred], 2)]),
                                     np.concatenate([dist, np.zeros(m), np.repeat(dist, 2)]))
            p[pred], p_stay[pred] = rows[:m], rows[m:2 * m]
            hz = np.minimum(cfg.change_per_metre * dist, 1.0)
            w_stay[pred] *= 1.0 - hz  # P(no change over this step)
            if cfg.stay_forgetting > 0:  # _report_median: the no-change belief's memory
                q = np.maximum(p_stay[pred], 1e-300) ** (1.0 - cfg.stay_forgetting * hz)[:, None]
                p_stay[pred] = q / q.sum(axis=1, keepdims=True)
            self.axles.set_beliefs(ixp, rows[2 * m:])
        self.last_stamp[ix] = stamp
        stats = self.stats[ix]
        decay = np.where(pred, np.exp(-np.where(pred, dt, 0.0) / cfg.evidence_window), 1.0)
        stats *= decay[:, None]
        prof = self.profile[ix]
        prof *= decay[:, None, None]
        info = np.zeros(k, dtype=bool)
        upd = use.any(axis=1)
        exponent = self._exponent(dt, pred)
        if upd.any():
            u = use[upd]
            # the likelihood of the used wheels only, (m, G); the unused get a factor of exactly 1
            s_used = slip[upd][u][:, None]
            h, dh_ds = self.grid.curve(s_used)
            if slip_ends is not None and span is not None:
                # a refresh interval's pair: its mean gross traction against the curve averaged over the
                # interval's slip path, start -> end (refresh_traction), by Simpson's rule on the path's middle
                ends = np.asarray(slip_ends, dtype=float)[upd][u]
                path = (np.asarray(span, dtype=float)[upd][u] > 0) & np.isfinite(ends).all(axis=1)
                if path.any():
                    h0, d0 = self.grid.curve(ends[path, 0, None])
                    h1, d1 = self.grid.curve(ends[path, 1, None])
                    h[path] = (h0 + 4.0 * h[path] + h1) / 6.0
                    dh_ds[path] = (d0 + 4.0 * dh_ds[path] + d1) / 6.0
            # the product over a row's used wheels as a sum of logs; the used pairs are stacked row by row
            n_used = u.sum(axis=1)
            starts = np.concatenate([[0], np.cumsum(n_used)[:-1]])  # first used pair of each row
            # the slip term of the variance at the prior belief's median, the same for every K (docs/method.md
            # §9, quasi-likelihood): evaluated per K, (dh/dS sigma_S)^2 would make the variance depend on K,
            # and with stated variances above the real scatter (observer gross 1-sigma 0.05 against 0.008
            # measured) 1/sqrt(sig2(K)) pulls K towards the flattest curve at every sample
            # (sweep-12s-0.1: firm 300 read 235)
            ref = self.grid.median_nodes(np.cumsum(p[upd], axis=1) - 0.5 * p[upd])
            dh_ref = dh_ds[np.arange(dh_ds.shape[0]), np.repeat(ref, n_used)][:, None]
            sig2 = np.broadcast_to(var[upd][u][:, None] + cfg.model_sigma**2 + (dh_ref * s_sig[upd][u][:, None]) ** 2,
                                   h.shape)
            r2 = (obs[upd][u][:, None] - h) ** 2 / sig2
            like_used = (1 - cfg.outlier_prob) * np.exp(-0.5 * r2) / np.sqrt(sig2) + cfg.outlier_prob
            # each pair's exponent: its vehicle's per sample, or its own refresh interval's (span), at most 1:
            # one pair is one observation at its stated variance (with the whole interval's 3.2 at 4.7 Hz, one
            # pair across a sweep's kink moved K from 200 to 70)
            exp_used = np.repeat(exponent[upd], n_used)
            span_used = None
            if span is not None:
                span_used = np.asarray(span, dtype=float)[upd][u]
                exp_used = np.where(span_used > 0, np.minimum(cfg.temper * span_used / cfg.temper_interval, 1.0), exp_used)
            loglike_used = np.log(like_used) * exp_used[:, None]
            loglike = np.add.reduceat(loglike_used, starts, axis=0)
            pair_row, pair_wheel = np.nonzero(u)  # row-major: the order the used pairs are stacked in
            self.axles.update(ix[upd], stamp[upd], pair_row, pair_wheel, loglike_used)
            like = np.exp(loglike - loglike.max(axis=1, keepdims=True))
            post, post_stay = p[upd] * like, p_stay[upd] * like
            total, total_stay = post.sum(axis=1), post_stay.sum(axis=1)
            ok = (total > 0) & np.isfinite(total)
            rows = np.flatnonzero(upd)[ok]
            p[rows] = post[ok] / total[ok][:, None]
            # Bayes on the two hypotheses: P(no change | data) = P(no change) x Z_stay / Z_pooled
            w_stay[rows] = np.clip(w_stay[rows] * total_stay[ok] / total[ok], 0.0, 1.0)
            # and the data's own say, ln Z_stay / Z_pooled, over the last change_evidence s of informative samples
            if cfg.change_evidence > 0:
                fade = np.exp(-np.where(pred, np.minimum(dt, 1.0), 0.0)[rows] / cfg.change_evidence)
                stay_llr[rows] = stay_llr[rows] * fade + np.log(np.maximum(total_stay[ok], 1e-300) / total[ok])
            fine = total_stay[ok] > 0  # else the data exclude the no-change belief: w is 0, taken below
            p_stay[rows[fine]] = post_stay[ok][fine] / total_stay[ok][fine][:, None]
            info[rows] = True
        cdf = np.cumsum(p, axis=1) - 0.5 * p  # mid-point CDF of every belief after this sample
        k_report, taken = self._report_median(p, p_stay, w_stay, stay_llr, cdf)
        # a change taken: the window's mismatch and systematic statistics were gathered on the old soil,
        # and would judge the new estimate by it for evidence_window seconds (the robustness drive's firm
        # segment: the scale profile still read 250 for 300 five seconds after the change)
        stats[taken] = 0.0
        prof[taken] = 0.0
        if upd.any():
            self._window_stats(stats, prof, np.flatnonzero(upd), n_used, starts, cdf, h, dh_ds, r2, sig2, s_used[:, 0],
                               obs[upd][u], dt, exp_used, span_used)
        self.p[ix], self.p_stay[ix], self.w_stay[ix], self.stay_llr[ix] = p, p_stay, w_stay, stay_llr
        self.stats[ix], self.profile[ix] = stats, prof
        if scale_sigma is not None:
            self.scale_prior[ix] = np.asarray(scale_sigma, dtype=float).reshape(k)
        fresh = np.flatnonzero(upd | taken)
        if fresh.size:
            self.scale_sys[ix[fresh]] = self._scale_shift(prof[fresh], None if scale_sigma is None
                                                          else self.scale_prior[ix[fresh]])
        return self._summaries(ix, stamp, cdf, info, use, gated & ~determined, gated & held, stale, ident, stats,
                               dt, k_report, self.scale_sys[ix], codes)

    def _report_median(self, p, p_stay, w_stay, stay_llr, cdf) -> tuple[np.ndarray, np.ndarray]:
        """The K each vehicle reports (k,), and whether a change was taken now (k,) bool: the median of
        the no-change belief until the data take a change, then the pooled belief's (docs/method.md §9,
        "Reporting across a possible change").

        The pooled belief p is a mixture: the soil is still the one learnt, or it changed (the hazard
        per metre mixes in the uniform change prior).  After a stretch without informative slip the
        change part holds much of the mass, and the first weakly informative samples place it where
        the curve is flat in K, so the mixture's median leaves a well-learnt K for samples that do not
        contradict it (sweep-6s-0.3: firm 300 read 355 for 0.2 s after a 1.5 s hold).  Beside it runs the
        no-change belief p_stay (the same likelihood; diffusion and ``stay_forgetting``, no change
        prior) and the posterior probability of that hypothesis, w = P(no change | data) =
        P(no change) x Z_stay / Z_pooled: the hazard lowers the prior with distance, each informative
        sample multiplies by the ratio of the two beliefs' evidence.  A change is taken when it is the
        more probable hypothesis (w < 1/2) and the data themselves favour it: ``stay_llr``, the sum of
        ln Z_stay / Z_pooled over the last ``change_evidence`` seconds of informative samples, is
        negative (distance alone, a hold, takes no change).  Then p_stay restarts from p (w = 1) and
        p's median is reported, where the mixture's median goes anyway once a new soil dominates it.
        ``change_evidence`` 0 reports p's median always (and takes no change).  The band is always p's:
        it includes the chance of a change.  p_stay, w_stay and stay_llr are updated in place."""
        if self.cfg.change_evidence > 0:
            changed = taken = (w_stay < 0.5) & (stay_llr < 0.0)
        else:
            changed, taken = np.ones(p.shape[0], dtype=bool), np.zeros(p.shape[0], dtype=bool)
        if changed.any():
            p_stay[changed] = p[changed]
            w_stay[changed] = 1.0
            stay_llr[changed] = 0.0
        cdf_stay = np.cumsum(p_stay, axis=1) - 0.5 * p_stay
        return np.exp(self.grid.medians(np.where(changed[:, None], cdf, cdf_stay))), taken

    def _exponent(self, dt, pred) -> np.ndarray:
        """Each vehicle's likelihood exponent (k,) for a sample ``dt`` s after its previous one (docs/method.md
        §9, "Information per second"): temper x dt / temper_interval, at most temper_max; temper itself where
        no interval is known (a first sample, a stamp repeated or gone backwards).

        The observer's gross traction error is nearly white at 100 and 200 Hz (lag-one r -0.16..0.12 on the
        nominal drive) around a per-wheel bias of 0.003-0.007 that no number of samples averages out, so what
        a second of samples says about K is the same at any rate: per sample it scales with the interval.  At
        low rates the error grows (1-sigma 0.025-0.037 at 20 Hz against 0.015) and is correlated with the next
        sample's (r 0.24-0.42), so a sample is worth (1 - r) / (1 + r) ~ 0.43 of its interval's share:
        0.75 x 0.43 ~ 0.3 at 20 Hz, ``temper_max``.  A fixed exponent per sample made a 20 Hz log learn a
        fifth as fast as a 100 Hz one (rate-20hz ln K band 0.154 against 0.096), a 200 Hz log twice as fast."""
        cfg = self.cfg
        step = np.where(pred, dt, cfg.temper_interval)
        return np.minimum(cfg.temper * step / cfg.temper_interval, cfg.temper_max)

    def _window_stats(self, stats, prof, rows, n_used, starts, cdf, h, dh_ds, r2, sig2, s_used, obs_used, dt,
                      exponent, span=None) -> None:
        """Accumulate the NIS at the posterior median, the systematic budget's sums (class doc) and the
        scale profile's per-node sums (:meth:`_scale_shift`, weighted as the belief weighs the samples:
        ``exponent`` (pairs,) / variance); ``span`` (pairs,) or None: the s a refresh interval's pair stands
        for (0: the sample's own interval); ``cdf``: the updated beliefs' mid-point CDF; the used pairs are
        stacked row by row, row i's from ``starts[i]``.  ``rows`` are distinct (one sample per vehicle and
        call), so the per-row sums are plain fancy-index adds."""
        G = self.theta.size
        which = np.repeat(np.arange(rows.size), n_used)  # wheel -> row in rows
        j = self.grid.median_nodes(cdf[rows], 1, G - 2)[which]  # the posterior median's node (central differences)
        w = np.arange(which.size)
        nis = r2[w, j]
        h_k = (h[w, j + 1] - h[w, j - 1]) / (2.0 * self.grid.dtheta)  # d h / d ln K at the median
        wt = 1.0 / sig2[w, j]
        ds = 1.0 - np.minimum(np.abs(s_used), 1.0)  # d S / d ln R_w (eq. 1, both slip signs)
        step = np.where(np.isnan(dt[rows]) | (dt[rows] <= 0), 0.0, np.minimum(dt[rows], 1.0))
        step_w = step[which]
        if span is not None:  # a refresh interval's pair stands for its interval (refresh_traction)
            step_w = np.where(span > 0, np.minimum(span, 1.0), step_w)
            step = np.maximum.reduceat(step_w, starts)
        stats[rows, 0] += step
        per_wheel = np.stack([step_w * nis / n_used[which], step_w * wt * h_k**2, step_w * wt * h_k * h[w, j],
                              step_w * wt * h_k * dh_ds[w, j] * ds], axis=1)
        stats[rows, 1:] += np.add.reduceat(per_wheel, starts, axis=0)
        # per sample, as the belief weighs them (its exponent / variance); sig2 is the same for every K
        # (quasi-likelihood, update): one weight per used wheel
        wt_pair = exponent / sig2[:, 0]
        wh = wt_pair[:, None] * h
        prof[rows, 0] += np.add.reduceat(wh * obs_used[:, None], starts, axis=0)
        prof[rows, 1] += np.add.reduceat(wh * h, starts, axis=0)

    def _scale_shift(self, prof, sigma=None) -> np.ndarray:
        """The systematic 1-sigma of ln K from a scale error c common to every observed coefficient (the
        torque constant), and c's posterior mean and 1-sigma: (k, 3) (docs/method.md §9, "The band").

        A torque constant off by c makes every observed gross traction c x the true one.  The curve's
        amplitude is a function of K alone (eq. 3), so on driving wheels c and K trade off; a braking
        wheel's gross traction carries the motion resistance twice (eq. 4, even in S: §11), which does
        not scale with the amplitude, so a drive that brakes one axle tells c apart in part.  Over the
        window (``prof`` (k, 2, G): S_oh(theta) = sum w obs h(theta) and S_hh(theta) = sum w h(theta)^2,
        on the current soil's samples: reset when a change is taken) the misfit of obs = c h(theta) is

            M(c) = min_theta  sum w obs^2 - 2 c S_oh(theta) + c^2 S_hh(theta),   at theta*(c)

        (sum w obs^2 is the same for every c and drops out).

        c gets the prior N(1, ``gross_scale_sigma``) and the likelihood exp(-M(c) / 2), with w the belief's
        own weight of a sample (its exponent / variance, :meth:`_exponent`), on nodes over +-4 sigma.  The
        systematic 1-sigma is the root mean square of theta*(c) - theta*(1) under that posterior: exact
        through the curve (where it saturates, K >~ 300 (§9), a small c sends theta* to the grid's end and
        the band says K is undetermined upwards), and narrow where the data exclude a scale error.  A linearised
        sensitivity at the estimate (d ln K = eps sum w h_K h / sum w h_K^2, earlier releases)
        understated it on both sides: torque-10 read firm 300 as 203 with a 1-sigma of 0.14,
        torque+10 as 1009 with 0.26; without the data's say (the prior's +-2 sigma alone), nominal firm
        soil's band reached 300..1300.  ``sigma`` (k,): each vehicle's scale 1-sigma (the online torque scale's
        posterior) instead of ``gross_scale_sigma``."""
        if sigma is not None:
            return self._scale_shift_each(prof, np.asarray(sigma, dtype=float))
        if self.cfg.gross_scale_sigma <= 0:
            return np.tile([0.0, 1.0, 0.0], (prof.shape[0], 1))
        c = self._scale_c
        cc = c[None, :, None]
        misfit = cc * (cc * prof[:, None, 1] - 2.0 * prof[:, None, 0])  # (k, C, G), less sum w obs^2 (the same for every c)
        theta, m = self._profile_argmin(misfit)
        log_post = self._scale_log_prior - 0.5 * m
        post = np.exp(log_post - log_post.max(axis=1, keepdims=True))
        post /= post.sum(axis=1, keepdims=True)
        shift2 = (theta - theta[:, c.size // 2, None]) ** 2  # against c = 1
        c_mean = post @ c
        out = np.stack([np.sqrt((post * shift2).sum(axis=1)), c_mean,
                        np.sqrt(np.maximum(post @ c**2 - c_mean**2, 0.0))], axis=1)
        # no samples in the window: every c fits alike, theta* is the grid's first node: no term
        out[~prof[:, 1].any(axis=1)] = (0.0, 1.0, self.cfg.gross_scale_sigma)
        return out

    def _scale_shift_each(self, prof, sigma: np.ndarray) -> np.ndarray:
        """:meth:`_scale_shift` with a 1-sigma per vehicle (k,): the nodes 1 + sigma z, the same prior in z."""
        z = np.linspace(-4.0, 4.0, self._scale_c.size)
        c = 1.0 + sigma[:, None] * z[None, :]  # (k, C)
        cc = c[:, :, None]
        misfit = cc * (cc * prof[:, None, 1] - 2.0 * prof[:, None, 0])
        theta, m = self._profile_argmin(misfit)
        log_post = self._scale_log_prior - 0.5 * m
        post = np.exp(log_post - log_post.max(axis=1, keepdims=True))
        post /= post.sum(axis=1, keepdims=True)
        shift2 = (theta - theta[:, z.size // 2, None]) ** 2
        c_mean = (post * c).sum(axis=1)
        out = np.stack([np.sqrt((post * shift2).sum(axis=1)), c_mean,
                        np.sqrt(np.maximum((post * c**2).sum(axis=1) - c_mean**2, 0.0))], axis=1)
        empty = ~prof[:, 1].any(axis=1)
        out[empty] = np.stack([np.zeros(empty.sum()), np.ones(empty.sum()), sigma[empty]], axis=1)
        out[sigma <= 0] = (0.0, 1.0, 0.0)
        return out

    def _profile_argmin(self, f) -> tuple[np.ndarray, np.ndarray]:
        """ln K at the least ``f`` (..., G) along the last axis, and that least value, both refined by the
        parabola through the nodes around it (the grid's end: its last interior node +- half a step).

        Values within 1e-9 of the least (relative) are ties, and the lowest ln K among them is
        taken: where the curve saturates (K >~ 1000, §9) a scaled profile is flat to 1e-14, and the plain
        argmin picked a node in that plateau by rounding (firm 300 with c <= 0.9: any of K 3000-5000, so
        the band moved by 5 % when the same sums were added in another order)."""
        G = f.shape[-1]
        flat = f.reshape(-1)
        low = f.min(axis=-1, keepdims=True)
        least = np.argmax(f <= low + 1e-9 * np.abs(low), axis=-1)  # the first of the ties (a plateau lies at the least)
        i = np.minimum(np.maximum(least, 1), G - 2)  # (np.clip costs 15 us on small arrays)
        at = (np.arange(i.size) * G + i.reshape(-1)).reshape(i.shape)  # flat index of each row's least node
        y0, y1, y2 = flat[at - 1], flat[at], flat[at + 1]
        curv = y0 - 2.0 * y1 + y2
        with np.errstate(divide="ignore", invalid="ignore"):
            off = np.minimum(np.maximum(np.where(curv > 0, 0.5 * (y0 - y2) / curv, 0.0), -0.5), 0.5)
        return self.theta[i] + off * self.grid.dtheta, y1 - 0.25 * (y0 - y2) * off

    def _vouch(self, v: int, stamp: float, evidence: float, c_mean: float) -> tuple[Status, str]:
        """Status and reason of an estimate whose band is narrow enough for ``ok``: ``ok`` only where its own
        checks vouch for it (docs/robustness.md, "ok means ok"), else ``uncertain`` naming what they lack.

        * the data lean to a torque scale the state does not assume (``_lean_since``: the window's scale
          posterior more than 2 of its sigmas, and more than the scale's own prior, from 1): a common scale
          and K trade off on a driving wheel (eq. 3), so K is limited by the torque scale whatever its
          statistical band (payload +25 % at constant speed: sand 50 read 67-73, ln K 1-sigma 0.16-0.18);
        * the front and rear axles read different soils for most of the window (the axle check's verdict,
          :mod:`soilocp.estimation.soil_axles`), though one axle is not informing now, so it is not judged now
          (mass-com+20: K 130-136 for 200 from the rear axle alone, ln K 1-sigma 0.09, between two
          ``model_mismatch`` stretches);
        * fewer than ``mismatch_min_evidence`` s of informative samples since the evidence window restarted
          (a change taken, the drive's start) or faded (a hold): the mismatch and axle checks have not had the
          data to judge the estimate yet (a change taken while the axles straddle two soils reads a K between
          them, ln K 1-sigma 0.12: skid-arcs, sand 50 / firm 300 read 122)."""
        cfg, ax = self.cfg, self.axles
        if not np.isnan(self._lean_since[v]) and self._lean_since[v] <= stamp:
            return "uncertain", (f"these data lean to a torque scale of {c_mean:.2f} (1 +- {self.scale_prior[v]:.2f} "
                                 "assumed): K is limited by the torque scale, which a drive at constant speed cannot "
                                 "tell apart from K (accelerate or brake, or soilocp calibrate-torque)")
        enough = 1.0 - math.exp(-cfg.mismatch_min_evidence / cfg.evidence_window)
        if cfg.axle_mismatch_z > 0 and ax.weight[v] >= enough and ax.over[v] > 0.5 * ax.weight[v]:
            return "uncertain", (f"the front and rear axles read different soils for most of the last "
                                 f"{cfg.evidence_window:g} s (one axle does not inform K now): the normal forces (mass, "
                                 "centre of mass) or an axle's torque constant may be off")
        if evidence < cfg.mismatch_min_evidence:
            return "uncertain", (f"K from {evidence:.1f} s of informative slip since the last change or hold: the "
                                 f"model checks need {cfg.mismatch_min_evidence:g} s before the estimate is ok")
        return "ok", ""

    def _summaries(self, ix, stamp, cdf, info, use, undetermined, held, stale, ident, stats, dt, k_report,
                   scale_shift, codes=None) -> list[SoilState]:
        """Per vehicle: K (``k_report``, :meth:`_report_median`) and its band from the pooled belief's
        mid-point CDF ``cdf``, status and reason; ``codes`` (k, 4): the wheels the longitudinal model does
        not describe now (:func:`_out_of_model`)."""
        cfg, k = self.cfg, ix.size
        out, rep = [], []  # rep: (vehicle, K, ln K 1-sigma) of the states that report a class
        for j in range(k):
            v = int(ix[j])
            hold = self._holds[v]
            st = float(stamp[j])
            if info[j]:
                hold.last_update = st
            _, _, log_stat = self.grid.summary(cdf[j])
            k_med = float(k_report[j])
            evidence, nis_sum, s_kk, s_kh, s_ks = stats[j]
            sens = abs(s_kh) / s_kk if s_kk > 0 else 0.0  # d ln K per relative gross-traction scale
            sys_scale, c_mean, c_std = scale_shift[j].tolist()  # exact, on the current data (_scale_shift)
            # how long the data have leant to a wrong torque constant: a window that spans two soils leans
            # too, briefly (the nominal drive's 300 -> 100: to 0.90 for 0.3 s before the change is taken)
            if abs(c_mean - 1.0) <= max(2.0 * c_std, self.scale_prior[v]):
                self._lean_since[v] = np.nan
            elif not self._lean_since[v] <= st:  # none yet (NaN), or a restarted clock: it starts now
                self._lean_since[v] = st
            sys_radius = cfg.radius_sigma * abs(s_ks) / s_kk if s_kk > 0 else 0.0
            axle_off, axle_z, theta_front, theta_rear = self.axles.judge(v, st, float(dt[j]),
                                                                         cfg.axle_scale_sigma * sens)
            # axles that disagree: the truth is usually near one of them (soil_axles), so their distance
            # is a systematic term.  Where the curve is flat in K (K >> 300, §9) a scale error moves K
            # without bound: the band is capped at the grid's whole ln K span ("undetermined")
            sys_axle = abs(theta_front - theta_rear) if axle_off else 0.0
            sys = min(math.hypot(math.hypot(sys_scale, sys_radius), sys_axle), self.grid.span)
            log_std = min(math.hypot(log_stat, sys), self.grid.span)
            k_std = k_med * math.sinh(log_std)
            status, reason, (rk, rs, rl) = hold.status(st, k_med, k_std, log_std)
            if status == "uncertain" and sys > log_stat and sys_scale >= sys_radius:
                # the data's scale without its posterior spread: across drives it moves by more than that
                # spread (nominal: 0.98-1.05 for 1.00, 1-sigma 0.03; docs/robustness.md)
                reason = (f"ln K 1-sigma {log_std:.2f}, mostly systematic: the torque scale (1 +- "
                          f"{self.scale_prior[v]:.2f} assumed; these data lean to {c_mean:.2f}) moves K this much "
                          "where the traction curve is flat in K")
                if st - self._lean_since[v] >= cfg.evidence_window:
                    reason += "; the data suggest a wrong torque constant: soilocp calibrate-torque"
            elif status == "uncertain" and sys > log_stat:
                reason = (f"ln K 1-sigma {log_std:.2f}, mostly systematic: a {100 * cfg.radius_sigma:g} % wheel-radius "
                          "uncertainty moves these small slips, and K, this much")
            nis = nis_sum / evidence if evidence > 0 else 0.0
            if not ident[j]:
                status = "not_observable"
                reason = ("not identifiable: no independent ground speed (slip, eq. 1, compares the wheel speed "
                          "with it; wheel odometry cannot stand in)")
            elif rk is not None and axle_off:
                status = "model_mismatch"
                reason = (f"the front and rear axles read different soils (K {math.exp(theta_front):.0f} front, "
                          f"{math.exp(theta_rear):.0f} rear; {axle_z:.1f} sigma apart, and most of the last "
                          f"{cfg.evidence_window:g} s): the normal forces (mass, centre of mass) or an axle's torque "
                          "constant are off")
            elif rk is not None and evidence >= cfg.mismatch_min_evidence and nis > cfg.mismatch_nis:
                status = "model_mismatch"
                reason = (f"the traction curve does not explain the (slip, gross traction) pairs: mean NIS {nis:.1f} "
                          f"> {cfg.mismatch_nis:g} over the last {cfg.evidence_window:g} s (torque scale, sensor or model)")
            elif rk is not None and cdf[j][self._floor_idx] > 0.5:
                status = "model_mismatch"
                reason = (f"gross traction is below what the model's weakest soil gives at this slip (K under "
                          f"{self.k_floor:g}, half the weakest reference soil's): torque scale or units?")
            elif status in ("no_estimate", "holding") and held[j].any() and not use[j].any():
                status = "not_observable"
                since = f"for {st - hold.last_update:.1f} s" if hold.last_update is not None else "yet"
                if stale[j]:
                    reason = (f"slip is informative but the ground speed is stale: no new reading for more than "
                              f"{cfg.max_input_age:g} s, no K update {since} (slip, eq. 1, needs a measured ground speed)")
                else:
                    reason = (f"slip is informative but the wheel speed / torque readings are held: no new reading of "
                              f"both {since} (sensor refresh too slow to measure traction)")
            elif status in ("no_estimate", "holding") and undetermined[j].any() and not use[j].any():
                status = "not_observable"
                reason = "slip is informative but the wheel torque balance does not determine gross traction"
            if status == "ok":
                status, reason = self._vouch(v, st, evidence, c_mean)
            if codes is not None and ident[j] and codes[j].any():
                status, reason = _out_of_model(status, reason, codes[j], use[j].any(), rk is not None, hold, st)
            if status == "not_observable":  # the data do not determine K now: no number (docs/method.md §12)
                rk = rs = rl = None
            if rk is not None and status != "model_mismatch":
                rep.append((j, rk, rl))
            held_for = None if rk is None or hold.last_update is None else max(st - hold.last_update, 0.0)
            out.append([rk, rs, rl, None, None, status, reason, hold.last_update, tuple(use[j].tolist()), held_for,
                        tuple(REASONS[int(c)] for c in codes[j]) if codes is not None else ("",) * 4])
        if rep:  # the class from the whole band (statistical and systematic), as reported
            js, ks, ls = zip(*rep)
            names, conf = classify_many(np.log(ks), np.array(ls), self.c)
            for j, name, c in zip(js, names, conf.tolist()):
                out[j][3:5] = name, c
        return [SoilState(*o) for o in out]


def _out_of_model(status: str, reason: str, codes: np.ndarray, used: bool, have_k: bool, hold: _HoldLogic,
                  stamp: float) -> tuple[str, str]:
    """Status and reason of a sample with wheels that the longitudinal model does not describe (codes (4,) of
    :mod:`soilocp.estimation.wheel_usability`, docs/method.md §17): never ``ok``.  A skid turn: ``not_observable``
    while it lasts (docs/robustness.md, "Skid turns"); no wheel used: the last estimate is held, flagged, with
    its age; other wheels used: ``uncertain``, K from them.  ``model_mismatch`` and ``not_observable`` of other
    causes keep their reason, a skid turn aside."""
    text = describe(codes)
    if (codes == SKID_TURN).any():
        return "not_observable", f"{text}: no K while it lasts"
    if status in ("model_mismatch", "not_observable"):
        return status, reason
    if not used:
        if not have_k:
            return "not_observable", f"{text}: no wheel informs K"
        age = stamp - hold.last_update if hold.last_update is not None else 0.0
        return "holding", f"{text}: no wheel informs K; holding the estimate of {age:.1f} s ago"
    if status == "ok":
        return "uncertain", f"{text}; K from the other wheels"
    return status, reason


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
               gate_slip=None, gate_sigma=None, held=None, speed=None) -> SoilState:
        """Fuse one sample: arrays (4,) as :meth:`SoilBank.update` (``slip_sigma`` default
        ``cfg.slip_sigma``; ``speed`` the ground speed in m/s, default ``UNKNOWN_SPEED``)."""
        slip, obs, var = _checked_quads(slip=slip, observed=observed, variance=variance)
        s_sig = np.full(4, self.cfg.slip_sigma) if slip_sigma is None else np.asarray(slip_sigma, dtype=float)
        one = (lambda a: None if a is None else np.asarray(a, dtype=float)[None])
        return self.bank.update(np.zeros(1, dtype=int), [stamp], slip[None], obs[None], var[None],
                                np.asarray(informative, dtype=bool)[None], s_sig[None], one(gate_slip), one(gate_sigma),
                                None if held is None else np.asarray(held, dtype=bool)[None], None,
                                None if speed is None else [speed])[0]


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
