"""Closed-loop test scenarios on the simulator, with the whole estimation chain in the loop.

Each sample goes sensor -> :class:`soilocp.estimation.pipeline.VehiclePipeline` (normal forces, observer,
slip + K, OCPs) -> controller -> wheel torques held over the next interval
(``simulate(..., wheel_torque_command=...)``).  The controller sees only the sample and the
pipeline's estimate; the truth is used only to score the run.

Scenarios (the operator's speed command is the scenario speed, ramped in over 2 s as in the
simulator's cruise mode; the slip controllers are limiters under that command):

* ``drawbar-<soil>``: flat soil, a towed load whose draft rises slowly (``ramp`` x W per second
  from ``start`` x W, W = m g) until the rover stalls: the draft soon exceeds what the soil can
  give, so every controller ends up pulling as hard as its slip set-point lets it.  The score is
  the steady drawbar pull: the largest 2-s mean of the true net traction sum(mu_i Fz_i) (eq. 6,
  the paper's F_DP) while the rover still moves (V >= 0.2 m/s).  The draft acts along the body
  x axis at the CoM (no hitch moment, so no extra load transfer).
* ``climb-<soil>``: the grade rises by 0.5 deg every 0.5 m (after 2 m of flat) until the rover
  stalls or spins out; scores: the highest grade under the CoM at which it still moved at
  V >= 0.1 m/s, and the distance made.
* ``mixed-drive``: sand -> gravel -> grass -> firm, 12 m each, at 1 m/s, towing a trailer whose
  draft grows with speed (0.4 W at 1 m/s, e.g. an implement in soil); score: motor energy per
  metre over the 48 m (the drive ends there, or after 150 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from soilocp.schemas.pipeline import OcpEstimate
from soilocp.schemas.sensor import SensorSample

from soilocp.model.constants import REFERENCE_SOILS
from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
from soilocp.sim.scenarios import Scenario, Segment
from soilocp.sim.controller import smoothstep
from soilocp.sim.simulator import simulate
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.control.controllers import SlipController, make_controller

DRAWBAR_SOILS = ("sand", "gravel", "grass", "firm")
STALL_SPEED = 0.1  #: m/s: below this for STALL_TIME the rover has stalled (or spun out)
STALL_TIME = 1.0
PULL_WINDOW = 2.0  #: s, window of the steady drawbar pull
PULL_MIN_SPEED = 0.2  #: m/s, the pull counts only while the rover still moves
RAMP_TIME = 2.0  #: s, speed command ramp (the simulator's cruise mode)

@dataclass(frozen=True)
class RigScenario:
    name: str
    description: str
    scenario: Scenario
    kind: str  # drawbar | climb | drive
    max_time: float
    draft: Optional[Callable[[float, float], float]] = None  # (t, V) -> N
    stop_distance: Optional[float] = None

def _weight() -> float:
    return DEFAULT_VEHICLE.mass * STANDARD_GRAVITY

def _ramp_draft(start: float, ramp: float, delay: float = 3.0) -> Callable[[float, float], float]:
    w = _weight()

    def draft(t: float, v: float) -> float:
        return w * (start + ramp * max(0.0, t - delay)) * smoothstep(t / delay)

    return draft

def _drawbar(soil: str) -> RigScenario:
    k = REFERENCE_SOILS[soil]
    sc = Scenario(f"drawbar-{soil}", f"{soil} drawbar", (Segment(soil, k),), speed=1.0, duration=120.0, mode="cruise")
    return RigScenario(sc.name, f"Flat {soil} (K={k:g}), draft ramping 0.2 W + 0.02 W/s until stall", sc,
                       "drawbar", max_time=90.0, draft=_ramp_draft(0.2, 0.02))

def _climb(soil: str) -> RigScenario:
    k = REFERENCE_SOILS[soil]
    segs = [Segment(soil, k, length=2.0)]
    g = 0.5
    while g < 44.0:
        segs.append(Segment(soil, k, length=0.5, grade=math.radians(g)))
        g += 0.5
    segs.append(Segment(soil, k, grade=math.radians(44.0)))
    sc = Scenario(f"climb-{soil}", f"{soil} climb", tuple(segs), speed=1.0, duration=120.0, mode="cruise")
    return RigScenario(sc.name, f"{soil} (K={k:g}), grade +0.5 deg per 0.5 m until stall", sc, "climb",
                       max_time=120.0)

def _mixed_drive() -> RigScenario:
    segs = tuple(Segment(s, REFERENCE_SOILS[s], length=12.0) for s in ("sand", "gravel", "grass"))
    segs += (Segment("firm", REFERENCE_SOILS["firm"]),)
    sc = Scenario("mixed-drive", "mixed drive", segs, speed=1.0, duration=150.0, mode="cruise")
    w = _weight()
    return RigScenario(sc.name, "sand -> gravel -> grass -> firm, 12 m each, 1 m/s, draft 0.4 W x V/(1 m/s)", sc,
                       "drive", max_time=150.0, draft=lambda t, v: 0.4 * w * max(v, 0.0) / 1.0, stop_distance=48.0)

RIG_SCENARIOS: dict[str, RigScenario] = {
    r.name: r for r in (*(_drawbar(s) for s in DRAWBAR_SOILS), _climb("gravel"), _mixed_drive())
}

def get_rig_scenario(name: str) -> RigScenario:
    try:
        return RIG_SCENARIOS[name]
    except KeyError:
        raise ValueError(f"scenario must be one of {', '.join(RIG_SCENARIOS)}; got {name!r}") from None

@dataclass
class Trace:
    """Per-sample record of one closed-loop run (for the plots and the scores)."""

    t: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)  # true V
    slip: list[float] = field(default_factory=list)  # mean true slip of the 4 wheels
    setpoint: list[float] = field(default_factory=list)  # nan: none
    source: list[str] = field(default_factory=list)
    k_est: list[float] = field(default_factory=list)  # nan: no estimate
    k_true: list[float] = field(default_factory=list)
    pull: list[float] = field(default_factory=list)  # true sum mu_i Fz_i, N
    grade: list[float] = field(default_factory=list)  # deg, under the CoM
    distance: list[float] = field(default_factory=list)
    motor_work: list[float] = field(default_factory=list)

class _Loop:
    """The callback the simulator calls with each sample: pipeline, then controller."""

    def __init__(self, ctl: SlipController, pipeline: VehiclePipeline, speed: float):
        self.ctl, self.pipeline, self.speed = ctl, pipeline, speed
        self.estimate: Optional[OcpEstimate] = None
        self.last = None

    def __call__(self, sample: SensorSample):
        self.estimate = self.pipeline.process(sample)
        cmd = self.speed * smoothstep(sample.stamp / RAMP_TIME)
        self.last = self.ctl.step(sample, self.estimate, cmd)
        return self.last.loop.torque

def run_closed_loop(rig: RigScenario, controller: str, *, seed: int = 0, duration: Optional[float] = None,
                    config: Optional[PipelineConfig] = None) -> tuple[dict[str, float], Trace]:
    """Drive ``rig`` with ``controller`` and the estimation chain in the loop; (scores, trace)."""
    config = config or PipelineConfig()
    ctl = make_controller(controller, vehicle=config.vehicle, constants=config.constants)
    loop = _Loop(ctl, VehiclePipeline(config), rig.scenario.speed)
    max_time = min(rig.max_time, duration) if duration is not None else rig.max_time
    tr = Trace()
    slow_since: Optional[float] = None
    for sample, truth in simulate(rig.scenario, duration=max_time, seed=seed, vehicle=config.vehicle,
                                  constants=config.constants, wheel_torque_command=loop, drawbar_load=rig.draft):
        est, last = loop.estimate, loop.last
        tr.t.append(truth.stamp)
        tr.speed.append(truth.ground_speed)
        tr.slip.append(float(np.mean(truth.slip)))
        sp = last.setpoint if last is not None else None
        tr.setpoint.append(sp.value if sp is not None and sp.value is not None else math.nan)
        tr.source.append(sp.source if sp is not None else "none")
        tr.k_est.append(est.soil_strength if est is not None and est.soil_strength is not None else math.nan)
        tr.k_true.append(truth.soil_strength)
        tr.pull.append(float(np.dot(truth.mu, truth.normal_force)))
        tr.grade.append(math.degrees(truth.grade))
        tr.distance.append(truth.distance)
        tr.motor_work.append(truth.motor_work)
        if rig.stop_distance is not None and truth.distance >= rig.stop_distance:
            break
        if truth.stamp > RAMP_TIME + 1.0 and rig.kind != "drive":
            slow_since = (slow_since if slow_since is not None else truth.stamp) if truth.ground_speed < STALL_SPEED else None
            if slow_since is not None and truth.stamp - slow_since >= STALL_TIME:
                break
    return score(rig, tr), tr

def score(rig: RigScenario, tr: Trace) -> dict[str, float]:
    """The four scores of the issue's JSON for one run (every scenario reports all four)."""
    t = np.asarray(tr.t)
    v = np.asarray(tr.speed)
    dist = tr.distance[-1] if tr.distance else 0.0
    work = tr.motor_work[-1] if tr.motor_work else 0.0
    out = {
        "drawbar_pull_n": 0.0,
        "energy_per_m_j": work / dist if dist > 0.5 else math.nan,
        "max_grade_deg": 0.0,
        "distance_m": dist,
        "duration_s": float(t[-1]) if len(t) else 0.0,
    }
    if len(t) > 1:
        dt = float(t[1] - t[0])
        n = max(1, int(round(PULL_WINDOW / dt)))
        pull = np.asarray(tr.pull)
        if len(pull) >= n:
            mean_pull = np.convolve(pull, np.ones(n) / n, mode="valid")
            min_v = np.lib.stride_tricks.sliding_window_view(v, n).min(axis=1)
            ok = min_v >= PULL_MIN_SPEED
            out["drawbar_pull_n"] = float(mean_pull[ok].max()) if ok.any() else 0.0
        moving = v >= STALL_SPEED
        if moving.any():
            out["max_grade_deg"] = float(np.asarray(tr.grade)[moving].max())
    est = np.asarray(tr.source) == "estimate"
    out["estimate_share"] = float(est.mean()) if len(est) else 0.0
    k = np.asarray(tr.k_est)
    kt = np.asarray(tr.k_true)
    good = np.isfinite(k)
    out["k_error_median"] = float(np.median(np.abs(k[good] / kt[good] - 1.0))) if good.any() else math.nan
    return out
