"""Drive scenarios for the simulated rover: terrain segments (soil strength K, grade, cross-slope)
laid out along the distance travelled, a speed, a default duration and a controller mode.

Segments are placed by distance along the path: segment j covers [start_j, start_j + length_j)
and the last segment extends without end.  Each wheel sees the segment at its own position
(distance of the CoM + the wheel's x offset), so the front wheels cross a soil change first.

Angles follow the sensor-log conventions (REP-103, docs/method.md, Conventions): ``grade`` > 0 is a climb
(the rover's pitch is -grade, nose up), ``cross_slope`` > 0 means the ground rises to the left
(the rover's roll is +cross_slope, left side up, so the right wheels are the lower ones).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from soilocp.model.constants import REFERENCE_SOILS

Mode = Literal["cruise", "excitation"]
MODES: tuple[str, ...] = ("cruise", "excitation")


@dataclass(frozen=True)
class SweepParams:
    """Slip sweep of ``excitation`` mode (a traction test): the front wheels track a
    triangle wave of driving slip (eq. 1) from ``s_min`` up to ``s_max`` and back in ``period``
    seconds, then hold ``s_min`` for ``dwell`` seconds; the FRONT axle sweeps, the rear axle brakes
    to hold the speed.

    Why the front axle and the dwell (default rover: h/L = 0.6, 54 % of the weight on the front):

    * Sweeping the rear axle instead (front braking) is statically unstable on strong soil:
      acceleration moves load onto the driving rear and off the braking front, which accelerates
      the rover more; with |mu| ~ 1 the loop gain h (mu_r - mu_f) / L exceeds 1 (from K ~ 170
      on).  With the front sweeping and the rear braking the same loop is negative feedback.
    * The heavier front axle's mean traction over a bare 0.05-0.6 triangle exceeds what the
      lighter rear can brake even at its peak, on every soil (sand: 107 N vs 104 N; firm: 304 N
      vs 298 N), so without the dwell the rover would run away; the dwell at ``s_min`` lets the
      rear pull the speed back every cycle.  The default cycle is 0.8 s of triangle + 0.4 s of
      dwell = 1.2 s; the shorter the triangle, the smaller the speed excursion while the front
      is near its peak (measured, mean 1.00 m/s: sand 0.94..1.08, firm 0.77..1.26).  A governor still
      cuts the sweep if the cycle-mean speed runs away (the truth records the actual set-point).
    """

    s_min: float = 0.05
    s_max: float = 0.6
    period: float = 0.8
    dwell: float = 0.4

    def __post_init__(self) -> None:
        for name in ("s_min", "s_max", "period", "dwell"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"sweep {name} must be a finite number, got {v!r}")
        if not 0.0 <= self.s_min < self.s_max < 0.95:
            raise ValueError(
                f"sweep slips must satisfy 0 <= s_min < s_max < 0.95, got s_min={self.s_min}, s_max={self.s_max}"
            )
        if self.period <= 0:
            raise ValueError(f"sweep period must be > 0 s, got {self.period}")
        if self.dwell < 0:
            raise ValueError(f"sweep dwell must be >= 0 s, got {self.dwell}")

    def slip_at(self, t: float) -> float:
        """s_min at t = 0, s_max at period/2, s_min at period, held until period + dwell; repeats."""
        tc = t % (self.period + self.dwell)
        if tc >= self.period:
            return self.s_min
        tri = 1.0 - abs(2.0 * tc / self.period - 1.0)
        return self.s_min + (self.s_max - self.s_min) * tri


@dataclass(frozen=True)
class Segment:
    """One stretch of terrain: soil class and strength K, grade and cross-slope (rad), length (m)."""

    soil_class: str
    soil_strength: float
    length: float = math.inf
    grade: float = 0.0
    cross_slope: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.soil_strength) and self.soil_strength > 0):
            raise ValueError(f"segment soil_strength must be a finite K > 0, got {self.soil_strength!r}")
        if not self.length > 0:
            raise ValueError(f"segment length must be > 0 m, got {self.length!r}")
        for name in ("grade", "cross_slope"):
            v = getattr(self, name)
            if not (math.isfinite(v) and abs(v) < math.radians(45)):
                raise ValueError(f"segment {name} must be finite and within +-45 deg, got {v!r} rad")


@dataclass(frozen=True)
class Scenario:
    """A named drive: terrain segments by distance, target speed, default duration and mode."""

    name: str
    description: str
    segments: tuple[Segment, ...]
    speed: float = 1.0
    duration: float = 30.0
    mode: Mode = "excitation"
    sweep: SweepParams = field(default_factory=SweepParams)

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError(f"scenario {self.name!r} needs at least one segment")
        if self.mode not in MODES:
            raise ValueError(f"scenario mode must be one of {MODES}, got {self.mode!r}")
        if not (math.isfinite(self.speed) and 0 < self.speed <= 5):
            raise ValueError(f"scenario speed must be in (0, 5] m/s, got {self.speed!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"scenario duration must be > 0 s, got {self.duration!r}")

    @property
    def starts(self) -> np.ndarray:
        """Distance (m) at which each segment starts."""
        lengths = np.array([s.length for s in self.segments[:-1]], dtype=float)
        return np.concatenate([[0.0], np.cumsum(lengths)])

    def segment_index(self, distance) -> np.ndarray:
        """Index of the segment at each distance (m); before the start -> the first segment."""
        idx = np.searchsorted(self.starts, np.asarray(distance, dtype=float), side="right") - 1
        return np.clip(idx, 0, len(self.segments) - 1)

    def with_overrides(self, *, sweep: SweepParams | None = None, speed: float | None = None) -> "Scenario":
        return replace(self, sweep=sweep or self.sweep, speed=self.speed if speed is None else speed)


def _single(name: str, soil: str, description: str, **kw) -> Scenario:
    return Scenario(name, description, (Segment(soil, REFERENCE_SOILS[soil]),), **kw)


_SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        _single("sand", "sand", "Flat sand (K=50) at 1 m/s, slip-sweep traction test"),
        _single("gravel", "gravel", "Flat gravel (K=80) at 1 m/s, slip-sweep traction test"),
        _single("EST", "EST", "Flat 'expected soil type' (K=120) at 1 m/s, slip-sweep traction test"),
        _single("grass", "grass", "Flat grass (K=200) at 1 m/s, slip-sweep traction test"),
        _single("firm", "firm", "Flat firm soil (K=300) at 1 m/s, slip-sweep traction test"),
        Scenario(
            "sandy-slope",
            "Sand (K=50) on a 10 deg climb with a 3 deg cross-slope (left side up), 1 m/s",
            (Segment("sand", REFERENCE_SOILS["sand"], grade=math.radians(10.0), cross_slope=math.radians(3.0)),),
        ),
        Scenario(
            "mixed",
            "Abrupt soil changes by distance: sand -> gravel -> grass -> firm, 12 m each at 1 m/s",
            (
                Segment("sand", REFERENCE_SOILS["sand"], length=12.0),
                Segment("gravel", REFERENCE_SOILS["gravel"], length=12.0),
                Segment("grass", REFERENCE_SOILS["grass"], length=12.0),
                Segment("firm", REFERENCE_SOILS["firm"]),
            ),
            duration=50.0,
        ),
        Scenario(
            "flat-cruise",
            "Flat gravel (K=80) at constant 1 m/s, no excitation: slip ~0, K not identifiable",
            (Segment("gravel", REFERENCE_SOILS["gravel"]),),
            mode="cruise",
        ),
    )
}


def list_scenarios() -> list[Scenario]:
    """All built-in scenarios, in a stable order."""
    return list(_SCENARIOS.values())


def get_scenario(name: str | Scenario) -> Scenario:
    """Look a scenario up by name (a Scenario passes through); ValueError lists the valid names."""
    if isinstance(name, Scenario):
        return name
    try:
        return _SCENARIOS[name]
    except (KeyError, TypeError):
        raise ValueError(f"scenario must be one of {', '.join(_SCENARIOS)}; got {name!r}") from None
