"""Settings, state and soil classes of the soil-strength estimator (docs/method.md §4, §9, §11-13)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from soilocp import _core
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants

Status = Literal["ok", "uncertain", "holding", "no_estimate", "not_observable", "model_mismatch"]


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
        0.13, gt=0, description="ln K 1-sigma above which the estimate is 'uncertain': 'ok' promises K within +-30 % "
        "(issue 27), which a band can only vouch for where its 2-sigma, 2 x 0.13 = ln 1.30, lies inside it"
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


@dataclass(frozen=True)
class SoilState:
    """What an estimator reports after each step: K is a belief's median (the no-change belief's until
    the data take a terrain change, docs/method.md §9), soil_strength_std and log_k_std half the
    pooled belief's 16-84 % interval (in K and in ln K) with the systematic terms."""

    soil_strength: Optional[float]
    soil_strength_std: Optional[float]
    log_k_std: Optional[float]
    soil_class: Optional[str]
    soil_class_confidence: Optional[float]
    status: Status
    reason: str
    last_update_stamp: Optional[float]
    used: tuple[bool, bool, bool, bool]
    #: s since the last informative update when K is reported (0: this sample informed it); None: no K
    held_for_s: Optional[float] = None
    #: per wheel: why the longitudinal model does not describe it now (soilocp.estimation.wheel_usability), '' usable
    unusable: tuple[str, str, str, str] = ("", "", "", "")


_CLASS_BOUNDS: dict[tuple, tuple[list[str], np.ndarray]] = {}  # per soil table: classify runs every sample


def class_bounds(constants: ModelConstants) -> tuple[list[str], np.ndarray]:
    """Soil classes ordered by K and their boundaries in ln K (geometric means of neighbours).

    The weakest class starts at half its reference K: below that no class applies (the traction
    constants were fitted on the reference soils; a K far under the weakest is an extrapolation,
    typically a wrong torque scale), so that mass counts for no class.  Computed once per soil
    table (``classify`` runs on every sample)."""
    key = tuple(constants.soils.items())
    hit = _CLASS_BOUNDS.get(key)
    if hit is None:
        names = sorted(constants.soils, key=constants.soils.get)
        logs = np.log([constants.soils[n] for n in names])
        edges = np.concatenate([[logs[0] - math.log(2.0)], (logs[:-1] + logs[1:]) / 2.0, [np.inf]])
        edges.flags.writeable = False
        hit = _CLASS_BOUNDS[key] = (names, edges)
    return list(hit[0]), hit[1]


def _row(a) -> np.ndarray:
    """A 1-D float array, the argument itself where it is one (the core reads a view's base: slower)."""
    a = np.asarray(a, dtype=float)
    return a if a.ndim == 1 else a.reshape(-1)


def classify(soil_strength: float, log_k_std: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> tuple[str, float]:
    """Most probable soil class for ln K ~ N(ln K, sigma^2), and its probability (:func:`classify_many`)."""
    names, conf = classify_many(np.array([math.log(soil_strength)]), np.array([log_k_std]), constants)
    return names[0], float(conf[0])


def classify_many(log_k: np.ndarray, log_k_std: np.ndarray,
                  constants: ModelConstants = DEFAULT_CONSTANTS) -> tuple[list[str], np.ndarray]:
    """For n beliefs ln K ~ N(log_k, log_k_std^2) (n,): the most probable soil class of each and its
    probability (the Gaussian's mass between the class boundaries of :func:`class_bounds`; the compiled
    core's soil/classes.rs, with the C library's erf, as math.erf)."""
    names, edges = class_bounds(constants)
    i, conf = _core.soil_classes(_row(log_k), _row(log_k_std), edges)
    return [names[j] for j in i.tolist()], conf


@dataclass
class SoilInputs:
    """What the soil update takes for k vehicles, from the observer's outputs (:class:`soilocp.estimation.slip_gate.SlipGate`):
    arrays (k, 4) unless marked; one struct, passed whole (:meth:`soilocp.estimation.soil_strength.SoilBank.update`)."""

    slip: np.ndarray  # eq. 1 at each wheel's ground speed V - psi_dot y_i
    informative: np.ndarray
    observed: np.ndarray
    variance: np.ndarray
    slip_sigma: np.ndarray
    gate_slip: np.ndarray  # the low-pass slip the gate decides on (docs/method.md §9)
    gate_sigma: np.ndarray
    held: np.ndarray  # no new speed and torque reading of the wheel now (SoilConfig.fresh_age)
    ground_stale: np.ndarray  # (k,) the ground speed's last reading is older than SoilConfig.max_input_age
    identifiable: np.ndarray  # (k,) False without an independent ground speed (slip, eq. 1, needs it)
    speed: np.ndarray  # (k,) filtered ground speed, m/s: the distance over which the soil may change
    span: np.ndarray | None  # (k, 4) s a wheel's pair stands for: a refresh interval (0: the sample's own; None: none)
    slip_ends: np.ndarray | None  # (k, 4, 2) a refresh pair's slip at its interval's start and end (None: no pair)
    unusable: np.ndarray | None = None  # (k, 4) int: soilocp.estimation.wheel_usability's code (0: usable)

    def arrays(self, k: int) -> SoilInputs:
        """These inputs of k vehicles as the core reads them (float64 / bool arrays of their shapes: the soil
        core's ``SoilGridBank.step`` takes the struct whole); ValueError naming a malformed or non-finite
        slip, observed, variance or slip_sigma."""
        f64, flag = (lambda a: np.asarray(a, dtype=float)), (lambda a: np.asarray(a, dtype=bool))
        quads = {}
        for name in ("slip", "observed", "variance", "slip_sigma"):
            a = f64(getattr(self, name))
            if a.shape != (k, 4) or not np.isfinite(a).all():
                raise ValueError(f"{name} must be a finite array of shape ({k}, 4), got {a!r}")
            quads[name] = a
        return SoilInputs(
            informative=flag(self.informative), gate_slip=f64(self.gate_slip), gate_sigma=f64(self.gate_sigma),
            held=flag(self.held), ground_stale=flag(self.ground_stale).reshape(k),
            identifiable=flag(self.identifiable).reshape(k), speed=f64(self.speed).reshape(k),
            span=None if self.span is None else f64(self.span),
            slip_ends=None if self.slip_ends is None else f64(self.slip_ends), unusable=self.unusable, **quads)
