"""Vehicle parameters (the geometry of eqs. 11-25) and their JSON file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from soilocp.model.files import read_json


#: ``traction_curve`` of a wheel that is the paper's testbed wheel (the constants it was fitted on)
PAPER_WHEEL = "paper"


class VehicleParams(BaseModel):
    """Rigid 4-wheel, differentially steered rover (paper Fig. 6), SI units.

    Wheel numbering (paper): 1 left-rear, 2 left-front, 3 right-front, 4 right-rear.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    mass: float = Field(60.0, gt=0, description="m, kg")
    yaw_inertia: float = Field(3.5, gt=0, description="I_z, kg m^2 (eq. 11)")
    wheel_inertia: float = Field(0.04, gt=0, description="I_omega, kg m^2 (eq. 13)")
    wheel_radius: float = Field(0.15, gt=0, description="R_w, m (eqs. 1, 13)")
    a: float = Field(0.27, gt=0, description="CoM to rear axle, m")
    b: float = Field(0.23, gt=0, description="CoM to front axle, m")
    c: float = Field(0.25, gt=0, description="CoM to left wheels, m")
    d: float = Field(0.25, gt=0, description="CoM to right wheels, m")
    h: float = Field(0.30, gt=0, description="CoM height above ground, m")
    drive: Literal["per_wheel", "per_side"] = Field(
        "per_wheel",
        description=(
            "per_wheel: each wheel has its own motor, speed and torque. per_side: skid-steer with one "
            "motor per side; the two wheels of a side share one measured speed and one torque, logged "
            "as the side's speed on both wheels and half the side's torque on each"
        ),
    )

    wheel_speed_reading: Literal["instant", "interval_mean"] = Field(
        "instant",
        description=(
            "instant: the logged wheel speed is the speed at the sample's stamp. interval_mean: it is an "
            "encoder count difference over the interval since the previous reading (the mean speed over "
            "it, lagging by omega_dot * interval / 2), which the observer then corrects for; the "
            "simulator's encoders read this way"
        ),
    )

    traction_curve: Optional[str] = Field(
        PAPER_WHEEL,
        description=(
            "Whose traction curve the wheels follow (the constants C1..C6 of eqs. 3-6). 'paper': the paper's "
            "testbed wheel, checked by its authors (the built-in rover, which the simulator drives on that "
            "wheel). A path: a calibration file (soilocp calibrate --from-drive, soilocp calibrate-drive) "
            "whose constants the estimator then uses; relative to the vehicle file. null: nobody has checked "
            "the curve for this wheel, so the OCPs rest on the paper's curve and are not served as ok until "
            "the drive itself has shown the curve (a traction sweep). A vehicle file that leaves the key out "
            "means null: the file describes another robot than the built-in one"
        ),
    )

    @model_validator(mode="after")
    def _finite(self):
        for name, v in self.model_dump().items():
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
        return self

    @property
    def wheel_x(self) -> tuple[float, float, float, float]:
        """Longitudinal wheel positions from the CoM (x forward), wheels 1..4."""
        return (-self.a, self.b, self.b, -self.a)

    @property
    def wheel_y(self) -> tuple[float, float, float, float]:
        """Lateral wheel positions from the CoM (y left), wheels 1..4."""
        return (self.c, self.c, -self.d, -self.d)


DEFAULT_VEHICLE = VehicleParams()


def curve_checked(vehicle: VehicleParams) -> bool:
    """Whether someone has checked the traction curve of this vehicle's wheels (the paper's testbed
    wheel, or a calibration file): the OCPs of a curve nobody checked are never served as ``ok``."""
    return vehicle.traction_curve is not None


def user_vehicle_data(data: dict, base: Path | None = None) -> dict:
    """A vehicle description written by a user (a vehicle file, a config's ``vehicle``), ready for
    :class:`VehicleParams`: ``traction_curve`` left out means unchecked (None), not the built-in
    rover's wheel, and a calibration file's relative path is taken from ``base`` (the vehicle file's
    folder)."""
    if not isinstance(data, dict):
        return data
    out = dict(data)
    curve = out.setdefault("traction_curve", None)
    if isinstance(curve, str) and curve != PAPER_WHEEL and base is not None and not Path(curve).is_absolute():
        out["traction_curve"] = str((base / curve).resolve())
    return out


def load_vehicle(path: str | Path | None) -> VehicleParams:
    """Read a vehicle JSON file ``{"mass","yaw_inertia","wheel_inertia","wheel_radius","a","b","c","d","h"}``."""
    if path is None:
        return DEFAULT_VEHICLE
    p = Path(path)
    data = user_vehicle_data(read_json(p, "vehicle file"), p.parent)
    try:
        return VehicleParams.model_validate(data)
    except ValidationError as exc:
        from soilocp.model.settings_errors import describe_validation_error

        raise ValueError(describe_validation_error(exc, f"vehicle file {str(p)!r}", VehicleParams)) from exc
