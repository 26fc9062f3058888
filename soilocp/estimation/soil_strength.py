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
from typing import Optional, get_args

import numpy as np

from soilocp.schemas.pipeline import REASON_CODES
from soilocp import _core
from soilocp.model.checks import as_float_array, check_count, check_index
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives
from soilocp.estimation.core_attribute import core_attribute
from soilocp.estimation.soil_config import SoilConfig, Status
from soilocp.estimation.soil_state import SoilInputs, SoilState, class_bounds, classify, classify_many
from soilocp.estimation.soil_grid import LogKGrid
from soilocp.estimation.wheel_usability import REASONS, describe

__all__ = ["BayesSoilEstimator", "PaperSoilEstimator", "SoilBank", "SoilInputs"]



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


def _paper_status(cfg: SoilConfig, stamp: float,
                  last_update: Optional[float]) -> tuple[Status, str, str, Optional[float]]:
    """The paper method's status from the age of its last update (docs/method.md §9: hold, flagged; never
    drift; withdraw after ``hold_after + expire_after``) with its reason and reason code, and the last update
    time to keep (None once the
    stamps went backwards: a restarted source's old time means nothing).  Its K only changes when it updates,
    so the held value is its K.  The Bayes bank's records are the core's (soilocp/_core/src/soil/status.rs)."""
    if last_update is None:
        return "no_estimate", "slip has not been informative yet (need |slip| >= %.2f)" % cfg.slip_min, "not_yet", None
    age = stamp - last_update
    if age < 0:
        return "no_estimate", "stamp went backwards (source restarted): estimate withdrawn", "stamp_backwards", None
    if age > cfg.hold_after + cfg.expire_after:
        return "no_estimate", f"slip uninformative for {age:.1f} s: estimate withdrawn", "withdrawn", last_update
    if age > cfg.hold_after:
        return "holding", f"slip uninformative for {age:.1f} s: holding the last estimate", "holding", last_update
    return "ok", "", "none", last_update


