"""Messages between the physics stages: normal forces -> observer -> soil strength -> OCP.

The same models are produced by the offline ``soilocp estimate`` path and by the live services,
and are serialised as JSON on Zenoh (floats round-trip exactly), so the live OCP stream equals
the offline one on the same log.
"""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from soilocp.schemas.codes import REASONS, STATUSES
from soilocp.schemas.position import EstimatePlace, GeoPosition, MapPosition
from soilocp.schemas.sensor import VehicleId

PIPELINE_SCHEMA_VERSION = 1

Quad = tuple[float, float, float, float]
BoolQuad = tuple[bool, bool, bool, bool]

#: Where an OCP record's mu_T and S_T come from (soilocp.estimation.wheel_curve).
OcpCurve = Literal["model", "learnt", "unchecked"]
_CURVE_DOC = (
    "Where mu_T and S_T come from. model: K and the configured constants, whose curve was checked for this wheel "
    "(the paper's testbed wheel, or a calibration file). learnt: the curve this drive showed on the current soil "
    "(a traction sweep), with its band in mu_T_std and S_T_std. unchecked: K and the paper's constants, which nobody "
    "checked for this wheel: such OCPs are never served as ok (the status says uncertain, the reason why)"
)
#: Status of a soil / OCP record, with its meaning: the compiled core's (soilocp.schemas.codes, generated from
#: soilocp/_core/src/codes.rs); ``stale`` is set by the live publisher.
EstimateStatus = Literal[tuple(STATUSES)]  # type: ignore[valid-type]
_STATUS_DOC = " | ".join(f"{name} ({meaning})" for name, (_, meaning) in STATUSES.items())

#: Machine-readable reason of a soil / OCP record, name -> meaning: the compiled core's (soilocp.schemas.codes).
#: The record's ``reason`` words the same reason with its numbers.
REASON_CODES: dict[str, str] = {name: meaning for name, (_, meaning) in REASONS.items()}
#: the codes set after the soil stage: the live publisher's and the OCP record's (the others are the soil stage's)
RECORD_REASON_CODES = tuple(name for name, (set_by, _) in REASONS.items() if set_by != "soil")
ReasonCode = Literal[tuple(REASON_CODES)]  # type: ignore[valid-type]
_REASON_CODE_DOC = ("Machine-readable reason (group and count by it; 'reason' words it with numbers): "
                    + "; ".join(f"{k}: {v}" for k, v in REASON_CODES.items()))
_CONFIRMED_DOC = (
    "True exactly when status is 'ok'. False: K, soil_class, its confidence and (OCP record) mu_T, S_T, S_E, where "
    "present, are the estimator's current best guess or a held value, NOT a confirmed estimate; a consumer that acts "
    "on them (a slip controller) must check this flag (or status == 'ok') first and otherwise fall back to its "
    "conservative setting. Derived from status when absent; a contradicting value is refused"
)


def _confirmed_given(value, info: ValidationInfo):
    """A given ``confirmed`` (a field validator, before the bool's own): null is filled in from ``status``, anything
    but the bool that the status implies is refused (the flag a consumer acts on must not disagree with the status
    it summarises).  Paired with :func:`_confirmed_absent`.  (Not one model validator before the fields: that one
    makes pydantic turn every record's JSON into Python objects first, 10 us a record at 100 Hz.)"""
    status = info.data.get("status")
    ok = status == "ok"
    if value is None:
        return ok
    if value is not ok:
        raise ValueError(f"confirmed={value!r} contradicts status {status!r}: confirmed is true "
                         "exactly when status is 'ok'")
    return value


def _confirmed_absent(record):
    """An absent ``confirmed`` from ``status`` (a model validator, after the fields), set as if given."""
    if "confirmed" not in record.__pydantic_fields_set__:
        object.__setattr__(record, "confirmed", record.status == "ok")
        record.__pydantic_fields_set__.add("confirmed")
    return record


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    schema_version: Literal[1] = PIPELINE_SCHEMA_VERSION
    vehicle_id: VehicleId
    seq: int = Field(ge=0, description="Sequence number of the sensor sample this derives from")
    stamp: float = Field(ge=0, description="Stamp of that sensor sample, s")


