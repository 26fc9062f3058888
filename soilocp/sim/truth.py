"""The simulator's ground truth record: what the rover really did at each sensor sample."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

TRUTH_SCHEMA_ID = "soilocp.truth_record/1"

_F4 = tuple[float, float, float, float]
_F3 = tuple[float, float, float]


class TruthRecord(BaseModel):
    """Ground truth of the simulated rover at one sensor sample (same vehicle_id / seq / stamp).

    Per-wheel lists are in the paper's order: 1 left-rear, 2 left-front, 3 right-front, 4 right-rear.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, title="TruthRecord", json_schema_extra={"$id": TRUTH_SCHEMA_ID})

    vehicle_id: str
    seq: int = Field(ge=0)
    stamp: float = Field(ge=0, description="s, equal to the sensor sample's stamp")
    mode: Literal["cruise", "excitation"] = Field(description="Wheel-speed controller mode")
    segment: int = Field(ge=0, description="Index of the terrain segment under the CoM")
    soil_class: str = Field(description="Soil class of the segment under the CoM")
    soil_strength: float = Field(gt=0, description="True soil strength K under the CoM")
    wheel_soil_strength: _F4 = Field(description="True K under each wheel (front wheels cross changes first)")
    grade: float = Field(description="Grade under the CoM, rad, > 0 = climb (pitch = -grade)")
    cross_slope: float = Field(description="Cross-slope under the CoM, rad, > 0 = left side up (roll = +cross_slope)")
    roll: float = Field(description="True roll, rad (REP-103, > 0 left side up)")
    pitch: float = Field(description="True pitch, rad (REP-103, > 0 nose down; < 0 on a climb)")
    distance: float = Field(description="Distance travelled by the CoM, m")
    heading: float = Field(description="Yaw angle relative to the start, rad")
    x: float = Field(default=0.0, description="CoM x in the drive's map frame, m (the start pose's; 0 at the start by default)")
    y: float = Field(default=0.0, description="CoM y in the drive's map frame, m")
    yaw_rate: float = Field(description="True yaw rate, rad/s, > 0 turning left")
    slip: _F4 = Field(description="Slip per wheel, eq. 1 with V_i = V - yaw_rate*y_i (> 0 driving)")
    mu: _F4 = Field(description="Net traction coefficient per wheel, eq. 6 (F_DP / Fz)")
    motion_resistance: _F4 = Field(description="Motion-resistance coefficient per wheel, eq. 4 (= gross - mu)")
    gross_traction: _F4 = Field(description="Gross traction coefficient per wheel, eq. 3 (what the wheel's eq. 13 sees)")
    normal_force: _F4 = Field(description="Normal force per wheel, N (zero-warp solution from specific_force)")
    ground_speed: float = Field(description="Longitudinal speed of the CoM, m/s")
    wheel_speed: _F4 = Field(description="True wheel angular speeds, rad/s")
    wheel_torque: _F4 = Field(description="True motor torques at the wheels, N m")
    specific_force: _F3 = Field(description="True specific force at the CoM, m/s^2 (body x fwd, y left, z up)")
    speed_command: float = Field(description="Vehicle speed set-point, m/s (ramps up from rest)")
    slip_command: float | None = Field(description="Front-axle slip set-point in excitation mode (None in cruise)")
    mu_T: float = Field(description="Maximum traction coefficient for the true K under the CoM (eq. 8)")
    S_T: float = Field(description="Slip of maximum traction for the true K under the CoM (eq. 7 corrected)")
    S_E: float = Field(description="Slip of best efficiency for the true K under the CoM (eq. 10)")
    motor_work: float = Field(description="Work done by the four motors since the start, J")
    kinetic_energy: float = Field(description="Body translation + yaw + wheel spin kinetic energy, J")
    potential_energy: float = Field(description="m g (height gained since the start), J")
    slip_dissipation: float = Field(description="Energy dissipated by slip, sum Fz g (omega R_w - V_i) dt, J (>= 0)")
    resistance_work: float = Field(
        description="Work of motion resistance, sum Fz r V_i dt, J (can be < 0 for K < ~125, docs/method.md §8)"
    )
    yaw_dissipation: float = Field(description="Energy dissipated by the skid-steer moment M_zR, J (>= 0)")
