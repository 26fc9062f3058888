"""What a calibration drive measured: the wheel's curve, and the force balance's torque constant or payload and
rolling resistance (``soilocp calibrate-drive``; the protocol is :mod:`soilocp.control.calibration_drive`).

* **The curve**: :func:`soilocp.analysis.drive_calibration.calibrate_from_drives` on every sample of the drive
  (the sweeps show the bend and the peak).  A soil whose sweeps did not reach past its fitted peak
  (``slip_top`` < S_T + :data:`PEAK_MARGIN`) did not show the peak: if no soil did, the drive showed too little,
  and the error says which ``--max-slip`` would.
* **The force balance** (docs/method.md §15, :func:`soilocp.analysis.torque_constant.fit_torque_constant`) on the
  swing phases only (accelerating and braking at small slips; the sweeps' windows add no acceleration spread,
  and their slip's resistance is not rolling resistance).  On flat ground it fixes one scale, k = m_file /
  m_true x (torque constant): a torque constant and a payload cannot both come from it.  ``known="torque"`` (the
  sensor log's torques are N m, the sensor-log contract) reads it as the true mass, hence the payload; ``known=
  "mass"`` (the vehicle file's mass is right) as the torque constant.  The other one is reported as not fitted,
  with that reason.  The intercept is the rolling resistance (N, and as a coefficient of the weight).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Literal, Sequence

from soilocp.analysis.drive_calibration import calibrate_from_drives
from soilocp.analysis.torque_constant import TorqueSelection, fit_torque_constant
from soilocp.estimation.pipeline import PipelineConfig
from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.model.wheel_curve import WheelCalibration

#: a soil showed its peak when its sweeps reached this far past the fitted S_T
PEAK_MARGIN = 0.05


class DriveTooLittle(ValueError):
    """The drive did not show what the calibration needs; the message says what to change."""


@dataclass
class DriveFitResult:
    calibration: WheelCalibration
    messages: list[str] = field(default_factory=list)


def _round(v, n=5):
    return None if v is None else round(float(v), n)


def force_balance(samples: Sequence[dict], vehicle, known: Literal["torque", "mass"] = "torque") -> dict:
    """The torque constant, payload and rolling resistance from the swing phases' samples (module doc), each
    ``{"value", "std"}`` or ``{"value": null, "reason"}``."""
    m = vehicle.mass
    try:
        fit = fit_torque_constant(samples, vehicle, TorqueSelection())
    except ValueError as exc:
        fit, why = None, str(exc)
    else:
        why = fit.reason
    if fit is None or fit.status != "ok":
        hint = ("; a longer drive (more swing cycles) or a higher --max-speed (the swings' acceleration grows with it) "
                "gives the force balance more to work on")
        reason = f"the force balance could not fix the torque/mass scale: {why}{hint}"
        out = {"torque_constant": {"value": None, "reason": reason}, "payload": {"value": None, "reason": reason},
               "rolling_resistance": {"value": None, "reason": reason}}
        if fit is not None:
            out["force_balance"] = {k: v for k, v in fit.as_dict().items() if k != "excluded"}
        return out
    k, k_std = fit.k, fit.k_std
    other = ("one drive on flat ground fixes only the ratio of the torque constant to the mass (docs/method.md §15): "
             "{what} is taken as {value}")
    if known == "torque":
        mass = m / k
        mass_std = m * k_std / k ** 2
        f_rr, f_rr_std = fit.resistance / k, math.hypot(fit.resistance_std / k, fit.resistance * k_std / k ** 2)
        out = {
            "torque_constant": {"value": 1.0, "reason": other.format(what="the torque channel", value="N m as logged (1.0)")},
            "payload": {"value": _round(mass - m, 3), "std": _round(mass_std, 3), "mass": _round(mass, 3),
                        "vehicle_file_mass": m, "unit": "kg"},
        }
    else:
        mass, mass_std = m, 0.0
        f_rr, f_rr_std = fit.resistance, fit.resistance_std
        out = {
            "torque_constant": {"value": _round(k, 5), "std": _round(k_std, 5),
                                "unit": "N m of wheel torque per unit of the logged torque"},
            "payload": {"value": None, "reason": other.format(what="the mass", value=f"the vehicle file's ({m:g} kg)")},
        }
    w = mass * STANDARD_GRAVITY
    out["rolling_resistance"] = {"value": _round(f_rr / w, 5), "std": _round(f_rr_std / w, 5), "force_N": _round(f_rr, 3),
                                 "force_std_N": _round(f_rr_std, 3), "unit": "share of the weight"}
    out["force_balance"] = {"k": _round(k, 5), "k_std": _round(k_std, 5), "windows_used": fit.windows_used,
                            "accel_spread": _round(fit.accel_spread, 4), "r2": _round(fit.r2, 4), "assumed_known": known}
    return out


def fit_drive(lines: Sequence[str], phases: Sequence[str], config: PipelineConfig, *, name: str = "calibration drive",
              known: Literal["torque", "mass"] = "torque", max_slip: float | None = None,
              protocol: dict | None = None) -> DriveFitResult:
    """The calibration file's content from a drive's sensor lines (JSON) and each line's protocol phase.

    Raises :class:`DriveTooLittle` (the message says what to change) when no soil showed its curve's peak or no
    soil had enough informative samples."""
    if len(lines) != len(phases):
        raise ValueError(f"{len(lines)} sensor lines but {len(phases)} phases: one phase per line")
    if not lines:
        raise DriveTooLittle("no sensor sample was recorded: the robot published nothing during the drive")
    try:
        fit = calibrate_from_drives([(name, list(lines))], config)
    except ValueError as exc:
        raise DriveTooLittle(f"the drive did not show the traction curve ({exc}); raise --max-slip past the robot's "
                             "traction peak (0.6-0.8 on most soils), or drive longer (--duration up to 60 s)") from None
    cal = fit.calibration
    messages = list(fit.messages)
    shown = [s for s in cal.soils if s["slip_top"] >= s["S_T"] + PEAK_MARGIN]
    if not shown:
        need = max(s["S_T"] for s in cal.soils) + 2 * PEAK_MARGIN
        top = max(s["slip_top"] for s in cal.soils)
        raise DriveTooLittle(
            f"no soil's sweep reached past its traction peak: slips reached {top:.2f}, the fitted peaks lie at S_T "
            + ", ".join(f"{s['S_T']:.2f}" for s in cal.soils)
            + f"; raise --max-slip to at least {min(need, 0.9):.2f}" + (f" (was {max_slip:g})" if max_slip else ""))
    for s in cal.soils:
        if s not in shown:
            messages.append(f"soil {s['soil']}: slips reached {s['slip_top']:.2f}, not past its fitted peak S_T "
                            f"{s['S_T']:.2f} + {PEAK_MARGIN}: its K rests on the curve the other soils showed")
    swing = [json.loads(line) for line, ph in zip(lines, phases) if ph == "swing"]
    extra = force_balance(swing, config.vehicle, known) if swing else {
        q: {"value": None, "reason": "the drive had no accelerate-and-brake phase"}
        for q in ("torque_constant", "payload", "rolling_resistance")}
    extra["drive"] = {"samples": len(lines), "phases": {p: phases.count(p) for p in dict.fromkeys(phases)},
                      "soils_past_peak": len(shown), **({"protocol": protocol} if protocol else {})}
    cal = cal.model_copy(update={"extra": extra})
    return DriveFitResult(cal, messages)