class NormalForces(_Message):
    """Normal force per wheel from the specific force (eqs. 16-25, zero-warp solution)."""

    normal_force: Quad = Field(description="F_z per wheel, N, wheels 1 LR, 2 LF, 3 RF, 4 RR; at or below 0 the "
                               "wheel has lifted off (the solution is not clipped); the observer takes a wheel at or "
                               "below 1 N (soilocp.estimation.observer_bank.LIFT_OFF_FORCE) as giving no traction "
                               "information")




class ObserverOutput(_Message):
    """Kalman observer estimate (eqs. 26-35, with the state chosen observable: docs/method.md §7)."""

    mu: Quad = Field(description="Net traction coefficient per wheel (F_DP/W, eq. 6's mu)")
    mu_var: Quad = Field(description="Variance of mu per wheel")
    resistance: Quad = Field(description="Longitudinal motion-resistance coefficient mu_xR per wheel (eq. 15)")
    gross: Quad = Field(description="Gross traction coefficient mu + mu_xR per wheel (what eq. 13 sees)")
    gross_var: Quad = Field(description="Variance of the gross coefficient per wheel")
    wheel_speed: Quad = Field(description="Filtered wheel angular speed, rad/s")
    ground_speed: float = Field(description="Filtered longitudinal CoM speed, m/s")
    ground_speed_measured: bool = Field(
        default=True, description="False: the sample had no independent ground speed (then slip and K are not identifiable)"
    )
    yaw_rate: float = Field(description="Filtered yaw rate, rad/s")
    normal_force: Quad = Field(description="F_z used in this step, N")
    mu_determined: BoolQuad = Field(
        default=(True,) * 4,
        description="Per wheel: the data determine mu (posterior 1-sigma small). False: the net / resistance split is "
        "carried by the model's assumptions only (e.g. a traction test with mirrored slips): do not use mu",
    )
    speed_age: Quad = Field(
        default=(0.0,) * 4, description="s since the wheel's speed reading was last a new measurement (a changed value, "
        "or a full-rate stream's quantised repeat; a held value ages: docs/method.md §13)"
    )
    ground_speed_age: float = Field(default=0.0, description="s since the ground speed reading was last a new measurement")
    torque_age: Quad = Field(default=(0.0,) * 4, description="s since the wheel's torque reading was last a new measurement")
    ground_speed_latency: float = Field(
        default=0.0, ge=0, description="s: the ground speed's latency measured against the accelerometer, by which the "
        "observer leads the reading (0: none determined; docs/method.md §13)"
    )
    ground_speed_excess: float = Field(
        default=0.0, ge=0, description="m/s: how far the ground speed's new readings stray from the filtered speed "
        "carried forward by the accelerometer, beyond the noise the observer assumes (rms over the last second, less "
        "r_ground_speed in quadrature): a GNSS-grade speed's noise, latency and hold, which the slip's uncertainty "
        "takes in (docs/method.md §20)"
    )
    interval: Quad = Field(
        default=(0.0,) * 4, description="s: > 0 where this sample is the refresh of a slow (held) stream while the other is "
        "read at every sample: a wheel speed's (the interval_* fields describe its interval, eq. 13 integrated) or a "
        "torque's (they describe this instant, eq. 13 from the readings; start = end); docs/method.md §13; 0 otherwise"
    )
    interval_gross: Quad = Field(
        default=(0.0,) * 4, description="The refresh's gross traction coefficient from the readings (the interval's mean)"
    )
    interval_gross_var: Quad = Field(default=(0.0,) * 4, description="Variance of interval_gross")
    interval_rim_start: Quad = Field(default=(0.0,) * 4, description="Rim speed R_w omega at the interval's start, m/s")
    interval_rim_end: Quad = Field(default=(0.0,) * 4, description="Rim speed R_w omega at the interval's end, m/s")
    interval_ground_start: Quad = Field(
        default=(0.0,) * 4, description="Ground speed at the wheel (V - yaw rate x y_i) at the interval's start, m/s"
    )
    interval_ground_end: Quad = Field(default=(0.0,) * 4, description="Ground speed at the wheel at the interval's end, m/s")
    interval_rim_sigma: Quad = Field(
        default=(0.0,) * 4, description="1-sigma of the rim speed's course between the readings against "
        "their chord, m/s"
    )
    interval_learning: BoolQuad = Field(
        default=(False,) * 4, description="Per wheel: one of its speed and torque streams refreshes slowly and the other is "
        "read at every sample, so K learns at the refreshes only, not from the observer's prediction between them"
    )
    speed_rejected: BoolQuad = Field(
        default=(False,) * 4, description="Per wheel: a new speed reading that the innovation gate rejected (and that "
        "did not re-anchor the wheel), or a held reading that the filtered speed has left by more than the gate's "
        "multiple of the encoder noise: the filtered speed, and the slip from it, are the prediction, not the "
        "measurement; such a wheel informs no K (docs/method.md §18)"
    )
    torque_scale: float = Field(
        default=1.0, gt=0, description="The common torque scale (motor constant x 1 / mass) the logged torques were "
        "multiplied by before this step: learnt online from the force balance (soilocp.estimation.torque_scale)"
    )
    torque_scale_std: Optional[float] = Field(
        default=None, ge=0, description="Its posterior 1-sigma, relative; None: the soil estimator's prior "
        "(soil.gross_scale_sigma), i.e. the online scale is off"
    )
    rejected_measurements: int = Field(ge=0, description="Measurement rows dropped by innovation gating this step")
    reset: bool = Field(description="True if the filter was (re)initialised at this sample")
    reset_reason: str = Field(
        default="", description="start | time_gap | stamp_backwards | non_finite_state | state_out_of_physics ('' if no reset)"
    )
    # the sample's position, passed on so that the soil estimate can say where it was made (docs/map.md)
    position: Optional[MapPosition] = Field(default=None, exclude_if=lambda v: v is None,
                                            description="The sample's local-frame position (optional)")
    geo: Optional[GeoPosition] = Field(default=None, exclude_if=lambda v: v is None,
                                       description="The sample's WGS84 position (optional)")