class SoilBank:
    """N grid Bayes filters over ln K (module doc), stepped together: the beliefs and their per-sample
    update live in the compiled core (:class:`soilocp._core.SoilGridBank`, one call per step), and so do the
    records (K held or withdrawn, the band, the status and reason codes: soilocp/_core/src/soil/status.rs); this
    class keeps the configuration, words the reason codes and names the class of the reported band.

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
        self.k_floor = self.grid.k_floor
        # the records (held / withdrawn K, status and reason codes, soilocp/_core/src/soil/status.rs)
        self.core.set_status(self.grid.span)
        #: wheel-samples the longitudinal model did not describe, by the unusable code's name (the health counters)
        self.unusable_by_reason: dict[str, int] = {r: 0 for r in REASONS if r}
        self._bounds = class_bounds(constants)  # the soil classes' (names, ln K edges), for every state's class

    # the core's state, as it holds it (each a copy)
    p = core_attribute("p", "The pooled beliefs over the grid (N, G) (a copy).", "core")
    w_stay = core_attribute("w_stay", "P(no change since the change last taken | data) per vehicle (N,) (a copy).",
                            "core")
    scale_sys = core_attribute(
        "scale_sys", "The scale's systematic 1-sigma of ln K, c's mean and 1-sigma, per vehicle (N, 3) (a copy).",
        "core")
    scale_prior = core_attribute(
        "scale_prior", "The torque scale's 1-sigma per vehicle (N,): the prior, or the online state's (a copy).",
        "core")

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
        inputs = inputs.arrays(k)
        codes = self._count_unusable(inputs.unusable, k)
        wheel = self.core.step(ix.astype(np.int64), stamp, inputs, codes,
                               None if scale_sigma is None else np.asarray(scale_sigma, dtype=float).reshape(k))[0]
        return self._states(ix, stamp, codes, self.core.report(wheel))

    def states(self, ix: np.ndarray, stamp: np.ndarray, inputs: SoilInputs, report) -> list[SoilState]:
        """The states of the vehicles ``ix`` at ``stamp`` (k,) from a gated step's inputs (their unusable
        wheels, counted in :attr:`unusable_by_reason`) and the core's records ``report`` (``ChainCore.step``'s or
        ``update``'s)."""
        return self._states(ix, stamp, self._count_unusable(inputs.unusable, ix.size), report)

    def _count_unusable(self, unusable, k: int) -> np.ndarray | None:
        """The wheels' unusable codes (k, 4) int64, counted in :attr:`unusable_by_reason`; None when all are 0."""
        if unusable is None:
            return None
        codes = np.asarray(unusable, dtype=np.int64).reshape(k, 4)
        if not np.count_nonzero(codes):  # (a C call; ndarray.any goes through numpy's Python wrappers)
            return None
        for c, n in enumerate(np.bincount(codes.ravel(), minlength=len(REASONS)).tolist()):
            if c and n:
                self.unusable_by_reason[REASONS[c]] += n
        return codes

    def _states(self, ix, stamp, codes, report) -> list[SoilState]:
        """Each vehicle's state from the core's records ``report`` (``SoilGridBank.report``: codes, numbers,
        used wheels) and the wheels' unusable ``codes`` (k, 4) (None: all usable): the status and reason text
        from their codes, the class from the reported band (statistical and systematic)."""
        flags, nums, used = report[0].tolist(), report[1].tolist(), report[2].tolist()
        rows = [_NO_CODES] * ix.size if codes is None else codes.tolist()
        stamps = np.asarray(stamp, dtype=float).tolist()
        out, rep = [], []  # rep: (row, K, ln K 1-sigma) of the states that report a class
        for j, ((status, why, have), (k, k_std, log_std, last, *args), use, row) in enumerate(
                zip(flags, nums, used, rows)):
            st = stamps[j]
            last = None if math.isnan(last) else last
            status = _STATUSES[status]
            reason = self._reason(why, args, row) if why else ""
            unusable = _ALL_USABLE if row is _NO_CODES else tuple(map(REASONS.__getitem__, row))
            if not have:
                k = k_std = log_std = None
            elif status != "model_mismatch":
                rep.append((j, k, log_std))
            held_for = None if k is None or last is None else max(st - last, 0.0)
            out.append([k, k_std, log_std, None, None, status, reason, last, tuple(use), held_for, unusable,
                        _REASON_NAMES[why]])
        if rep:  # the class from the whole band (statistical and systematic), as reported
            js, ks, ls = zip(*rep)
            cls, conf = classify_many(np.log(ks), np.array(ls), self.c, self._bounds)
            for j, name, c in zip(js, cls, conf.tolist()):
                out[j][3:5] = name, c
        return [SoilState(*o) for o in out]

    def _reason(self, why: int, args, unusable) -> str:
        """The reason text of the core's reason code ``why`` (soilocp/_core/src/soil/status.rs, ``reason``) and
        its numbers ``args``; ``unusable``: the wheels' unusable codes (4,) (the out-of-model reasons word them).
        A text that is one template is :data:`_REASON_TEMPLATES`'; the others are worded here."""
        cfg, (a0, a1, a2, _) = self.cfg, args
        template = _REASON_TEMPLATES.get(why)
        if template is not None:
            # the wheels the longitudinal model does not describe, worded only where the text names them
            text = describe(unusable) if "{text}" in template else ""
            return template.format(cfg=cfg, a0=a0, a1=a1, a2=a2, k_floor=self.k_floor, text=text)
        if why in (_R["systematic_scale"], _R["systematic_scale_calibrate"]):
            # the data's scale without its posterior spread: across drives it moves by more than that
            # spread (nominal: 0.98-1.05 for 1.00, 1-sigma 0.03; docs/robustness.md)
            reason = (f"ln K 1-sigma {a0:.2f}, mostly systematic: the torque scale (1 +- "
                      f"{a1:.2f} assumed; these data lean to {a2:.2f}) moves K this much "
                      "where the traction curve is flat in K")
            if why == _R["systematic_scale_calibrate"]:
                reason += "; the data suggest a wrong torque constant: soilocp calibrate-torque"
            return reason
        if why == _R["systematic_radius"]:
            return (f"ln K 1-sigma {a0:.2f}, mostly systematic: a {100 * cfg.radius_sigma:g} % wheel-radius "
                    "uncertainty moves these small slips, and K, this much")
        if why == _R["axles"]:
            return (f"the front and rear axles read different soils (K {math.exp(a0):.0f} front, "
                    f"{math.exp(a1):.0f} rear; {a2:.1f} sigma apart, and most of the last "
                    f"{cfg.evidence_window:g} s): the normal forces (mass, centre of mass) or an axle's torque "
                    "constant are off")
        if why in (_R["ground_stale"], _R["readings_held"]):
            since = "yet" if math.isnan(a0) else f"for {a0:.1f} s"
            if why == _R["ground_stale"]:
                return (f"slip is informative but the ground speed is stale: no new reading for more than "
                        f"{cfg.max_input_age:g} s, no K update {since} (slip, eq. 1, needs a measured ground speed)")
            return (f"slip is informative but the wheel speed / torque readings are held: no new reading of "
                    f"both {since} (sensor refresh too slow to measure traction)")
        raise ValueError(f"reason code {why}: unknown to this version of soilocp (the core is newer?)")


_NO_CODES = (0, 0, 0, 0)  # every wheel usable: the unusable codes
_ALL_USABLE = (REASONS[0],) * 4  # and their names

