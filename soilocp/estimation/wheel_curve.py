"""The wheel's own traction curve in the OCP records: learnt where the drive shows it, and flagged where
nobody checked it (docs/method.md §14, §19).

The paper's constants C1..C6 describe one testbed wheel; the OCPs follow from the wheel's curve, not from K
alone.  :class:`WheelCurve` runs the compiled core's learners (``soilocp._core.CurveBank``, one per vehicle:
soilocp/_core/src/curve.rs) on each soil estimate's (slip, net traction) pairs and decides each record's OCPs:

* **learnt**, for a wheel whose curve nobody checked: where the current soil's pairs spread over the bend (the
  peak lies inside them), mu_T and S_T are the fitted curve's, with their 1-sigma (the fit's own, the
  learner's systematic error ``CurveConfig.s_t_sys``, ``mu_t_sys``, and for S_T the peak's flatness
  ``tilt_sys``).  Never ``ok``: the learnt peak rests on the observer's split of gross traction into net and
  resistance (docs/method.md §12, §19), which places it within +-0.05 on most simulated drives but not on
  all (scripts/curve_learner_errors.py); the reason says how to make the curve checked.  S_E is null: eq.
  10's line is the paper wheel's, and the efficiency line is not learnt.  A checked curve keeps its own
  OCPs;
* **model**: mu_T, S_T, S_E from K and the configured constants, whose curve somebody checked for this
  wheel: the paper's testbed wheel (the built-in rover) or a calibration file (the vehicle's
  ``traction_curve``);
* **unchecked**: the same numbers, from a curve nobody checked for this wheel.  Never ``ok``: an ``ok``
  soil estimate becomes ``uncertain``, and the reason says why and what to do.

One code path for the live OCP publisher (:class:`soilocp.estimation.ocp_stage.OcpStage`, N = 1) and the
offline and batched chain (:class:`soilocp.estimation.batch.BatchPipeline`).  No numpy: the OCP publisher
loads none.
"""

from __future__ import annotations

import math
from typing import Sequence

from schemas.pipeline import OcpEstimate, SoilEstimate

from soilocp import _core
from soilocp.estimation.config import PipelineConfig
from soilocp.model.vehicle import curve_checked

#: The reason an unchecked curve's OCPs are not served as ok, and what a user can do about it.
UNCHECKED_REASON = (
    "OCPs from the paper's traction curve, which nobody checked for this wheel: drive a traction sweep (slips "
    "past the peak) so that the curve is learnt, or name a calibration file as the vehicle's traction_curve "
    "(soilocp calibrate --from-drive)"
)


#: The reason a learnt curve's OCPs are not served as ok, and the way to ok.
LEARNT_REASON = "OCPs from the traction curve this drive showed"
LEARNT_NEXT = (": the learnt peak rests on the observer's split of traction and resistance and is not checked; fit "
               "a calibration from such drives (soilocp calibrate --from-drive) and name it as the vehicle's "
               "traction_curve")


class WheelCurve:
    """The wheel-curve learners of N vehicles and the rule that makes each OCP record (module doc)."""

    def __init__(self, config: PipelineConfig, n_vehicles: int):
        c = config.curve
        self.config = c
        self.checked = curve_checked(config.vehicle)
        #: a calibration's soils, widened by CurveConfig.k_range_margin (None: not limited)
        kr = config.constants.k_range
        self.k_range = None if kr is None else (kr[0] / c.k_range_margin, kr[1] * c.k_range_margin)
        self.bank = _core.CurveBank(n_vehicles, c.window, c.change_window, c.change_shift, c.change_pairs, c.slip_min,
                                    c.slip_max, c.min_pairs, c.min_beyond, c.peak_span, c.interval) if c.enabled else None

    def fit(self, j: int, soil: SoilEstimate):
        """Vehicle ``j``'s learnt curve after this soil estimate (None: none yet, or learning is off)."""
        if self.bank is None:
            return None
        used = tuple(i and d for i, d in zip(soil.informative, soil.mu_determined))
        return self.bank.step(j, soil.stamp, soil.slip, soil.mu, used)

    def bands(self, fit) -> tuple[float, float]:
        """(S_T's, mu_T's) 1-sigma of a learnt curve: the fit's own, the learner's systematic error, and for S_T
        the peak's flatness, which turns a tilt of the observed traction into a shift of the peak."""
        cfg = self.config
        curvature = fit.a * fit.c3 * fit.c3 * math.exp(-fit.c3 * fit.s_t)  # |mu''(S_T)|
        flat = cfg.tilt_sys / curvature if curvature > 0 else math.inf
        return math.hypot(fit.s_t_std, cfg.s_t_sys, flat), math.hypot(fit.mu_t_std, cfg.mu_t_sys)

    def record(self, j: int, soil: SoilEstimate, values: Sequence[float]) -> OcpEstimate:
        """Vehicle ``j``'s OCP record: the soil estimate, the model's (mu_T, S_T, S_E, TE at S_E) at its K
        (:data:`soilocp.model.ocp_values.OCP_NAMES`' order; NaN: none), and the learnt curve where it holds."""
        from soilocp.estimation.ocp_stage import ocp_message

        fit = self.fit(j, soil)
        cfg = self.config
        if not self.checked and fit is not None and fit.shown and soil.soil_strength is not None:
            s_t_std, mu_t_std = self.bands(fit)
            learnt = f"{LEARNT_REASON} (S_T {fit.s_t:.2f} +- {s_t_std:.2f}, mu_T {fit.mu_t:.2f} +- {mu_t_std:.2f}){LEARNT_NEXT}"
            status = "uncertain" if soil.status == "ok" else soil.status
            reason = f"{soil.reason}; {learnt}" if soil.reason else learnt
            return ocp_message(soil, (fit.mu_t, fit.s_t, math.nan, math.nan), curve="learnt", bands=(mu_t_std, s_t_std),
                               status=status, reason=reason, reason_code=_code(soil, status, "curve_learnt"))
        k = soil.soil_strength
        k_range = self.k_range
        if k is not None and k_range is not None and not k_range[0] <= k <= k_range[1]:
            beyond = (f"K {k:.0f} is beyond the soils the wheel's calibration was fitted over ({k_range[0]:.0f}..."
                      f"{k_range[1]:.0f}): its OCPs are extrapolated; drive the calibration on this soil too")
            status = "uncertain" if soil.status == "ok" else soil.status
            return ocp_message(soil, values, status=status, reason=f"{soil.reason}; {beyond}" if soil.reason else beyond,
                               reason_code=_code(soil, status, "curve_extrapolated"))
        if self.checked or k is None:
            return ocp_message(soil, values)
        status = "uncertain" if soil.status == "ok" else soil.status
        reason = f"{soil.reason}; {UNCHECKED_REASON}" if soil.reason else UNCHECKED_REASON
        return ocp_message(soil, values, curve="unchecked", status=status, reason=reason,
                           reason_code=_code(soil, status, "curve_unchecked"))


def _code(soil: SoilEstimate, status: str, curve_code: str) -> str:
    """The record's reason code: the soil estimate's own where it is flagged already (its reason comes first),
    else the curve's, which alone keeps an ok soil estimate from being an ok record."""
    return soil.reason_code if soil.status != "ok" and soil.reason_code != "none" else curve_code
