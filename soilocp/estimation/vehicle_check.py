"""Does a sensor log look like the vehicle it is estimated with?

The chain takes the vehicle's mass, wheel radius and geometry as given (a log says nothing of them),
so a log of a 300 kg robot on 0.3 m wheels estimated with the built-in 60 kg rover on 0.15 m wheels
runs to the end and gives wrong slips and wrong traction without complaint.  Two cheap checks on
the samples catch the gross cases:

* the wheel radius: while the robot drives straight at a measured ground speed, slip is small most
  of the time, so the median of V / (R_w omega) over those samples is near 1; a median far from 1
  says the radius (or the wheel-speed unit) is off;
* the torque: the wheels' summed torque over R_w, divided by the weight m g, is the traction
  coefficient the torques claim; on soil it stays under about 1 (the strongest reference soil's
  mu_T is below 0.7), so claims above that for a tenth of the drive say the torques are not in
  N m at this vehicle's wheels (a heavier robot, bigger wheels, or a motor current).

No numpy: one pass, a bounded sample of values, plain floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

#: the checks' thresholds (module doc)
RADIUS_RATIO_RANGE = (0.7, 1.4)
TORQUE_MU_P90_MAX = 1.0
MIN_SAMPLES = 50
MIN_SPEED = 0.3  # m/s: slower samples leave the radius ratio to noise and quantisation
MAX_YAW_RATE = 0.2  # rad/s: a turning robot's wheels do not roll at the centre's speed
MAX_KEPT = 20000  # values kept per check (every later one is skipped: a long log's start decides)
GRAVITY = 9.81


def _quantile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, max(0, int(round(q * (len(s) - 1)))))]


@dataclass
class VehicleFit:
    """Accumulates, sample by sample, what the two checks need (module doc)."""

    ratios: list[float] = field(default_factory=list)
    mus: list[float] = field(default_factory=list)

    def add(self, sample, wheel_radius: float, mass: float, torque_constant: float = 1.0) -> None:
        """Take one validated sensor sample (a :class:`soilocp.schemas.sensor.SensorSample`), judged against a
        vehicle of ``wheel_radius`` m and ``mass`` kg whose torques are the logged ones x ``torque_constant``."""
        v = sample.ground_speed
        if v is None or abs(v) < MIN_SPEED or abs(sample.yaw_rate) > MAX_YAW_RATE:
            return
        if len(self.ratios) < MAX_KEPT:
            rim = wheel_radius * sum(sample.wheel_speed) / 4.0
            if rim != 0.0 and math.copysign(1.0, rim) == math.copysign(1.0, v):
                self.ratios.append(v / rim)
        if len(self.mus) < MAX_KEPT:
            self.mus.append(abs(torque_constant * sum(sample.wheel_torque)) / wheel_radius / (mass * GRAVITY))

    def problems(self, wheel_radius: float, mass: float) -> list[str]:
        """What in the data does not fit a vehicle of ``wheel_radius`` m and ``mass`` kg (empty: nothing,
        or too few moving samples to tell)."""
        out = []
        if len(self.ratios) >= MIN_SAMPLES:
            r = _quantile(self.ratios, 0.5)
            lo, hi = RADIUS_RATIO_RANGE
            if not lo <= r <= hi:
                out.append(f"the ground speed is {r:.2f} x the wheels' rim speed at wheel_radius {wheel_radius:g} m "
                           f"(median over {len(self.ratios)} straight samples above {MIN_SPEED} m/s; near 1 for the "
                           f"right radius): the wheel radius is about {r * wheel_radius:.2g} m, or the wheel speeds "
                           "are not in rad/s")
        if len(self.mus) >= MIN_SAMPLES:
            m90 = _quantile(self.mus, 0.9)
            if m90 > TORQUE_MU_P90_MAX:
                out.append(f"the torques claim a traction coefficient sum(T) / (R_w m g) of {m90:.2f} or more for a "
                           f"tenth of the drive (90th percentile) with mass {mass:g} kg and wheel_radius "
                           f"{wheel_radius:g} m, where soil gives under {TORQUE_MU_P90_MAX:g}: the robot is heavier, "
                           "its wheels bigger, or the torques are not N m at the wheel (soilocp calibrate-torque)")
        return out


def vehicle_warning(fit: Optional[VehicleFit], vehicle, vehicle_given: bool) -> Optional[str]:
    """The warning ``soilocp estimate`` prints when the data do not look like ``vehicle`` (None: they do).

    ``vehicle_given``: the user gave the vehicle (a vehicle file or a config's ``vehicle``); without it
    the vehicle is the built-in 60 kg rover, and the fix is to give one."""
    if fit is None:
        return None
    problems = fit.problems(vehicle.wheel_radius, vehicle.mass)
    if not problems:
        return None
    head = ("WARNING: no vehicle file given, so the built-in rover (60 kg, wheel_radius 0.15 m) was used, and these "
            "data do not look like it:" if not vehicle_given else
            "WARNING: these data do not look like the vehicle given:")
    fix = ("give the robot's parameters with --vehicle FILE (README, 'Describe the vehicle')" if not vehicle_given
           else "check the vehicle file's mass and wheel_radius, and the torque unit (--torque-constant)")
    return "\n".join([head, *(f"  - {p}" for p in problems), f"  -> {fix}; every record above assumes this vehicle."])