class SoilEstimate(_Message):
    """Soil strength K from per-wheel slip (eq. 1) and observed traction (eqs. 36-37, corrected)."""

    slip: Quad = Field(description="Slip per wheel from the filtered speeds (eq. 1), in the wheel's direction of "
                       "travel: > 0 driving, < 0 braking, forwards or backwards (docs/method.md §17)")
    informative: tuple[bool, bool, bool, bool] = Field(description="Wheel used for the K update this step")
    soil_strength: Optional[float] = Field(description="K estimate (null: no estimate)")
    soil_strength_std: Optional[float] = Field(description="1-sigma uncertainty of K")
    log_k_std: Optional[float] = Field(description="1-sigma uncertainty of ln K")
    soil_class: Optional[str] = Field(description="Most probable soil class")
    soil_class_confidence: Optional[float] = Field(description="Probability of that class, 0..1")
    status: EstimateStatus = Field(description=_STATUS_DOC)
    reason: str = Field(default="", description="Why there is no estimate / why it is flagged")
    reason_code: ReasonCode = Field(default="none", description=_REASON_CODE_DOC)
    confirmed: bool = Field(default=False, description=_CONFIRMED_DOC)
    last_update_stamp: Optional[float] = Field(description="Stamp of the last informative update")
    held_for_s: Optional[float] = Field(
        default=None, description="Age of K, s: time since the last sample that informed it (0: this one); null "
        "without K. A held K's band widens with this age"
    )
    unusable: tuple[str, str, str, str] = Field(
        default=("", "", "", ""), description="Per wheel, why the longitudinal model does not describe it now and it "
        "informs no K: slip_beyond_eq1 | stopped_unpowered | stall | skid_turn ('' usable; docs/method.md §17)"
    )
    mu: Quad = Field(description="Observed net traction per wheel (passed through for consumers)")
    mu_determined: BoolQuad = Field(default=(True,) * 4, description="Per wheel: mu is determined by the data")
    ground_speed_latency: float = Field(
        default=0.0, ge=0, description="s: the observer's ground-speed latency estimate the slips were formed under "
        "(passed through: the curve learner drops pairs formed under another; docs/method.md §19)"
    )
    where: Optional[EstimatePlace] = Field(
        default=None, exclude_if=lambda v: v is None,
        description="Contact patches of the wheels that informed this estimate (absent without a position or "
        "without an informing wheel): what the fleet soil map fuses (docs/map.md)")

    _confirmed = field_validator("confirmed", mode="before")(_confirmed_given)
    _confirmed_default = model_validator(mode="after")(_confirmed_absent)


