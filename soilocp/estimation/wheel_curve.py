"""The wheel's own traction curve in the OCP records: learnt where the drive shows it, and flagged where
nobody checked it (docs/method.md §14, §19).

The paper's constants C1..C6 describe one testbed wheel; the OCPs follow from the wheel's curve, not from K
alone.  :class:`WheelCurve` runs the compiled core's learners (``soilocp._core.CurveBank``, one per vehicle:
soilocp/_core/src/curve.rs) on each soil estimate's (slip, net traction) pairs and decides each record's OCPs:

* **learnt**, for a wheel whose curve nobody checked: where the current soil's pairs spread over the bend (the
  peak lies inside them), mu_T and S_T are the fitted curve's, with the core's band (the fit's own 1-sigma, the
  learner's systematic error ``CurveConfig.s_t_sys``, ``mu_t_sys``, for S_T the peak's flatness
  ``tilt_sys`` and the part of ``peak_span`` past it the slips do not reach, and for mu_T the torques' common
  scale, ``SoilConfig.gross_scale_sigma`` of it).  Never
  ``ok``: the learnt peak rests on the observer's split of gross traction into net and resistance
  (docs/method.md §12, §19), which places it within +-0.05 on most simulated drives but not on all
  (scripts/curve_learner_errors.py); the reason says how to make the curve checked.  S_E is null: eq.
  10's line is the paper wheel's, and the efficiency line is not learnt.  A checked curve keeps its own
  OCPs;
* **model**: mu_T, S_T, S_E from K and the configured constants, whose curve somebody checked for this
  wheel: the paper's testbed wheel (the built-in rover) or a calibration file (the vehicle's
  ``traction_curve``), with the 1-sigma K's band carries into mu_T and S_T.  Not ``ok`` where that band
  is wider than a controller acts on (``CurveConfig.ok_mu_t``, ``ok_s_t``: reason ``ocp_wide``): K's own
  ok allows +-30 % at 2 sigma, which on firm soil moves mu_T by 0.13;
* **unchecked**: the same numbers, from a curve nobody checked for this wheel.  Never ``ok``: an ``ok``
  soil estimate becomes ``uncertain``, and the reason says why and what to do.

One code path for the live OCP publisher (:class:`soilocp.estimation.ocp_stage.OcpStage`, N = 1) and the
offline and batched chain (:class:`soilocp.estimation.batch.BatchPipeline`).  No numpy: the OCP publisher
loads none.
"""

from __future__ import annotations

import math
import operator
from typing import Optional, Sequence

from soilocp.estimation.settings_model import core_values
from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate

from soilocp import _core
from soilocp.estimation.config import PipelineConfig
from soilocp.model.vehicle import curve_checked

#: Why an unchecked curve's OCPs are not served as ok, and what a user can do about it.
UNCHECKED_REASON = (
    "OCPs from the paper's traction curve, which nobody checked for this wheel: name a calibration file as the "
    "vehicle's traction_curve (soilocp calibrate-drive, or soilocp calibrate --from-drive on drives with a traction "
    "sweep past the peak)"
)
#: Why a learnt curve's OCPs are not served as ok, and the way to ok.
LEARNT_REASON = ("OCPs from the traction curve this drive showed (S_T {s_t:.2f} +- {s_t_std:.2f}, mu_T {mu_t:.2f} +- "
                 "{mu_t_std:.2f}): the learnt peak rests on the observer's split of traction and resistance and is "
                 "not checked; fit a calibration from such drives (soilocp calibrate --from-drive) and name it as the "
                 "vehicle's traction_curve")
#: Why a checked curve's OCPs are not served as ok where K's band spreads them beyond a controller's tolerance.
WIDE_REASON = ("K's 2-sigma band spreads the OCPs by mu_T +-{mu:.2f}, S_T +-{s:.2f}: wider than a controller acts on "
               "(curve.ok_mu_t {ok_mu:.2f}, ok_s_t {ok_s:.2f})")
#: Why a calibrated curve's OCPs beyond its soils are not served as ok.
BEYOND_REASON = ("K {k:.0f} is beyond the soils the wheel's calibration was fitted over ({lo:.0f}...{hi:.0f}): its "
                 "OCPs are extrapolated; drive the calibration on this soil too")


#: what ``OcpEstimate(**fields)`` runs (the whole validation), without the keyword call
_validate_ocp = OcpEstimate.__pydantic_validator__.validate_python


def ocp_message(soil: SoilEstimate, values: Sequence[float], curve: str = "model", bands=(None, None),
                status: Optional[str] = None, reason: Optional[str] = None,
                reason_code: Optional[str] = None) -> OcpEstimate:
    """An OcpEstimate from a soil estimate and its K's (mu_T, S_T, S_E, TE at S_E) in the core's order
    (:data:`soilocp.model.ocp_values.OCP_NAMES`; NaN: none); ``curve`` says where they come from, ``bands`` is
    (mu_T's, S_T's) 1-sigma of a learnt curve, ``status``, ``reason`` and ``reason_code`` replace the soil
    estimate's (:class:`WheelCurve` decides them)."""
    have = soil.soil_strength is not None or curve == "learnt"  # a learnt curve's OCPs are its own, not K's
    mu_t, s_t, s_e, te = (None if not have or math.isnan(v) else float(v) for v in values)
    k, log_std = soil.soil_strength, soil.log_k_std
    low, high = (None, None) if k is None or log_std is None else (k * math.exp(-2.0 * log_std),
                                                                    k * math.exp(2.0 * log_std))
    return _validate_ocp(dict(
        vehicle_id=soil.vehicle_id, seq=soil.seq, stamp=soil.stamp, soil_strength=k,
        soil_strength_std=soil.soil_strength_std, soil_strength_low=low, soil_strength_high=high,
        soil_class=soil.soil_class,
        soil_class_confidence=soil.soil_class_confidence, status=status or soil.status,
        reason=soil.reason if reason is None else reason, reason_code=reason_code or soil.reason_code, mu=soil.mu,
        mu_determined=soil.mu_determined, slip=soil.slip, mu_T=mu_t, S_T=s_t, S_E=s_e, te_at_S_E=te,
        curve=curve, mu_T_std=bands[0], S_T_std=bands[1], held_for_s=soil.held_for_s, unusable=soil.unusable,
    ))