#: the soil stage's status and reason codes, code -> name (soilocp/_core/src/codes.rs, the one definition)
_STATUSES: tuple[Status, ...] = tuple(_core.SoilGridBank.status_names)
_REASON_NAMES: tuple[str, ...] = tuple(_core.SoilGridBank.reason_names)
#: reason name -> code
_R = {name: code for code, name in enumerate(_REASON_NAMES)}
if _STATUSES != get_args(Status) or not set(_REASON_NAMES) <= set(REASON_CODES):
    raise ImportError(f"soilocp._core's status names {_STATUSES} or reason names {_REASON_NAMES} are not those of "
                      "soilocp.schemas.codes: rebuild the core (make setup) and regenerate its file "
                      "(python -m soilocp.cli.generate_codes)")

#: the reason texts that are one template each, by reason code (the others: SoilBank._reason): filled in with
#: the record's numbers a0, a1, a2, the soil settings cfg, the grid's k_floor and text, the wheels outside the
#: longitudinal model described (docs/method.md §17, docs/robustness.md "Skid turns")
_REASON_TEMPLATES: dict[int, str] = {
    _R["not_yet"]: "slip has not been informative yet (need |slip| >= {cfg.slip_min:.2f})",
    _R["stamp_backwards"]: "stamp went backwards (source restarted): estimate withdrawn",
    _R["withdrawn"]: "slip uninformative for {a0:.1f} s: estimate withdrawn",
    _R["holding"]: "slip uninformative for {a0:.1f} s: holding the last estimate",
    _R["wide"]: "ln K 1-sigma {a0:.2f} > {cfg.uncertain_log_sigma}: K poorly determined",
    _R["not_identifiable"]: ("not identifiable: no independent ground speed (slip, eq. 1, compares the wheel speed "
                             "with it; wheel odometry cannot stand in)"),
    _R["nis"]: ("the traction curve does not explain the (slip, gross traction) pairs: mean NIS {a0:.1f} "
                "> {cfg.mismatch_nis:g} over the last {cfg.evidence_window:g} s (torque scale, sensor or model)"),
    _R["below_floor"]: ("gross traction is below what the model's weakest soil gives at this slip (K under "
                        "{k_floor:g}, half the weakest reference soil's): torque scale or units?"),
    _R["undetermined"]: "slip is informative but the wheel torque balance does not determine gross traction",
    _R["leans"]: ("these data lean to a torque scale of {a0:.2f} (1 +- {a1:.2f} assumed): K is limited by the "
                  "torque scale, which a drive at constant speed cannot tell apart from K (accelerate or brake, "
                  "or soilocp calibrate-torque)"),
    _R["axle_window"]: ("the front and rear axles read different soils for most of the last "
                        "{cfg.evidence_window:g} s (one axle does not inform K now): the normal forces (mass, "
                        "centre of mass) or an axle's torque constant may be off"),
    _R["evidence"]: ("K from {a0:.1f} s of informative slip since the last change or hold: the "
                     "model checks need {cfg.mismatch_min_evidence:g} s before the estimate is ok"),
    _R["out_skid"]: "{text}: no K while it lasts",
    _R["out_no_wheel"]: "{text}: no wheel informs K",
    _R["out_holding"]: "{text}: no wheel informs K; holding the estimate of {a0:.1f} s ago",
    _R["out_others"]: "{text}; K from the other wheels",
}


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
        ``cfg.slip_sigma``; ``speed`` the ground speed in m/s, default ``cfg.unknown_speed``)."""
        slip, obs, var = _checked_quads(slip=slip, observed=observed, variance=variance)
        s_sig = np.full(4, self.cfg.slip_sigma) if slip_sigma is None else np.asarray(slip_sigma, dtype=float)
        row = (lambda a, default, dtype=float: (default if a is None else np.asarray(a, dtype=dtype))[None])
        inputs = SoilInputs(slip[None], row(informative, None, bool), obs[None], var[None], s_sig[None],
                            row(gate_slip, slip), row(gate_sigma, s_sig), row(held, np.zeros(4, dtype=bool), bool),
                            np.zeros(1, dtype=bool), np.ones(1, dtype=bool),
                            np.array([self.cfg.unknown_speed if speed is None else speed], dtype=float), None, None)
        return self.bank.update(np.zeros(1, dtype=int), [stamp], inputs)[0]


class PaperSoilEstimator:
    """The paper's update rule, eqs. 36-37, with the sign of eq. 37 restored and gated (module doc)."""

    def __init__(self, constants: ModelConstants = DEFAULT_CONSTANTS, config: SoilConfig | None = None):
        self.c = constants
        self.cfg = config or SoilConfig(method="paper", measurement="net")
        self.k = float(self.cfg.k_initial)
        self.last_update: Optional[float] = None

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
            self.last_update = stamp
        status, reason, code, self.last_update = _paper_status(cfg, stamp, self.last_update)
        rk = self.k if status != "no_estimate" else None
        cls = conf = None
        if rk is not None:
            cls, conf = classify(rk, 0.1, self.c)
        return SoilState(rk, None, None, cls, conf, status, reason, self.last_update, tuple(bool(u) for u in used),
                         reason_code=code)
