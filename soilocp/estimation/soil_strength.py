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
  median leaves a learnt soil on the first weak samples after a hold: ``report_median`` in
  soilocp/_core/src/soil/bank.rs),
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
from typing import NamedTuple, Optional

import numpy as np

from soilocp.model.checks import as_float_array, check_count, check_index
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives
from soilocp.estimation.soil_config import (SoilConfig, SoilInputs, SoilState, Status, classify,
                                            classify_many)
from soilocp.estimation.soil_grid import UNKNOWN_SPEED, LogKGrid
from soilocp.estimation.wheel_usability import REASONS, SKID_TURN, describe

__all__ = ["UNKNOWN_SPEED", "BayesSoilEstimator", "PaperSoilEstimator", "SoilBank", "SoilInputs"]

# the core's per-wheel flags (crate::soil::bank): used; gated but undetermined (§12); gated but held / stale
_USED, _UNDETERMINED, _HELD = 1, 2, 4


class _CoreStep(NamedTuple):
    """What the status logic reads of the core's step, per vehicle (k,): the pooled belief's ln K 1-sigma
    (half its 16-84 % interval), the axle check's verdict and (z, ln K front, ln K rear), and the belief's
    mid-point CDF at the weakest fitted soil (:attr:`SoilBank.k_floor`)."""

    log_stat: np.ndarray
    axle_off: np.ndarray
    axle: np.ndarray
    floor_cdf: np.ndarray


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
    """N grid Bayes filters over ln K (module doc), stepped together: the beliefs and their per-sample
    update live in the compiled core (:class:`soilocp._core.SoilGridBank`, one call per step); this class
    keeps the configuration and makes each vehicle's status and reason from what the core returns.

    Per vehicle it also keeps, over ``evidence_window`` seconds of informative samples:

    * the mean normalised residual (NIS) of the used wheels at the posterior median: when the
      traction curve cannot explain the (slip, traction) pairs at any K, the status is
      ``model_mismatch`` rather than a confident class;
    * the systematic part of K's error budget: a gross-traction scale error c (the torque constant;
      prior 1-sigma ``gross_scale_sigma``) and a wheel-radius error (``radius_sigma``) are common to
      every sample, so they do not average out like noise.  The scale's effect on ln K is propagated
      exactly through the curve, under c's posterior given the window's samples
      (``scale_shift``, soilocp/_core/src/soil/scale.rs); the radius's is the linearised weighted least-squares shift
      d lnK = eps sum(w h_K h_S dS/dlnR) / sum(w h_K^2).  Both add in quadrature to the belief's own
      spread.  The window restarts when a change is taken: its samples are the current soil's;
    * a front-only and a rear-only belief (soilocp/_core/src/soil/axles.rs): when
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
        # the beliefs and the per-sample update (prediction, likelihood, no-change belief, window statistics,
        # scale profile, axle check): soilocp/_core/src/soil/
        self.core = self.grid.bank(n)
        self._holds = [_HoldLogic(cfg) for _ in range(n)]
        self.k_floor = self.grid.k_floor
        self._lean_since = np.full(n, np.nan)  # stamp since which the data lean to a wrong torque constant
        #: wheel-samples the longitudinal model did not describe, by wheel_usability's reason (the health counters)
        self.unusable_by_reason: dict[str, int] = {r: 0 for r in REASONS if r}

    @property
    def p(self) -> np.ndarray:
        """The pooled beliefs over the grid (N, G) (a copy)."""
        return self.core.p

    @property
    def w_stay(self) -> np.ndarray:
        """P(no change since the change last taken | data) per vehicle (N,) (a copy)."""
        return self.core.w_stay

    @property
    def scale_sys(self) -> np.ndarray:
        """The scale's systematic 1-sigma of ln K, c's mean and 1-sigma, per vehicle (N, 3) (a copy)."""
        return self.core.scale_sys

    @property
    def scale_prior(self) -> np.ndarray:
        """The torque scale's 1-sigma per vehicle (N,): the prior, or the online state's (a copy)."""
        return self.core.scale_prior

    def start_belief(self, i: int, log_k: float, log_k_std: float, floor: float = 1e-3) -> None:
        """Start vehicle i's belief over again from N(log_k, log_k_std^2) on the grid, with a uniform
        ``floor`` (the fleet map's cell and its band, opt-in: soilocp.map.prior, docs/map.md); the evidence
        window restarts, as when a change is taken."""
        g = np.exp(-0.5 * ((self.theta - log_k) / max(log_k_std, 1e-3)) ** 2)
        self.core.start_belief(check_index([i], self.n_vehicles)[0], (1.0 - floor) * g / g.sum() + floor / g.size)

    def update(self, idx, stamp, inputs: SoilInputs, scale_sigma=None) -> list[SoilState]:
        """Fuse one sample per vehicle in ``idx``: stamp (k,) [s] and the vehicles' :class:`SoilInputs`
        (their meaning: its fields) in one call of the core; ``scale_sigma`` (k,) or None: the torque
        scale's relative 1-sigma now (the online state, :mod:`soilocp.estimation.torque_scale`, whose mean
        the torques already carry), instead of the prior ``gross_scale_sigma``.

        A wheel informs K when the gate lets its smoothed slip through (|S| in [slip_min, slip_max],
        >= slip_snr x its 1-sigma, the same sign as the slip the curve is evaluated at), its gross
        traction is determined (§12), its readings are fresh, the sample has an independent ground speed
        and the longitudinal model describes the wheel (``unusable`` 0; a code is counted in
        :attr:`unusable_by_reason`, and the record is never ``ok``)."""
        ix = check_index(idx, self.n_vehicles)
        k = ix.size
        stamp = np.asarray(stamp, dtype=float).reshape(k)
        slip, obs, var, s_sig = (np.asarray(a, dtype=float) for a in (inputs.slip, inputs.observed, inputs.variance,
                                                                      inputs.slip_sigma))
        for name, a in (("slip", slip), ("observed", obs), ("variance", var), ("slip_sigma", s_sig)):
            if a.shape != (k, 4) or not np.isfinite(a).all():
                raise ValueError(f"{name} must be a finite array of shape ({k}, 4), got {a!r}")
        codes = self._count_unusable(inputs.unusable, k)
        f64, flag = (lambda a: np.asarray(a, dtype=float)), (lambda a: np.asarray(a, dtype=bool))
        out = self.core.step(
            ix.astype(np.int64), stamp, slip, obs, var, s_sig, f64(inputs.gate_slip), f64(inputs.gate_sigma),
            flag(inputs.informative), flag(inputs.held), flag(inputs.ground_stale).reshape(k),
            flag(inputs.identifiable).reshape(k), f64(inputs.speed).reshape(k),
            None if inputs.span is None else f64(inputs.span), None if inputs.slip_ends is None else f64(inputs.slip_ends),
            codes, None if scale_sigma is None else f64(scale_sigma).reshape(k))
        return self._states(ix, stamp, inputs, codes, out)

    def step_gated(self, gate, idx, stamp, rows: np.ndarray, scale_sigma=None) -> tuple[SoilInputs, list[SoilState]]:
        """The soil stage's step in one core call: ``gate`` (:class:`soilocp.estimation.slip_gate.SlipGate`) on
        the packed observer outputs ``rows`` (k, ``SlipGateBank.columns``) of the vehicles ``idx`` at ``stamp``
        (k,), then :meth:`update` with its inputs.  Returns the gate's inputs (the record's slip) and the states."""
        ix = np.asarray(idx, dtype=np.int64)  # the core refuses a negative, out-of-range or repeated index
        k = ix.size
        stamp = np.asarray(stamp, dtype=float)
        stamp = stamp if stamp.shape == (k,) else stamp.reshape(k)
        fields, out = self.core.step_gated(gate.core, ix, stamp, rows,
                                           None if scale_sigma is None else np.asarray(scale_sigma, dtype=float).reshape(k))
        inputs = SoilInputs(*fields)
        return inputs, self._states(ix, stamp, inputs, self._count_unusable(inputs.unusable, k), out)

    def _count_unusable(self, unusable, k: int) -> np.ndarray | None:
        """The wheels' unusable codes (k, 4) int64, counted in :attr:`unusable_by_reason`; None when all are 0."""
        if unusable is None:
            return None
        codes = np.asarray(unusable, dtype=np.int64).reshape(k, 4)
        if not codes.any():
            return None
        for c, n in enumerate(np.bincount(codes.ravel(), minlength=len(REASONS)).tolist()):
            if c and n:
                self.unusable_by_reason[REASONS[c]] += n
        return codes

    def _states(self, ix, stamp, inputs: SoilInputs, codes, out) -> list[SoilState]:
        """Each vehicle's state from the core step's arrays ``out`` (``SoilGridBank.step``'s)."""
        k = ix.size
        (wheel, dt, info, _, k_report, log_stat, stats, scale, axle_off, axle, floor_cdf) = out
        core = _CoreStep(log_stat, axle_off, axle, floor_cdf)
        flag = (lambda a: np.asarray(a, dtype=bool))
        return self._summaries(ix, stamp, core, info, (wheel & _USED) > 0, (wheel & _UNDETERMINED) > 0,
                               (wheel & _HELD) > 0, flag(inputs.ground_stale).reshape(k),
                               flag(inputs.identifiable).reshape(k), stats, dt, k_report, scale, codes)

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
        row = (lambda a, default, dtype=float: (default if a is None else np.asarray(a, dtype=dtype))[None])
        inputs = SoilInputs(slip[None], row(informative, None, bool), obs[None], var[None], s_sig[None],
                            row(gate_slip, slip), row(gate_sigma, s_sig), row(held, np.zeros(4, dtype=bool), bool),
                            np.zeros(1, dtype=bool), np.ones(1, dtype=bool),
                            np.array([UNKNOWN_SPEED if speed is None else speed], dtype=float), None, None)
        return self.bank.update(np.zeros(1, dtype=int), [stamp], inputs)[0]


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
