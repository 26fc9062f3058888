"""The synthetic vehicle as the robot of a calibration drive: it follows ``soilocp calibrate-drive``'s set-points.

``soilocp service vehicle --scenario NAME --follow-drive [--tyre slow|grippy|vector|FILE.json]``: the
simulator runs in real time on the scenario's terrain, endlessly unless ``--duration`` says otherwise, and
publishes its samples on ``soilocp/<vid>/sensors/raw`` from the start (a robot publishes its sensors whether
anybody listens or not).  It stands still until a :class:`soilocp.schemas.messages.DriveSetpoint` arrives on
``soilocp/<vid>/control/drive``; then its own loops (the simulator's wheel-speed PIs, the speed hold of the
trailing axle and the leading axle's slip reference, :mod:`soilocp.sim.controller`) follow the latest one, as a
robot's firmware follows a speed and a slip command.  A set-point older than its ``timeout_s`` is dropped and
the robot brakes to a stop: a command side that died must not leave it sweeping its slip.

``--tyre`` puts the simulated robot on another tyre (the true eq. 6 constants: ``soilocp.sim.variants``'
TYRE_SLOW, TYRE_GRIPPY, TYRE_VECTOR, or a constants / calibration JSON), so that a calibration can be checked
against a curve the estimator was not given.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import DriveSetpoint

from soilocp.services.control.setpoints import LatestSetpoint

#: tyres by name (the true constants live in soilocp.sim.variants)
TYRE_NAMES = ("paper", "slow", "grippy", "vector")


def tyre_constants(tyre: Optional[str]):
    """The true traction constants of ``tyre``: a name of :data:`TYRE_NAMES` or a JSON file (model constants, or a
    calibration file's ``constants``).  None or ``paper``: the paper's testbed wheel.  ValueError names the value."""
    from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants

    if tyre is None or tyre == "paper":
        return DEFAULT_CONSTANTS
    if tyre in TYRE_NAMES:
        from soilocp.sim import variants

        return {"slow": variants.TYRE_SLOW, "grippy": variants.TYRE_GRIPPY, "vector": variants.TYRE_VECTOR}[tyre]
    p = Path(tyre)
    if not p.is_file():
        raise ValueError(f"--tyre {tyre!r}: neither one of {', '.join(TYRE_NAMES)} nor a JSON file of constants")
    from soilocp.model.files import read_json

    data = read_json(p, "tyre file")
    if isinstance(data, dict) and "constants" in data:  # a calibration file
        data = data["constants"]
    try:
        return ModelConstants.model_validate(data)
    except ValueError as exc:
        raise ValueError(f"--tyre {tyre!r}: not a constants file ({exc})") from None


def find_scenario(name: str):
    """A simulator scenario by name: the built-in ones (``soilocp simulate --list``) or the robustness drives'
    terrains (``soilocp.sim.variants``: e.g. ``tyre-sand-loam``, ``gravel-k160``).  ValueError lists them."""
    from soilocp.sim import variants
    from soilocp.sim.scenarios import Scenario, get_scenario, list_scenarios

    extra = {v.name: v for v in vars(variants).values() if isinstance(v, Scenario)}
    if name in extra:
        return extra[name]
    try:
        return get_scenario(name)
    except ValueError:
        names = [s.name for s in list_scenarios()] + sorted(extra)
        raise ValueError(f"--scenario {name!r}: must be one of {', '.join(names)}") from None


@dataclass(frozen=True)
class DriveState:
    """The set-point in force, as the vehicle's health report shows it (``value``: the speed set-point)."""

    value: float
    source: str
    slip: Optional[float]


class DriveInbox(LatestSetpoint):
    """The latest calibration-drive set-point (:class:`LatestSetpoint`), counted by phase."""

    key = staticmethod(keys.control_drive)
    control = "calibrate-drive"
    message = DriveSetpoint
    clock = staticmethod(time.monotonic)

    @staticmethod
    def source(sp: DriveSetpoint) -> str:
        return sp.phase

    def current(self, now: Optional[float] = None) -> DriveState:
        """The set-point in force: the latest, or standstill if there is none or it is older than its timeout."""
        now = self.clock() if now is None else now
        sp, wall = self.latest()
        if sp is None:
            return DriveState(0.0, "none", None)
        if now - wall > sp.timeout_s:
            return DriveState(0.0, "timeout", None)
        return DriveState(sp.speed, sp.phase, sp.slip)

    def sent(self, stamp: float, wall: float) -> None:  # the vehicle service's latency hook: not measured here
        return None

    def latency_summary(self) -> dict:
        return {"setpoints_bad": self.bad}


def drive_source(scenario: str, vehicle_id: str, inbox: DriveInbox, *, duration: Optional[float], rate: float,
                 seed: int, tyre: Optional[str] = None) -> Iterator[tuple[bytes, Optional[float]]]:
    """Samples of ``scenario``'s terrain driven by the calibration drive's set-points (module doc).

    Not a generator itself: a bad scenario or tyre raises ValueError here, at startup."""
    import math

    from soilocp.sim.simulator import simulate

    sc = find_scenario(scenario)
    constants = tyre_constants(tyre)

    def command(_sample):
        st = inbox.current()
        return st.value, st.slip

    samples = simulate(sc, duration=math.inf if duration is None else duration, rate=rate, seed=seed,
                       vehicle_id=vehicle_id, constants=constants, mode="excitation", drive_command=command)
    return ((s.model_dump_json().encode(), s.stamp) for s, _truth in samples)
