"""The estimation chain's configuration, :class:`PipelineConfig`, and its loader: pydantic only, no numpy,
so that a service which needs the settings but not the physics (the OCP publisher) loads none
(tests/test_lean_processes.py)."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from soilocp.estimation.curve_config import CurveConfig
from soilocp.estimation.observer_config import ObserverConfig
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.model.constants import DEFAULT_CONSTANTS, DEFAULT_DEADBAND, DEFAULT_FLOOR, ModelConstants, load_constants
from soilocp.model.files import read_json
from soilocp.model.vehicle import PAPER_WHEEL, DEFAULT_VEHICLE, VehicleParams, load_vehicle, user_vehicle_data


class PipelineConfig(BaseModel):
    """Everything the estimation chain needs: vehicle, model constants, observer and soil settings."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    vehicle: VehicleParams = DEFAULT_VEHICLE
    constants: ModelConstants = DEFAULT_CONSTANTS
    observer: ObserverConfig = Field(default_factory=ObserverConfig)
    soil: SoilConfig = Field(default_factory=SoilConfig)
    torque_scale: TorqueScaleConfig = Field(default_factory=TorqueScaleConfig)
    curve: CurveConfig = Field(default_factory=CurveConfig)
    slip_deadband: float = Field(DEFAULT_DEADBAND, ge=0, description="m/s below which slip is not informative (eq. 1)")
    slip_floor: float = Field(DEFAULT_FLOOR, gt=0, description="floor of eq. 1's denominator, m/s")


def load_pipeline_config(
    path: str | Path | None = None,
    *,
    vehicle: str | Path | None = None,
    constants: str | Path | None = None,
) -> PipelineConfig:
    """Read a pipeline config (JSON, shape of PipelineConfig; every key optional) and apply
    separate vehicle / constants files on top.  Errors name the file and the field."""
    data: dict = {}
    if path is not None:
        p = Path(path)
        data = read_json(p, "config file")
        if not isinstance(data, dict):
            raise ValueError(f"config file {str(p)!r} must hold a JSON object")
        if "vehicle" in data:  # a user's robot: its curve is unchecked unless the file names one
            data = {**data, "vehicle": user_vehicle_data(data["vehicle"], p.parent)}
    try:
        cfg = PipelineConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"config {str(path)!r}: {exc}") from exc
    update = {}
    if vehicle is not None:
        update["vehicle"] = load_vehicle(vehicle)
    if constants is not None:
        update["constants"] = load_constants(constants)
    else:  # the wheel's calibration file, named by the vehicle: its constants replace the paper's
        curve = update.get("vehicle", cfg.vehicle).traction_curve
        if curve is not None and curve != PAPER_WHEEL:
            from soilocp.model.wheel_curve import load_calibration

            update["constants"] = load_calibration(curve).constants
    return cfg.model_copy(update=update) if update else cfg
