"""Which wheels the longitudinal model describes now: travel direction, and the conditions where eq. 1
and the traction law of docs/method.md §11 cannot give a wheel's traction (docs/method.md §17).

Per wheel and sample, from the observer's filtered speeds and gross traction:

* the **travel direction** d = sgn(V_i) (the ground speed under the wheel; at standstill the rim's
  direction): eq. 1, eqs. 3, 4 and 6 are written for forward travel, and a wheel travelling backwards
  is their mirror image (docs/method.md, Conventions): slip S = d (R_w omega - V_i) / max(|V_i|,
  |R_w omega|, floor) is > 0 when the wheel drives in its direction of travel, and its gross
  traction in that frame is d times the body-frame one;
* an **unusable** code, 0 where the wheel may inform K, else the first that applies of ``skid_turn``,
  ``slip_beyond_eq1`` (|S| > 1: the rim and the ground under it move in opposite directions; eq. 1
  is bounded by 1 by definition), ``stopped_unpowered`` (the body moves, the wheel stands, and no
  torque acts on it: no slip the wheel's torque balance explains), ``stall`` (the ground speed is
  near zero while a torque acts: slip is ~1 at any soil and creep is beyond the curve's
  calibration).  ``skid_turn``: the vehicle turns about a point within its track (the sides' rims
  turn in opposite directions, or the inner wheels' ground speed reverses); the wheels slide
  sideways, eq. 12's lateral resistance, which the longitudinal model does not describe (measured in
  docs/robustness.md, "Skid turns").

The pipeline's slip gate keeps the codes only where the wheel's speed and torque readings are new
(between a slow stream's refreshes the filtered speed is a prediction, and a held wheel informs no K
anyway).  The codes are computed in the compiled core (soilocp/_core/src/soil/usability.rs, the slip gate's
soil/gate.rs); :data:`REASONS` names them, :func:`describe` words them, and the soil bank counts them (:attr:`soilocp.estimation.soil_strength.SoilBank.unusable_by_reason`).
"""

from __future__ import annotations

from soilocp import _core
from soilocp.estimation.settings_model import model_from_core

#: code -> name, 0 = usable: soilocp/_core/src/soil/usability.rs's table
REASONS: tuple[str, ...] = tuple(getattr(_core.SoilGridBank, "unusable_names", ()))
if REASONS[:1] != ("",):  # 0 is "usable" wherever a code is tested for truth
    raise ImportError(f"soilocp._core's unusable codes {REASONS} do not start with the usable one: rebuild the core "
                      "(make setup)")
USABLE, SLIP_BEYOND_EQ1, STOPPED_UNPOWERED, STALL, SKID_TURN = (REASONS.index(name) for name in (
    "", "slip_beyond_eq1", "stopped_unpowered", "stall", "skid_turn"))

#: what each code means, for the record's reason
EXPLAIN = {
    SLIP_BEYOND_EQ1: "|slip| > 1 (rim and ground move in opposite directions: beyond eq. 1)",
    STOPPED_UNPOWERED: "wheel stopped under no torque while the body moves",
    STALL: "stall: ground speed near zero under torque",
    SKID_TURN: "skid turn: the wheels slide sideways (eq. 12's lateral resistance), which the longitudinal "
               "model does not describe",
}

#: Thresholds of the unusable codes (docs/method.md §17), declared in the compiled core
#: (soilocp/_core/src/soil/usability.rs); whether the body moves is the pipeline's ``slip_deadband``.
UsabilityLimits = model_from_core("UsabilityLimits", "usability", __name__,
                                  "Thresholds of the wheels' unusable codes (docs/method.md §17).")


def describe(codes) -> str:
    """The reason text for the unusable codes of one sample's wheels (4,): each condition once, with its
    wheels (numbered 1 LR, 2 LF, 3 RF, 4 RR)."""
    parts = []
    for c in sorted({int(x) for x in codes if int(x)}, reverse=True):
        wheels = ", ".join(str(i + 1) for i, x in enumerate(codes) if int(x) == c)
        parts.append(f"{EXPLAIN[c]} (wheel{'s' if ',' in wheels else ''} {wheels})")
    return "; ".join(parts)
