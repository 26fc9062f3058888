"""The wheel's own traction curve: a calibration file that a vehicle file names.

The paper's constants C1..C6 were fitted on one testbed wheel; a robot's wheels have their own
curve, and the OCPs follow from the curve (docs/method.md §14).  A calibration file holds the
constants fitted for one robot's wheels (``soilocp calibrate --from-drive``, ``soilocp
calibrate-drive``), each with its 1-sigma band, the correlations of the fitted ones, the reason
for any it could not fit, and how well the fitted curve predicted held-out parts of the drives.
The vehicle file names it (``"traction_curve": "my-robot.curve.json"``); the estimator then uses
its constants in place of the paper's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field

from soilocp.model.constants import ModelConstants
from soilocp.model.files import read_json

CALIBRATION_SCHEMA_ID = "soilocp.wheel_calibration/1"


class WheelCalibration(BaseModel):
    """One robot's wheel calibration: the traction constants and what the data said about them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_id: str = Field(CALIBRATION_SCHEMA_ID, description="File format and version")
    constants: ModelConstants = Field(description="The wheel's constants C1..C6 (eqs. 3-6) and the S_E line (eq. 10)")
    std: dict[str, float] = Field(default_factory=dict, description="1-sigma of each fitted constant")
    correlation: dict[str, dict[str, float]] = Field(
        default_factory=dict, description="Correlation coefficients between the fitted constants")
    not_fitted: dict[str, str] = Field(
        default_factory=dict, description="Constants kept at their prior value, each with the reason the data could not fit it")
    soils: list[dict] = Field(
        default_factory=list, description="The soils the drives crossed: each one's fitted K, its 1-sigma and the samples it had")
    held_out: Optional[dict] = Field(
        None, description="How well the curve fitted on part of the data predicts the rest: rms of the traction "
                          "residual (fit and held-out), and the held-out segments' OCPs against the fitted curve's")
    extra: dict = Field(default_factory=dict,
                        description="What else a calibration drive measured: torque constant, payload, rolling resistance, "
                                    "each with its band or the reason it could not be fitted")
    sources: list[str] = Field(default_factory=list, description="The sensor logs the calibration was fitted on")


def load_calibration(path: str | Path) -> WheelCalibration:
    """Read a calibration file; errors name the file and the field."""
    p = Path(path)
    data = read_json(p, "calibration file")
    try:
        return WheelCalibration.model_validate(data)
    except Exception as exc:  # pydantic's ValidationError, said with the file's name
        raise ValueError(f"calibration file {str(p)!r}: {exc}") from exc


def save_calibration(cal: WheelCalibration, path: str | Path) -> None:
    Path(path).write_text(json.dumps(cal.model_dump(), indent=2) + "\n")
