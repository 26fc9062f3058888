"""Settings of the wheel-curve learner (:mod:`soilocp.estimation.wheel_curve` says what it learns and how):
pydantic only, no numpy (:mod:`soilocp.estimation.config`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class CurveConfig(BaseModel):
    """Settings of the wheel's traction-curve learner (docs/method.md §19)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Learn the curve of a wheel nobody checked where the drive shows it, and "
                                            "serve its OCPs, flagged (False: the OCPs always follow from K and the "
                                            "configured constants)")
    window: float = Field(8.0, gt=0, description="s: the (slip, traction) pairs of the last window are fitted")
    change_window: float = Field(0.5, gt=0, description="s: the recent wheel-samples whose mean departure from the "
                                                        "learnt curve tells a change of soil")
    change_shift: float = Field(0.04, gt=0, description="Mean departure of those wheel-samples' traction from the "
                                                        "learnt curve beyond which the soil changed: the older samples "
                                                        "are dropped and the curve is learnt anew")
    change_pairs: int = Field(20, ge=1, description="Recent wheel-samples needed to judge a change of soil")
    slip_min: float = Field(0.02, ge=0, description="|slip| below this is not fitted (eq. 6's zero-slip bridge, "
                                                    "eq. 1's noise at small slip)")
    slip_max: float = Field(0.95, gt=0, description="|slip| above this is not fitted (a spinning or locked wheel)")
    min_pairs: int = Field(200, ge=5, description="Wheel-samples of the current soil before a fit (2 s of two "
                                                  "sweeping wheels at 50 Hz)")
    min_beyond: int = Field(40, ge=1, description="Wheel-samples on each side of the fitted S_T, within peak_span of it, "
                                                  "for the peak to count as shown (not extrapolated, nor bridged over "
                                                  "a gap in the slips)")
    peak_span: float = Field(0.1, gt=0, description="Slip distance from the fitted S_T within which min_beyond "
                                                    "wheel-samples on each side show the bend")
    interval: float = Field(0.5, ge=0, description="s between two fits (and at once after a change of soil)")
    s_t_sys: float = Field(0.02, ge=0, description="Systematic 1-sigma added to the learnt S_T's band, whatever the "
                                                   "curve's shape (scripts/curve_learner_errors.py measures the learnt "
                                                   "peak against simulated truth)")
    tilt_sys: float = Field(0.06, ge=0, description="Systematic error of the observed net traction per unit slip: a "
                                                    "tilt that moves the fitted peak by tilt_sys / |mu''(S_T)|, added to "
                                                    "S_T's band, so that a flat peak is not reported as precise (the "
                                                    "observer's traction reads 0.005-0.02 high past the peak and as "
                                                    "much low near zero slip on simulated drives)")
    mu_t_sys: float = Field(0.02, ge=0, description="Systematic 1-sigma added to the learnt mu_T's band")
    k_range_margin: float = Field(1.25, ge=1, description="A calibrated curve's OCPs are served as ok for K within its "
                                                          "fitted soils' range widened by this factor either way; "
                                                          "beyond, they are extrapolated and flagged")
