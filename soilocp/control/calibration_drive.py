"""The calibration drive's protocol: what the robot is told to do at each instant (pure library, no Zenoh).

``soilocp calibrate-drive`` commands a robot through at most 60 s of driving that shows what the
calibration needs, and nothing more aggressive than the limits its user sets (``max_speed``, ``max_slip``):

* **accelerate and brake** (``swing``): the speed set-point swings sinusoidally between 0.25 and 1.0 x
  ``max_speed`` every ``swing_period`` s.  The longitudinal force balance (docs/method.md §15) needs windows
  whose accelerations spread (``soilocp.analysis.torque_constant``: a spread of at least 0.5 m/s^2) to tell
  the torque (or the mass) from the rolling resistance; at 1 m/s the swing's acceleration reaches
  +-0.94 m/s^2.  The slips stay small, so the windows measure rolling resistance, not the slip's;
* **a slip sweep past the peak** (``sweep``): at a constant 0.625 x ``max_speed``, the front axle's slip
  set-point runs a triangle from ``min_slip`` up to ``max_slip`` and back in ``sweep_period`` s, then holds
  ``min_slip`` for ``sweep_dwell`` s, while the rear axle brakes to hold the speed (the simulator's traction
  test, ``soilocp.sim.scenarios.SweepParams`` says why the front sweeps and why the dwell).  This is what
  shows the traction curve's bend and peak (``soilocp.analysis.drive_calibration``);
* the two alternate twice (swing, sweep, swing, sweep), so that a robot crossing two soils sweeps on each,
  between a smooth start from rest and a smooth stop.

The protocol is a function of the time since its start only (:meth:`DriveProtocol.at`); the command side
publishes it, the robot follows it with its own fast loops.  A 0.625 x ``max_speed`` sweep leaves room for the
overshoot of a sweep near the peak (up to +26 % on firm soil, SweepParams), so the robot stays within
``max_speed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

Phase = Literal["start", "swing", "sweep", "stop", "done"]

#: the longest calibration drive (s): the issue's budget, and what a user can watch without a break
MAX_DURATION = 60.0
#: speed of the sweeps and centre of the swings, as a share of max_speed
SWEEP_SPEED_SHARE = 0.625
#: the swings' amplitude, as a share of max_speed (0.25 .. 1.0 x max_speed)
SWING_SHARE = 0.375


@dataclass(frozen=True)
class DriveCommand:
    """What the robot should do now: its speed set-point (m/s, forward), the front axle's driving slip
    set-point (eq. 1; None: every wheel holds the speed) and the protocol's phase."""

    phase: Phase
    speed: float
    slip: Optional[float]


@dataclass(frozen=True)
class DriveProtocol:
    """The calibration drive (module doc).  Every field is checked at construction; an error names the
    field, its value and the limit."""

    duration: float = MAX_DURATION  #: s, whole drive including the start and the stop
    max_speed: float = 1.0  #: m/s: no set-point exceeds it
    max_slip: float = 0.6  #: the sweep's top slip: past the traction peak of the robot's soils, within the user's limit
    min_slip: float = 0.05  #: the sweep's bottom slip (and its dwell)
    swing_period: float = 2.5  #: s, one acceleration-and-brake cycle
    swing_cycles: tuple[int, int] = (3, 2)  #: cycles of the first and the second swing
    sweep_period: float = 1.6  #: s, the triangle up and down
    sweep_dwell: float = 0.4  #: s at min_slip after each triangle
    start_s: float = 2.0  #: s, the smooth start from rest
    stop_s: float = 2.0  #: s, the smooth stop

    def __post_init__(self) -> None:
        for name in ("duration", "max_speed", "max_slip", "min_slip", "swing_period", "sweep_period", "sweep_dwell",
                     "start_s", "stop_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"calibration drive {name} must be a finite number >= 0, got {v!r}")
        if not 0 < self.duration <= MAX_DURATION:
            raise ValueError(f"calibration drive duration must be in (0, {MAX_DURATION:g}] s, got {self.duration!r}")
        if not 0.2 <= self.max_speed <= 5.0:
            raise ValueError(f"calibration drive max_speed must be in [0.2, 5] m/s (slower windows tell the force balance "
                             f"nothing: soilocp calibrate-torque's min_speed), got {self.max_speed!r}")
        if not 0.0 <= self.min_slip < self.max_slip < 0.95:
            raise ValueError(f"calibration drive slips must satisfy 0 <= min_slip < max_slip < 0.95, got min_slip "
                             f"{self.min_slip!r}, max_slip {self.max_slip!r}")
        if self.swing_period <= 0 or self.sweep_period <= 0:
            raise ValueError(f"calibration drive swing_period and sweep_period must be > 0 s, got {self.swing_period!r}, "
                             f"{self.sweep_period!r}")
        if self.sweep_time < 2 * self.sweep_cycle:
            need = self.start_s + self.stop_s + sum(self.swing_cycles) * self.swing_period + 4 * self.sweep_cycle
            raise ValueError(f"calibration drive duration {self.duration:g} s leaves {self.sweep_time:.1f} s for the slip "
                             f"sweeps, less than one sweep ({self.sweep_cycle:g} s) per half: give at least {need:.0f} s")

    @property
    def sweep_cycle(self) -> float:
        """s of one sweep: triangle + dwell."""
        return self.sweep_period + self.sweep_dwell

    @property
    def sweep_time(self) -> float:
        """s of each of the two sweep phases: what the start, the swings and the stop leave, in whole sweeps."""
        rest = self.duration - self.start_s - self.stop_s - sum(self.swing_cycles) * self.swing_period
        return math.floor(max(rest, 0.0) / 2.0 / self.sweep_cycle + 1e-9) * self.sweep_cycle

    def phases(self) -> list[tuple[Phase, float, float]]:
        """(phase, start s, end s) of each part of the drive, in order."""
        out, t = [], 0.0
        plan = [("start", self.start_s), ("swing", self.swing_cycles[0] * self.swing_period), ("sweep", self.sweep_time),
                ("swing", self.swing_cycles[1] * self.swing_period), ("sweep", self.sweep_time)]
        for name, length in plan:
            out.append((name, t, t + length))
            t += length
        out.append(("stop", t, self.duration))
        return out

    @property
    def sweep_speed(self) -> float:
        return SWEEP_SPEED_SHARE * self.max_speed

    def at(self, t: float) -> DriveCommand:
        """The command at ``t`` s after the start (``done`` with speed 0 after the end)."""
        v0 = self.sweep_speed
        for name, a, b in self.phases():
            if not a <= t < b:
                continue
            tau = t - a
            if name == "start":
                return DriveCommand("start", v0 * _smoothstep(tau / self.start_s), None)
            if name == "swing":
                return DriveCommand("swing", v0 + SWING_SHARE * self.max_speed * math.sin(2 * math.pi * tau / self.swing_period),
                                    None)
            if name == "sweep":
                tc = tau % self.sweep_cycle
                slip = self.min_slip
                if tc < self.sweep_period:
                    slip += (self.max_slip - self.min_slip) * (1.0 - abs(2.0 * tc / self.sweep_period - 1.0))
                return DriveCommand("sweep", v0, slip)
            return DriveCommand("stop", v0 * (1.0 - _smoothstep(tau / max(b - a, 1e-9))), None)
        return DriveCommand("done", 0.0, None)


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)