class OcpEstimate(_Message):
    """Optimal control parameters from K (eqs. 7 corrected, 8, 10): one record per sensor sample."""

    soil_strength: Optional[float] = Field(description="K, null when there is no estimate")
    soil_strength_std: Optional[float] = Field(description="1-sigma of K")
    soil_strength_low: Optional[float] = Field(
        default=None, description="Lower end of K's 2-sigma band, K exp(-2 sigma) with sigma the 1-sigma of ln K: the "
        "estimator's belief is Gaussian in ln K, so the band is not symmetric about K and, where it is wide, K - 2 std "
        "does not describe it (null: no K)")
    soil_strength_high: Optional[float] = Field(
        default=None, description="Upper end of K's 2-sigma band, K exp(2 sigma) (null: no K); where the belief is wide "
        "the truth may lie far above K + 2 std but within this end")
    soil_class: Optional[str] = Field(default=None, description="Most probable soil class (null: no K); a class to act on only where confirmed is true")
    soil_class_confidence: Optional[float] = Field(default=None, description="Probability of that class, 0..1")
    mu_T: Optional[float] = Field(description="Maximum net traction coefficient (eq. 8)")
    S_T: Optional[float] = Field(description="Slip of maximum traction (eq. 7, sign corrected)")
    S_E: Optional[float] = Field(description="Slip of maximum tractive efficiency (eq. 10; null when the OCPs are "
                                             "the wheel's learnt curve's, whose efficiency line nobody fitted)")
    te_at_S_E: Optional[float] = Field(default=None, description="Tractive efficiency (eq. 9) at S_E, when defined")
    curve: OcpCurve = Field(default="model", description=_CURVE_DOC)
    mu_T_std: Optional[float] = Field(default=None, description="1-sigma of mu_T: the learnt curve's band, or, on a "
                                      "checked curve (curve 'model'), the one K's band carries through it (null: none)")
    S_T_std: Optional[float] = Field(default=None, description="1-sigma of S_T: the learnt curve's band, or, on a "
                                     "checked curve (curve 'model'), the one K's band carries through it (null: none)")
    status: EstimateStatus = Field(description=_STATUS_DOC)
    reason: str = Field(default="", description="Why there is no estimate / why it is flagged")
    reason_code: ReasonCode = Field(default="none", description=_REASON_CODE_DOC)
    confirmed: bool = Field(default=False, description=_CONFIRMED_DOC)
    mu: Quad = Field(description="Observed net traction per wheel")
    mu_determined: BoolQuad = Field(default=(True,) * 4, description="Per wheel: mu is determined by the data")
    slip: Quad = Field(description="Slip per wheel (eq. 1)")
    held_for_s: Optional[float] = Field(default=None, description="Age of K, s (the soil estimate's held_for_s)")
    unusable: tuple[str, str, str, str] = Field(
        default=("", "", "", ""), description="Per wheel: why it informs no K now (the soil estimate's unusable)"
    )

    _confirmed = field_validator("confirmed", mode="before")(_confirmed_given)
    _confirmed_default = model_validator(mode="after")(_confirmed_absent)
