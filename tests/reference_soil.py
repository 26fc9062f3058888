"""The soil-grid update as numpy wrote it before the compiled core: the reference that
tests/test_soil_core.py checks :class:`soilocp._core.SoilGridBank` against (hypothesis property tests).
Not part of the product: the product's update is the core's (soilocp/_core/src/soil/).  Below it, the
slip gate and the wheels' usability codes as numpy wrote them (:class:`ReferenceSlipGate`), which
tests/test_slip_gate.py checks :class:`soilocp._core.SlipGateBank` against.  This is the
code of soilocp/estimation/{soil_grid,soil_axles,soil_strength}.py at the commit before the port, with
the status logic left out: :meth:`ReferenceSoilBank.update` returns the numbers the status is made from.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np

from soilocp.model.checks import check_count, check_index
from soilocp.model.constants import ModelConstants
from soilocp.model.traction import curve_unchecked
from soilocp.estimation.soil_config import SoilConfig, Status
from soilocp.estimation.soil_state import SoilState, class_bounds
from soilocp.estimation.wheel_usability import describe
from soilocp.estimation.soil_grid import LogKGrid as ProductGrid
# the wheel gate of the paper estimator, which the core's gate must equal
from soilocp.estimation.soil_strength import _gate
from soilocp.estimation.observer_bank import LIFT_OFF_FORCE, ObserverBlocks
from soilocp.estimation.soil_state import SoilInputs
from soilocp.estimation.wheel_usability import SKID_TURN, SLIP_BEYOND_EQ1, STALL, STOPPED_UNPOWERED, UsabilityLimits

UNKNOWN_SPEED = 1.0



#: the wheels' unusable codes' names, the reference's own (the product's come from the core under test)
REASONS = ("", "slip_beyond_eq1", "stopped_unpowered", "stall", "skid_turn")


class LogKGrid(ProductGrid):
    """The ln K grid of the Bayes estimator and what is computed on it: the observation curve
    (eq. 3 or 6, factorised), the belief's prediction (random walk + change prior) and its robust
    summaries.  One object serves :class:`BayesSoilEstimator` and the batched ``soilocp.estimation.batch``."""

    def __init__(self, constants: ModelConstants, cfg: SoilConfig):
        super().__init__(constants, cfg)  # the nodes: the product's grid, so both start from the same numbers
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


class ReferenceSoilBank:
    """N grid Bayes filters over ln K, numpy (the pre-port SoilBank without its status logic)."""

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
        the core's soilocp/_core/src/observer/intervals.rs) weighs that interval's exponent, at most 1; 0 or None:
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
        judged = []
        for j in range(k):
            evidence, nis_sum, s_kk, s_kh, s_ks = stats[j]
            sens = abs(s_kh) / s_kk if s_kk > 0 else 0.0
            judged.append(self.axles.judge(int(ix[j]), float(stamp[j]), float(dt[j]), cfg.axle_scale_sigma * sens))
        return dict(use=use, undetermined=gated & ~determined, held=gated & held, dt=dt, info=info, taken=taken,
                    k_report=k_report, log_stat=np.array([self.grid.summary(c)[2] for c in cdf]), stats=stats.copy(),
                    scale=self.scale_sys[ix].copy(), axle_mismatch=np.array([a[0] for a in judged]),
                    axle=np.array([a[1:] for a in judged]), floor_cdf=cdf[:, self._floor_idx])

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


# --- the slip gate as numpy wrote it before the core (soilocp/estimation/pipeline.py's SlipGate and
# --- soilocp/estimation/wheel_usability.py at 86852cb): the reference of tests/test_slip_gate.py

V_STILL = 0.02


def travel_direction(rim: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """d per wheel, +-1: the sign of the ground speed under the wheel, or of the rim where the ground
    stands (|V_i| < ``V_STILL``), +1 where both stand."""
    d = np.where(np.abs(ground) >= V_STILL, np.sign(ground), np.sign(rim))
    return np.where(d == 0, 1.0, d)


def wheel_usability(slip: np.ndarray, rim: np.ndarray, ground: np.ndarray, body_speed: np.ndarray,
                    yaw_rate: np.ndarray, gross: np.ndarray, half_track: float,
                    limits: UsabilityLimits = UsabilityLimits(), deadband: float = 0.15) -> np.ndarray:
    """Unusable code (k, 4) per wheel (module doc) from the travel-frame slip (k, 4) (eq. 1,
    :func:`travel_slip`), rim speeds R_w omega (k, 4) and ground speeds under the wheels (k, 4) in m/s,
    the body's ground speed (k,) m/s, yaw rate (k,) rad/s, each wheel's gross traction (k, 4) (eq. 13's
    F_GT / W), the half-track (c + d) / 2 in m and the slip deadband (m/s: above it the body moves)."""
    lim = limits
    code = np.zeros(slip.shape, dtype=np.int8)
    left, right = rim[:, :2].mean(axis=1), rim[:, 2:].mean(axis=1)
    yaw, v = np.abs(yaw_rate), np.abs(body_speed)
    skid = (((left * right < 0) & (np.minimum(np.abs(left), np.abs(right)) > lim.rim_turning))
            | ((yaw > lim.yaw_turning) & (v < yaw * half_track)))
    powered = np.abs(gross) > lim.gross_idle
    code[(v[:, None] < lim.stall_speed) & powered] = STALL
    code[(np.abs(rim) < lim.rim_stopped) & ~powered & (np.abs(ground) > deadband)] = STOPPED_UNPOWERED
    code[np.abs(slip) > 1.0] = SLIP_BEYOND_EQ1
    code[skid] = SKID_TURN  # a skid turn explains the rest (an in-place turn is also V ~ 0 under torque)
    return code


class ReferenceSlipGate:
    """Slip per wheel (eq. 1 with the floor and deadband of docs/method.md §6, §10, in each wheel's direction
    of travel, §17) from the filtered speeds, the wheels the longitudinal model describes now
    (:func:`wheel_usability`), its uncertainty, and the low-pass slip the soil gate decides on (``gate_smoothing``:
    gating on the raw, noisy slip keeps the samples whose noise pushed |S| up and biases K,
    docs/method.md §9), for N vehicles."""

    def __init__(self, config: PipelineConfig, n_vehicles: int):
        self.cfg = config
        self._wheel_y = np.asarray(config.vehicle.wheel_y, dtype=float)
        self._lp = np.zeros((n_vehicles, 4))
        self._lp_stamp = np.full(n_vehicles, np.nan)
        # the ground speed's age at the last stamp and its last refresh interval (s; NaN: not yet seen)
        self._gs_age = np.full(n_vehicles, np.nan)
        self._gs_interval = np.full(n_vehicles, np.nan)
        # skid-steer: the two wheels of a side carry one torque measurement, so each counts half
        self._shared = 2.0 if config.vehicle.drive == "per_side" else 1.0
        self._static_load = config.vehicle.mass * config.observer.gravity / 4.0
        self._half_track = 0.5 * (config.vehicle.c + config.vehicle.d)

    def step(self, ix: np.ndarray, stamp: np.ndarray, ob: ObserverBlocks) -> SoilInputs:
        """ix (k,) vehicle indices, stamp (k,) s, and the observer's output for them."""
        cfg = self.cfg
        r = cfg.vehicle.wheel_radius
        v_wheel = ob.ground_speed[:, None] - ob.yaw_rate[:, None] * self._wheel_y
        rim = ob.wheel_speed * r
        slip, scale = self._eq1(rim, v_wheel)
        # eq. 1 and the traction law in each wheel's direction of travel (§17): a wheel travelling backwards
        # is the mirror image of one travelling forwards, its slip and its traction both negated
        direction = travel_direction(rim, v_wheel)
        slip = direction * slip
        if cfg.soil.measurement == "gross":
            observed, var = direction * ob.gross, ob.gross_var * self._shared
        else:
            observed, var = direction * ob.mu, ob.mu_var * self._shared
        unusable = wheel_usability(slip, rim, v_wheel, ob.ground_speed, ob.yaw_rate, ob.gross, self._half_track,
                                   deadband=cfg.slip_deadband)
        # a slow stream's refresh: the pair from the readings (soilocp/_core/src/observer/intervals.rs: eq. 13
        # integrated over a held speed's interval, or at a held torque's refresh) instead of the observer's
        # prediction through the held value; gross only
        refresh = ob.interval > 0 if cfg.soil.measurement == "gross" else np.zeros(ob.interval.shape, dtype=bool)
        any_refresh = bool(refresh.any())
        slip_ends = None
        if any_refresh:
            s0, scale0 = self._eq1(ob.interval_rim_start, ob.interval_ground_start)
            s1, scale1 = self._eq1(ob.interval_rim_end, ob.interval_ground_end)
            d0 = travel_direction(ob.interval_rim_start, ob.interval_ground_start)
            d1 = travel_direction(ob.interval_rim_end, ob.interval_ground_end)
            s0, s1 = d1 * s0, d1 * s1
            # a pair whose interval reverses the travel is no one slip path of one law: not informative
            scale0 = np.where(d0 == d1, scale0, 0.0)
            slip_ends = np.stack([s0, s1], axis=2)
            filtered_slip = slip
            # the slip path's middle; informative only where the wheel moved at both ends
            slip, scale = np.where(refresh, 0.5 * (s0 + s1), slip), np.where(refresh, np.minimum(scale0, scale1), scale)
            observed = np.where(refresh, d1 * ob.interval_gross, observed)
            unusable = np.where(refresh & ((np.abs(s0) > 1.0) | (np.abs(s1) > 1.0)), SLIP_BEYOND_EQ1, unusable)
            var = np.where(refresh, ob.interval_gross_var * self._shared, var)
        # a wheel whose new speed reading the observer's gate rejected has a predicted slip (docs/method.md §18);
        # a refresh pair, made from the readings, keeps its say
        # (a held wheel informs no K anyway, and keeps its own reason: the readings are held)
        held = np.where(ob.interval_learning, ~refresh,
                        (ob.speed_age > cfg.soil.fresh_age) | (ob.torque_age > cfg.soil.fresh_age))
        informative = ((scale >= cfg.slip_deadband) & (ob.normal_force > LIFT_OFF_FORCE) & ~ob.reset[:, None]
                       & (unusable == 0) & (~ob.speed_rejected | refresh | held))
        # slip error of eq. 1 at this speed: a speed error dV gives dS ~ dV / V (docs/method.md §6, §9), with the
        # ground speed's stray beyond its assumed noise (§20)
        # the stray is one error per reading, repeated by every sample until the next reading: counted as often
        # as those samples' likelihood exponents add up to
        last = self._lp_stamp[ix]
        start = np.isnan(last)
        dt = stamp - last  # NaN at the start (quiet NaN: no FP warning), where it is not used
        age = np.asarray(ob.ground_speed_age, dtype=float)
        since = self._gs_age[ix] + dt
        with np.errstate(invalid="ignore"):
            new_reading = np.isfinite(since) & (age < since - 1e-9)
            interval = np.where(new_reading, since - age, self._gs_interval[ix])
            step = np.where(dt > 0, dt, 1.0)
            exponent = np.minimum(cfg.soil.temper * step / cfg.soil.temper_interval, cfg.soil.temper_max)
            repeats = np.where((dt > 0) & (interval > dt), np.maximum(interval / step * exponent, 1.0), 1.0)
        self._gs_age[ix], self._gs_interval[ix] = age, interval
        speed_sigma = np.hypot(cfg.soil.speed_sigma, ob.ground_speed_excess * np.sqrt(repeats))[:, None]
        s_sig = np.hypot(cfg.soil.slip_sigma, speed_sigma / np.maximum(scale, 1e-3))
        if any_refresh:  # and the interval's mean rim speed is known only to interval_rim_sigma
            s_sig = np.where(refresh, np.hypot(s_sig, ob.interval_rim_sigma / np.maximum(scale, 1e-3)), s_sig)
        tau = cfg.soil.gate_smoothing
        restart = start | ob.reset | (dt <= 0) | (dt > 1.0)
        if tau > 0:
            alpha = np.where(restart, 1.0, -np.expm1(-np.where(restart, 0.0, dt) / tau))
        else:
            alpha = np.ones(ix.size)
            restart[:] = True
        prev = self._lp[ix]
        own = filtered_slip if any_refresh else slip  # the low-pass runs on the filtered speeds' slip
        lp = np.where(restart[:, None], own, prev + alpha[:, None] * (own - prev))
        self._lp[ix] = lp
        self._lp_stamp[ix] = stamp
        g_sig = s_sig * np.sqrt(alpha / (2.0 - alpha))[:, None]  # stationary std of low-passed white noise
        span = None
        if any_refresh:  # between refreshes the low-pass follows a prediction: the gate takes the interval's slip
            lp, g_sig = np.where(refresh, slip, lp), np.where(refresh, s_sig, g_sig)
            span = np.where(refresh, ob.interval, 0.0)
        # between the refreshes of a slow wheel-speed stream the filtered speed is a prediction (its slip
        # 1-sigma 0.06-0.30 within 50 ms of a 5 Hz refresh), and the samples repeat one measurement: K learns
        # from samples within fresh_age of a new reading, and where the interval's own pair is served
        # (interval_learning) at the refresh only.  A slow torque stream likewise: between its refreshes the
        # gross traction rests on a held torque (the Warthog's currents, refreshed once a second, were paired
        # with four wheel-speed refreshes each): `held`, above
        measured = ob.ground_speed_measured
        loaded = ob.normal_force >= cfg.soil.min_load_fraction * self._static_load
        # the codes judge measured speeds and torques: between a slow stream's refreshes the filtered speed is
        # a prediction (at 5 Hz its slip passed +-1, and a side's rim crossed zero: a 'skid turn' on the last
        # record of wheel-speed-5hz took its convergence from 0.71 to 7.1 s), and a held wheel informs no K anyway
        unusable = np.where(held, 0, unusable)
        return SoilInputs(slip, informative & measured[:, None] & loaded, observed, var, s_sig, lp, g_sig, held,
                          ob.ground_speed_age > cfg.soil.max_input_age, measured, ob.ground_speed, span, slip_ends,
                          np.where(measured[:, None], unusable, 0))

    def _eq1(self, rim: np.ndarray, ground: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 1 with the floor of docs/method.md §6 (numpy's eq. 1 before the core): slip
        (k, 4) from rim speeds R_w omega and the ground speeds at the wheels (m/s), and the larger of the
        two speeds (the deadband's measure)."""
        scale = np.maximum(np.abs(rim), np.abs(ground))
        return (rim - ground) / np.maximum(scale, self.cfg.slip_floor), scale


def classify_many(log_k: np.ndarray, log_k_std: np.ndarray, constants: ModelConstants) -> tuple[list[str], np.ndarray]:
    """The soil classes as numpy computed them before the core (soil_config.classify_many at 86852cb):
    math.erf element-wise, numpy's diff and argmax."""
    names, edges = class_bounds(constants)
    sig = np.maximum(log_k_std, 1e-6)[:, None]
    erf = np.frompyfunc(math.erf, 1, 1)
    cdf = 0.5 * (1 + erf((edges[None, :] - log_k[:, None]) / (sig * math.sqrt(2))).astype(float))
    probs = np.diff(cdf, axis=1)
    i = probs.argmax(axis=1)
    return [names[j] for j in i], probs[np.arange(i.size), i]


# --- the soil records as Python made them before the core (soilocp/estimation/soil_strength.py's SoilBank._vouch,
# --- _summaries and _out_of_model at 86852cb), on the core step's arrays: the reference of
# --- tests/test_slip_gate.py's record test

class _HoldLogic:
    """The records' 'holding' / expiry bookkeeping and the held band (docs/method.md §9: hold, flagged; never
    drift): the reference of soilocp/_core/src/soil/status.rs ``StatusParams::hold``, which the product runs."""

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


class ReferenceRecords:
    """Status, reason, K held or withdrawn, band and class of a :class:`soilocp.estimation.soil_strength.SoilBank`'s
    vehicles from the arrays of its core's ``step`` (``summaries``), with their own hold state."""

    def __init__(self, bank):
        from soilocp.estimation.soil_strength import PaperSoilEstimator  # noqa: F401  (the module the code came from)

        self.bank, self.cfg, self.c, self.grid, self.k_floor = bank, bank.cfg, bank.c, bank.grid, bank.k_floor
        self.core = bank.core
        self._holds = [_HoldLogic(bank.cfg) for _ in range(bank.n_vehicles)]
        self._lean_since = np.full(bank.n_vehicles, np.nan)

    @property
    def scale_prior(self):
        return self.core.scale_prior

    def summaries(self, ix, stamp, step, inputs, codes) -> list:
        """The states from the core step's arrays ``step`` (``SoilGridBank.step``'s) and the step's inputs."""
        (wheel, dt, info, _, k_report, log_stat, stats, scale, axle_off, axle, floor_cdf) = step
        k = ix.size
        core = _CoreStep(log_stat, axle_off, axle, floor_cdf)
        flag = (lambda a: np.asarray(a, dtype=bool))
        return self._summaries(ix, stamp, core, info, (wheel & 1) > 0, (wheel & 2) > 0, (wheel & 4) > 0,
                               flag(inputs.ground_stale).reshape(k), flag(inputs.identifiable).reshape(k), stats, dt,
                               k_report, scale, codes)

    def _vouch(self, v: int, stamp: float, evidence: float, c_mean: float) -> tuple[Status, str]:
        """Status and reason of an estimate whose band is narrow enough for ``ok``: ``ok`` only where its own
        checks vouch for it (docs/robustness.md, "ok means ok"), else ``uncertain`` naming what they lack.

        * the data lean to a torque scale the state does not assume (``_lean_since``: the window's scale
          posterior more than 2 of its sigmas, and more than the scale's own prior, from 1): a common scale
          and K trade off on a driving wheel (eq. 3), so K is limited by the torque scale whatever its
          statistical band (payload +25 % at constant speed: sand 50 read 67-73, ln K 1-sigma 0.16-0.18);
        * the front and rear axles read different soils for most of the window (the axle check's verdict,
          soilocp/_core/src/soil/axles.rs), though one axle is not informing now, so it is not judged now
          (mass-com+20: K 130-136 for 200 from the rear axle alone, ln K 1-sigma 0.09, between two
          ``model_mismatch`` stretches);
        * fewer than ``mismatch_min_evidence`` s of informative samples since the evidence window restarted
          (a change taken, the drive's start) or faded (a hold): the mismatch and axle checks have not had the
          data to judge the estimate yet (a change taken while the axles straddle two soils reads a K between
          them, ln K 1-sigma 0.12: skid-arcs, sand 50 / firm 300 read 122)."""
        cfg = self.cfg
        over, weight = self.core.axle_window(v)
        if not np.isnan(self._lean_since[v]) and self._lean_since[v] <= stamp:
            return "uncertain", (f"these data lean to a torque scale of {c_mean:.2f} (1 +- {self.scale_prior[v]:.2f} "
                                 "assumed): K is limited by the torque scale, which a drive at constant speed cannot "
                                 "tell apart from K (accelerate or brake, or soilocp calibrate-torque)")
        enough = 1.0 - math.exp(-cfg.mismatch_min_evidence / cfg.evidence_window)
        if cfg.axle_mismatch_z > 0 and weight >= enough and over > 0.5 * weight:
            return "uncertain", (f"the front and rear axles read different soils for most of the last "
                                 f"{cfg.evidence_window:g} s (one axle does not inform K now): the normal forces (mass, "
                                 "centre of mass) or an axle's torque constant may be off")
        if evidence < cfg.mismatch_min_evidence:
            return "uncertain", (f"K from {evidence:.1f} s of informative slip since the last change or hold: the "
                                 f"model checks need {cfg.mismatch_min_evidence:g} s before the estimate is ok")
        return "ok", ""

    def _summaries(self, ix, stamp, core, info, use, undetermined, held, stale, ident, stats, dt, k_report,
                   scale_shift, codes=None) -> list[SoilState]:
        """Per vehicle: K (``k_report``, the core's report median) and its band from the pooled belief's
        spread and the core's systematic terms (``core``: :class:`_CoreStep`), status and reason; ``codes``
        (k, 4): the wheels the longitudinal model does not describe now (:func:`_out_of_model`)."""
        cfg, k = self.cfg, ix.size
        out, rep = [], []  # rep: (vehicle, K, ln K 1-sigma) of the states that report a class
        for j in range(k):
            v = int(ix[j])
            hold = self._holds[v]
            st = float(stamp[j])
            if info[j]:
                hold.last_update = st
            log_stat = float(core.log_stat[j])
            k_med = float(k_report[j])
            evidence, nis_sum, s_kk, s_kh, s_ks = stats[j]
            sys_scale, c_mean, c_std = scale_shift[j].tolist()  # exact, on the current data (the core's scale_shift)
            # how long the data have leant to a wrong torque constant: a window that spans two soils leans
            # too, briefly (the nominal drive's 300 -> 100: to 0.90 for 0.3 s before the change is taken)
            if abs(c_mean - 1.0) <= max(2.0 * c_std, self.scale_prior[v]):
                self._lean_since[v] = np.nan
            elif not self._lean_since[v] <= st:  # none yet (NaN), or a restarted clock: it starts now
                self._lean_since[v] = st
            sys_radius = cfg.radius_sigma * abs(s_ks) / s_kk if s_kk > 0 else 0.0
            axle_off, (axle_z, theta_front, theta_rear) = bool(core.axle_off[j]), core.axle[j].tolist()
            # axles that disagree: the truth is usually near one of them (the core's axles.rs), so their distance
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
            elif rk is not None and core.floor_cdf[j] > 0.5:
                status = "model_mismatch"
                reason = (f"gross traction is below what the model's weakest soil gives at this slip (K under "
                          f"{self.k_floor:g}, half the weakest reference soil's): torque scale or units?")
            elif status in ("no_estimate", "holding") and held[j].any() and not use[j].any():
                status = "holding" if status == "holding" else "not_observable"
                since = f"for {st - hold.last_update:.1f} s" if hold.last_update is not None else "yet"
                if stale[j]:
                    reason = (f"slip is informative but the ground speed is stale: no new reading for more than "
                              f"{cfg.max_input_age:g} s, no K update {since} (slip, eq. 1, needs a measured ground speed)")
                else:
                    reason = (f"slip is informative but the wheel speed / torque readings are held: no new reading of "
                              f"both {since} (sensor refresh too slow to measure traction)")
            elif status in ("no_estimate", "holding") and undetermined[j].any() and not use[j].any():
                status = "holding" if status == "holding" else "not_observable"
                reason = "slip is informative but the wheel torque balance does not determine gross traction"
            if status == "ok":
                status, reason = self._vouch(v, st, evidence, c_mean)
            if codes is not None and ident[j] and codes[j].any():
                status, reason = _out_of_model(status, reason, codes[j], use[j].any(), rk is not None, hold, st)
            below_floor = status == "model_mismatch" and reason.startswith("gross traction is below")
            if status == "not_observable" or below_floor:  # no number: K not determined now (§12), or a belief
                rk = rs = rl = None                            # truncated at the weakest soil (below the floor)
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


class _CoreStep(NamedTuple):
    log_stat: np.ndarray
    axle_off: np.ndarray
    axle: np.ndarray
    floor_cdf: np.ndarray


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
