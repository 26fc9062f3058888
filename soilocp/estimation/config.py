"""The estimation chain's configuration, :class:`PipelineConfig`, and its loader: pydantic only, no numpy,
so that a service which needs the settings but not the physics (the OCP publisher) loads none
(tests/test_lean_processes.py)."""

from __future__ import annotations

import math
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from soilocp.estimation.curve_config import CurveConfig
from soilocp.estimation.observer_config import ObserverConfig
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.model.constants import DEFAULT_CONSTANTS, DEFAULT_DEADBAND, DEFAULT_FLOOR, ModelConstants, load_constants
from soilocp.model.files import read_json
from soilocp.model.settings_errors import describe_validation_error
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
    slip_floor: float = Field(
        DEFAULT_FLOOR, gt=0, description="floor of eq. 1's denominator, m/s: keeps a standstill's slip finite; below "
        "slip_deadband the slip informs nothing, so the floor only bounds the numbers", json_schema_extra={"audience": "internal"})
    torque_constant: float = Field(
        1.0, gt=0, description="N m at the wheel per unit of the log's wheel_torque column: every logged torque is "
        "multiplied by it before the chain (a motor current's constant, as soilocp calibrate-torque fits it; 1: the "
        "log holds wheel torques in N m)")


def load_pipeline_config(
    path: str | Path | None = None,
    *,
    vehicle: str | Path | None = None,
    constants: str | Path | None = None,
    torque_constant: str | float | None = None,
) -> PipelineConfig:
    """Read a pipeline config (JSON, shape of PipelineConfig; every key optional) and apply
    separate vehicle / constants files and a torque constant (a number or a calibrate-torque JSON,
    :func:`torque_constant_from`) on top.  Errors name the file and the field."""
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
        raise ValueError(describe_validation_error(exc, f"config file {str(path)!r}", PipelineConfig)) from exc
    update = {}
    if vehicle is not None:
        update["vehicle"] = load_vehicle(vehicle)
    if constants is not None:
        update["constants"] = load_constants(constants)
    else:
        update.update(calibrated_constants(update.get("vehicle", cfg.vehicle)))
    if torque_constant is not None:
        update["torque_constant"] = torque_constant_from(torque_constant)
    return cfg.model_copy(update=update) if update else cfg


def torque_constant_from(value: str | float) -> float:
    """The torque constant a user gives: a number (N m per unit of the logged torque) or the JSON file
    ``soilocp calibrate-torque --json`` writes (its ``k``, when its status is ok).  ValueError says which
    value or file and why it cannot be used."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        k = float(value)
    else:
        text = str(value)
        try:
            k = float(text)
        except ValueError:
            p = Path(text)
            if not p.is_file():
                raise ValueError(f"torque constant {text!r}: neither a number nor an existing file (give N m per "
                                 "unit of the logged torque, or the JSON of soilocp calibrate-torque --json)") from None
            data = read_json(p, "torque-constant file")
            if not isinstance(data, dict) or "k" not in data:
                raise ValueError(f"torque-constant file {text!r}: no 'k' in it (expected the JSON of soilocp "
                                 "calibrate-torque --json)")
            if data.get("status", "ok") != "ok" or data["k"] is None:
                raise ValueError(f"torque-constant file {text!r}: the calibration did not determine k (status "
                                 f"{data.get('status')!r}: {data.get('reason', '')}); calibrate on a drive with "
                                 "straight accelerations and brakings (docs/import.md)")
            k = data["k"]
            if not isinstance(k, (int, float)) or isinstance(k, bool):
                raise ValueError(f"torque-constant file {text!r}: k {k!r} is not a number")
            k = float(k)
    if not (math.isfinite(k) and k > 0):
        raise ValueError(f"torque constant {value!r}: must be a finite number > 0 (N m per unit of the logged torque)")
    return k


def calibrated_constants(vehicle: VehicleParams) -> dict:
    """``{"constants": ...}`` of the wheel's calibration file that ``vehicle`` names as its traction_curve (its
    constants replace the paper's), or ``{}`` for the paper's wheel and a curve nobody checked."""
    curve = vehicle.traction_curve
    if curve is None or curve == PAPER_WHEEL:
        return {}
    from soilocp.model.wheel_curve import load_calibration

    return {"constants": load_calibration(curve).constants}
