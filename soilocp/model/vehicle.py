"""Vehicle parameters (the geometry of eqs. 11-25) and their JSON file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from soilocp.model.files import read_json


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


def load_vehicle(path: str | Path | None) -> VehicleParams:
    """Read a vehicle JSON file ``{"mass","yaw_inertia","wheel_inertia","wheel_radius","a","b","c","d","h"}``."""
    if path is None:
        return DEFAULT_VEHICLE
    p = Path(path)
    data = read_json(p, "vehicle file")
    try:
        return VehicleParams.model_validate(data)
    except ValidationError as exc:
        from soilocp.model.settings_errors import describe_validation_error

        raise ValueError(describe_validation_error(exc, f"vehicle file {str(p)!r}", VehicleParams)) from exc
