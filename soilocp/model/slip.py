"""Longitudinal slip ratio, eq. 1, with defined behaviour at zero and low speed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from soilocp import _core
from soilocp.model.checks import as_float_array, positive_scalar
from soilocp.model.constants import DEFAULT_DEADBAND, DEFAULT_FLOOR  # noqa: F401 (eq. 1's defaults, used from here)


@dataclass(frozen=True)
class Slip:
    """Slip per wheel (eq. 1 with the floor and deadband of docs/method.md §6, §10), shape of the
    wheel-speed input, and where it informs traction."""

    slip: np.ndarray  #: eq. 1 per wheel, in [-1, 1] for forward motion
    informative: np.ndarray  #: bool per wheel: True where slip carries information on traction


def slip_ratio(
    wheel_speed,
    ground_speed,
    wheel_radius: float,
    *,
    deadband: float = DEFAULT_DEADBAND,
    floor: float = DEFAULT_FLOOR,
) -> Slip:
    """Slip ratio S = (omega R_w - V_x) / max(V_x, omega R_w), eq. 1.

    Departures from the print (docs/method.md §6, §10):

    * the denominator is max(|V_x|, |omega R_w|, floor), so S is finite at standstill
      (the print divides 0 by 0);
    * with speeds of either sign the same formula gives S > 0 when the wheel drives (rim faster
      than the ground) and S < 0 when it brakes, for forward motion;
    * where max(|V_x|, |omega R_w|) < deadband the slip is flagged not informative: no soil
      update may use it.

    ``wheel_speed`` may be any shape (e.g. 4 wheels or N x 4 samples); ``ground_speed`` broadcasts.
    """
    w = as_float_array("wheel_speed", wheel_speed)
    v = as_float_array("ground_speed", ground_speed)
    r = positive_scalar("wheel_radius", wheel_radius)
    if deadband < 0 or floor <= 0:
        raise ValueError(f"deadband must be >= 0 and floor > 0, got deadband={deadband}, floor={floor}")
    try:
        np.broadcast_shapes(w.shape, v.shape)
    except ValueError as exc:
        raise ValueError(
            f"wheel_speed (shape {w.shape}) and ground_speed (shape {v.shape}) do not broadcast"
        ) from exc
    return slip_ratio_unchecked(w, v, r, deadband, floor)


def slip_ratio_unchecked(wheel_speed, ground_speed, wheel_radius: float, deadband: float, floor: float) -> Slip:
    """:func:`slip_ratio` (eq. 1 as corrected there) for arguments already checked: the per-sample path.
    Eq. 1 itself is the compiled core's (soilocp/_core/src/slip.rs), written once for every caller."""
    s, scale = _core.slip_ratio(np.asarray(wheel_speed, dtype=float), np.asarray(ground_speed, dtype=float),
                                float(wheel_radius), float(floor))
    return Slip(slip=s, informative=scale >= deadband)