class WheelCurve:
    """The wheel-curve learners of N vehicles and the rule that makes each OCP record (module doc)."""

    def __init__(self, config: PipelineConfig, n_vehicles: int):
        c = config.curve
        self.config = c
        self.checked = curve_checked(config.vehicle)
        self.kernel = config.constants.kernel
        #: a calibration's soils, widened by CurveConfig.k_range_margin (None: not limited)
        kr = config.constants.k_range
        self.k_range = None if kr is None else (kr[0] / c.k_range_margin, kr[1] * c.k_range_margin)
        # the learnt mu_T's band carries the torques' common scale at the torque constant's prior, which K's band
        # starts from (the level of the traction the learner fits, which no shape shows)
        self.bank = _core.CurveBank(n_vehicles, core_values(c, "curve"), config.soil.gross_scale_sigma) \
            if c.enabled and not self.checked else None  # a checked curve keeps its own OCPs: nothing to learn

    def fit(self, j: int, soil: SoilEstimate):
        """Vehicle ``j``'s learnt curve after this soil estimate (None: none yet, or learning is off)."""
        if self.bank is None:
            return None
        used = tuple(map(operator.and_, soil.informative, soil.mu_determined))
        return self.bank.step(j, soil.stamp, soil.slip, soil.mu, used, soil.ground_speed_latency)

    def record(self, j: int, soil: SoilEstimate, values: Sequence[float]) -> OcpEstimate:
        """Vehicle ``j``'s OCP record: the soil estimate, the model's (mu_T, S_T, S_E, TE at S_E) at its K
        (:data:`soilocp.model.ocp_values.OCP_NAMES`' order; NaN: none), and the learnt curve where it holds."""
        fit = self.fit(j, soil)
        k = soil.soil_strength
        learnt = not self.checked and fit is not None and fit.shown
        # a learnt peak does not rest on K: it stands where the paper's curve cannot describe the traction at
        # any K (model_mismatch, which serves no K below the model's floor), though not where the data do
        # not determine the state now (not_observable)
        if learnt and (k is not None or soil.status == "model_mismatch"):
            s_t_std, mu_t_std = fit.s_t_band, fit.mu_t_band
            why = LEARNT_REASON.format(s_t=fit.s_t, s_t_std=s_t_std, mu_t=fit.mu_t, mu_t_std=mu_t_std)
            return _flagged(soil, (fit.mu_t, fit.s_t, math.nan, math.nan), why, "curve_learnt",
                            curve="learnt", bands=(mu_t_std, s_t_std))
        if k is None:
            return ocp_message(soil, values)
        if not self.checked:
            return _flagged(soil, values, UNCHECKED_REASON, "curve_unchecked", curve="unchecked")
        bands = self.model_bands(soil)
        if self.k_range is not None:
            lo, hi = self.k_range
            if not lo <= k <= hi:
                return _flagged(soil, values, BEYOND_REASON.format(k=k, lo=lo, hi=hi), "curve_extrapolated",
                                bands=bands)
        mu_std, s_std = bands
        cfg = self.config
        if soil.status == "ok" and mu_std is not None and (2.0 * mu_std > cfg.ok_mu_t or 2.0 * s_std > cfg.ok_s_t):
            why = WIDE_REASON.format(mu=2.0 * mu_std, s=2.0 * s_std, ok_mu=cfg.ok_mu_t, ok_s=cfg.ok_s_t)
            return _flagged(soil, values, why, "ocp_wide", bands=bands)
        return ocp_message(soil, values, bands=bands)

    def model_bands(self, soil: SoilEstimate) -> tuple[Optional[float], Optional[float]]:
        """(mu_T's, S_T's) 1-sigma that the soil estimate's K band carries through the checked curve
        (``soilocp._core.ocp_band``); (None, None) without a band (the paper's soil method gives none: its
        records keep the soil estimate's status)."""
        if soil.log_k_std is None:
            return None, None
        mu_std, s_std = _core.ocp_band(soil.soil_strength, soil.log_k_std, self.kernel)
        return (None, None) if math.isnan(mu_std) else (mu_std, s_std)


def _flagged(soil: SoilEstimate, values, why: str, code: str, **kw) -> OcpEstimate:
    """The OCP record of a curve that keeps it from being ok: ``uncertain`` where the soil estimate was ok, its
    reason after the soil estimate's, and the reason code the soil estimate's own where it is flagged already (that
    reason comes first), else ``code``."""
    flagged_before = soil.status != "ok" and soil.reason_code != "none"
    return ocp_message(soil, values, status="uncertain" if soil.status == "ok" else soil.status,
                       reason=f"{soil.reason}; {why}" if soil.reason else why,
                       reason_code=soil.reason_code if flagged_before else code, **kw)
