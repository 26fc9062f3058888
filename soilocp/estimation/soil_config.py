"""Settings of the soil-strength estimator (docs/method.md §4, §9, §11-13) and its statuses: pydantic only,
no numpy (:mod:`soilocp.estimation.config`); what one step takes and gives is :mod:`soilocp.estimation.soil_state`."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Status = Literal["ok", "uncertain", "holding", "no_estimate", "not_observable", "model_mismatch"]


class SoilConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    method: Literal["bayes", "paper"] = Field("bayes", description="bayes (default) or paper (eqs. 36-37, sign fixed)")
    measurement: Literal["gross", "net"] = Field("gross", description="Compare gross (eq. 3) or net (eq. 6) traction")
    slip_min: float = Field(0.04, gt=0, lt=1, description="|S| below this carries no usable information")
    slip_max: float = Field(0.95, gt=0, le=1, description="|S| above this is wheel spin / lock")
    k_min: float = Field(5.0, gt=0, description="Lower end of the K grid")
    k_max: float = Field(5000.0, gt=0, description="Upper end of the K grid")
    grid_points: int = Field(241, ge=20, le=5000, description="Nodes of the K grid, evenly spaced in ln K "
                             "from k_min to k_max")
    q_log_k: float = Field(0.1, ge=0, description="Random walk of ln K, 1/sqrt(s)")
    change_per_metre: float = Field(
        0.5, ge=0, description="Hazard of an abrupt terrain change per metre travelled (mixing the belief with the "
        "uniform change prior): terrain changes where the robot goes, not while it stands; 0.5 = a new soil every 2 m "
        "on average, which lets K follow a change within about a second of informative slip"
    )
    change_evidence: float = Field(
        1.0, ge=0, description="s of informative samples over which the data's evidence for a terrain change is "
        "weighed: K is reported from the no-change belief until a change is more probable than not and the recent "
        "data favour it (docs/method.md §9); 0 = always the pooled belief's median"
    )
    stay_forgetting: float = Field(
        0.5, ge=0, le=1, description="Share of the change hazard at which the no-change belief forgets old "
        "evidence (p^(1 - a h)): without it the belief keeps every sample since the last change, the observer's "
        "early errors with them"
    )
    model_sigma: float = Field(0.03, gt=0, description="Model / unmodelled error of the coefficient, 1-sigma")
    slip_sigma: float = Field(0.005, ge=0, description="Uncertainty of the filtered slip at speed, 1-sigma")
    speed_sigma: float = Field(
        0.008, ge=0, description="Error of the filtered speeds, m/s: slip error grows as speed_sigma / speed at low speed"
    )
    slip_snr: float = Field(3.0, ge=0, description="A wheel is used only when |S| >= slip_snr x its slip uncertainty")
    gate_smoothing: float = Field(
        0.15, ge=0, description="Time constant (s) of the low-pass slip the gate looks at: gating on the raw, noisy "
        "slip keeps the samples whose noise pushed |S| up and biases K low (docs/method.md §9)"
    )
    outlier_prob: float = Field(0.02, ge=0, lt=1, description="Weight of the outlier component of the likelihood")
    temper: float = Field(
        0.15, gt=0, le=1, description="Likelihood exponent of a sample temper_interval s after the previous one: the "
        "observer's gross traction carries a per-wheel bias that samples do not average out (docs/method.md §9, "
        "'Information per second')"
    )
    temper_interval: float = Field(
        0.01, gt=0, description="s: the sample interval temper is stated for; a sample dt after the previous one "
        "weighs temper x dt / temper_interval, up to temper_max"
    )
    temper_max: float = Field(
        0.3, gt=0, le=1, description="Largest likelihood exponent of one sample: at low rates consecutive observer "
        "outputs are correlated (lag-one r ~0.4 at 20 Hz), so a sample carries less than its interval's share"
    )
    uncertain_log_sigma: float = Field(
        0.13, gt=0, description="ln K 1-sigma above which the estimate is 'uncertain': 'ok' promises K within +-30 %, "
        "which a band can only vouch for where its 2-sigma, 2 x 0.13 = ln 1.30, lies inside it"
    )
    hold_after: float = Field(0.5, gt=0, description="s without an informative update before status 'holding'")
    expire_after: float = Field(10.0, gt=0, description="s of 'holding' after which the estimate is withdrawn")
    gross_scale_sigma: float = Field(
        0.05, ge=0, description="Prior 1-sigma relative error of the gross traction common to all samples (torque "
        "constant, mass): it does not average out, so it enters K's band as a systematic term, narrowed where the data "
        "tell the scale apart (a braking axle)"
    )
    radius_sigma: float = Field(0.01, ge=0, description="1-sigma relative error of the wheel radius (a systematic slip error)")
    max_input_age: float = Field(
        0.5, gt=0, description="s: no wheel informs K while the ground speed reading has not changed for longer "
        "(a held reading from a slow driver is not a measurement, docs/method.md §13; between its refreshes the observer "
        "carries the speed on the accelerometer)"
    )
    min_load_fraction: float = Field(
        0.25, ge=0, lt=1, description="A wheel informs K only while its normal force is at least this share of "
        "the static m g / 4: the torque balance hardly determines a nearly unloaded wheel's gross traction"
    )
    fresh_age: float = Field(
        0.05, ge=0, description="s: a wheel informs K only at samples whose speed and torque readings are both at most "
        "this old: between a slow stream's refreshes the observer's slip or gross traction rests on a held value"
    )
    evidence_window: float = Field(3.0, gt=0, description="s: memory of the mismatch and systematic-error statistics")
    mismatch_nis: float = Field(
        4.0, gt=0, description="Mean normalised residual (NIS) of the used wheels at the estimate above which the "
        "traction curve does not explain the (slip, traction) pairs: status model_mismatch"
    )
    axle_mismatch_z: float = Field(
        2.5, ge=0, description="The front-only and rear-only beliefs' disagreement in ln K, in units of its 1-sigma, "
        "above which - now and for more than half of evidence_window - the status is model_mismatch: the normal forces "
        "(mass, centre of mass) or one axle's torque constant are off (docs/method.md §16); 0 = no check"
    )
    axle_scale_sigma: float = Field(
        0.03, ge=0, description="1-sigma relative difference of gross traction between the axles that is ordinary "
        "model error (tyres, load transfer): mapped to ln K through the traction curve's sensitivity, it widens the "
        "disagreement the axle check tolerates (at K = 300 a 3 % difference is ~12 % in K)"
    )
    mismatch_min_evidence: float = Field(1.0, gt=0, description="s of informative samples in the window before judging a mismatch")
    observable_max_gross_sigma: float = Field(
        0.4, gt=0, description="A wheel whose gross traction 1-sigma exceeds this cannot inform K (torque balance undetermined)"
    )
    learning_rate: float = Field(0.5, gt=0, le=1, description="lambda of eq. 36 (paper method)")
    k_initial: float = Field(120.0, gt=0, description="K_0 of the paper method")
