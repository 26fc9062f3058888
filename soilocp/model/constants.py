"""Model constants: the improved Brixius constants (paper §2.2), the S_E line (eq. 10) and the
reference soil strengths, in one configuration object that a calibration can replace.

The defaults are the paper's, defined once in the compiled core (``soilocp._core.Constants.PAPER``,
soilocp/_core/src/constants.rs).  ``soilocp calibrate`` writes a file of the same shape, and every
command that takes ``--constants FILE`` loads it with :func:`load_constants`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator

from soilocp._core import Constants as _CoreConstants
from soilocp.model.files import read_json

# Paper §2.2 and §2.2 (EST): soil strength of the testbed soils.  "firm" is ours: the paper's
# firm-soil drive (Fig. 15a) gives no number; anything clearly above grass.
REFERENCE_SOILS: dict[str, float] = {
    "sand": 50.0,
    "gravel": 80.0,
    "EST": 120.0,
    "grass": 200.0,
    "firm": 300.0,
}


#: g_n, m/s^2: the standard gravity (eq. 20's g, the rest specific force of eqs. 16-19)
STANDARD_GRAVITY = 9.80665
#: Below this speed (m/s) slip is reported but flagged as not informative (docs/method.md §6):
#: quantised encoders and a noisy ground speed make eq. 1 meaningless when both speeds are small.
DEFAULT_DEADBAND = 0.15
#: Floor on eq. 1's denominator (m/s), so that standstill gives a finite slip (docs/method.md §10).
DEFAULT_FLOOR = 0.05


#: A constant that ``soilocp calibrate`` / ``calibrate-drive`` fits from data and writes to a constants file,
#: which the vehicle file's ``traction_curve`` or ``--constants`` names: a user gives the file, not the numbers
_CALIBRATED = {"audience": "calibration"}


#: the paper's constants, the core's (its Constants.PAPER): the defaults below
_PAPER = _CoreConstants.PAPER


class ModelConstants(BaseModel):
    """Improved Brixius constants C1..C6 (eqs. 3-6), the S_E line (eq. 10) and model options."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    C1: float = Field(_PAPER.c1, gt=0, description="Gross-traction amplitude (eq. 3)", json_schema_extra=_CALIBRATED)
    C2: float = Field(_PAPER.c2, gt=0, description="Soil-strength saturation rate, 1/K (eq. 3)", json_schema_extra=_CALIBRATED)
    C3: float = Field(_PAPER.c3, gt=0, description="Slip rate of the traction rise (eq. 3)", json_schema_extra=_CALIBRATED)
    C4: float = Field(_PAPER.c4, description="Constant of gross traction and motion resistance (eqs. 3-4)", json_schema_extra=_CALIBRATED)
    C5: float = Field(_PAPER.c5, description="K-inverse motion-resistance term (eq. 4)", json_schema_extra=_CALIBRATED)
    C6: float = Field(_PAPER.c6, gt=0, description="Slip-proportional motion resistance over sqrt(K) (eq. 4)", json_schema_extra=_CALIBRATED)
    alpha: float = Field(_PAPER.alpha, description="S_E = (K - alpha) / beta (eq. 10)", json_schema_extra=_CALIBRATED)
    beta: float = Field(_PAPER.beta, description="S_E = (K - alpha) / beta (eq. 10)", json_schema_extra=_CALIBRATED)
    bridge_slip: float = Field(
        _PAPER.bridge_slip,
        ge=0,
        lt=0.1,
        description=(
            "Half-width of the linear bridge through S=0 (docs/method.md §8): eq. 6 jumps from -C5/K "
            "to +C5/K at zero slip; inside |S| < bridge_slip the model is linear, in the traction curve and in "
            "the observer's motion resistance alike. 0 = as printed."
        ),
        json_schema_extra={"audience": "internal"},
    )
    k_range: Optional[tuple[float, float]] = Field(
        None,
        description=(
            "The soil strengths the constants were fitted over (a calibration's soils, on its own scale of K). "
            "Outside them the OCPs are an extrapolation and are not served as ok. None: not limited (the paper's "
            "constants, whose testbed soils the simulator's scenarios span)"
        ),
        json_schema_extra=_CALIBRATED,
    )
    soils: dict[str, float] = Field(
        default_factory=lambda: dict(REFERENCE_SOILS),
        description="Soil class -> reference soil strength K (calibrated per soil)",
        json_schema_extra=_CALIBRATED,
    )

    @field_validator("soils")
    @classmethod
    def _soils_positive(cls, v: dict[str, float]) -> dict[str, float]:
        if not v:
            raise ValueError("soils must name at least one soil class")
        for name, k in v.items():
            if not (math.isfinite(k) and k > 0):
                raise ValueError(f"soils[{name!r}] must be a finite K > 0, got {k!r}")
        return dict(sorted(v.items(), key=lambda kv: kv[1]))

    @field_validator("beta")
    @classmethod
    def _beta_nonzero(cls, v: float) -> float:
        if v == 0 or not math.isfinite(v):
            raise ValueError(f"beta must be finite and non-zero (it divides eq. 10), got {v!r}")
        return v

    # (the numbers it was built from, the compiled core's Constants): kept with the numbers because
    # model_copy(update=...) copies private attributes without re-validating
    _kernel: tuple | None = PrivateAttr(default=None)

    @property
    def kernel(self):
        """These constants as the compiled core's ``soilocp._core.Constants`` (built once)."""
        # read through __dict__ and __pydantic_private__: pydantic's attribute hooks cost 8 us per call here,
        # and the OCP stage asks at every new K
        fields = self.__dict__
        key = tuple([fields[name] for name in _KERNEL_FIELDS])
        private = self.__pydantic_private__
        cached = private.get("_kernel")
        if cached is None or cached[0] != key:
            cached = (key, _CoreConstants(*key))
            private["_kernel"] = cached
        return cached[1]

    def __eq__(self, other: object) -> bool:
        """Constants of the same values are equal whether or not either has built its kernel (a cache, not a
        value: pydantic's own equality would compare it too)."""
        if not isinstance(other, BaseModel):
            return NotImplemented
        return type(other) is type(self) and self.__dict__ == other.__dict__


_KERNEL_FIELDS = ("C1", "C2", "C3", "C4", "C5", "C6", "alpha", "beta", "bridge_slip")


DEFAULT_CONSTANTS = ModelConstants()


def load_constants(path: str | Path | None) -> ModelConstants:
    """Load a constants file (JSON, the shape of :class:`ModelConstants`); None -> the paper's."""
    if path is None:
        return DEFAULT_CONSTANTS
    return ModelConstants.model_validate(read_json(path, "constants file"))


def save_constants(constants: ModelConstants, path: str | Path) -> None:
    Path(path).write_text(json.dumps(constants.model_dump(), indent=2) + "\n")
