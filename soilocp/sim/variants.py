"""Robustness variants: drives the estimator was not tuned to (docs/robustness.md; docs/method.md §11-13).

A :class:`Variant` changes what the simulator does or what the sensors report while the
estimator keeps its NOMINAL vehicle and default configuration:

* the drive itself: controller mode, slip sweep, rear axle mirroring the front's slip (§12),
  S-turns, sample rate, travel backwards, a skid steer turning on the spot or on arcs, a speed
  set-point that accelerates and brakes, a grade, a towed draft that stalls the robot;
* the true vehicle (:class:`VehicleChange`): wheel radius, mass and CoM differ from the nominal
  ones the estimator uses;
* the sensor stream (stream transforms): Unix-epoch stamps, torque scale, IMU bias, channels
  refreshed at a lower rate and held in between, a lagging ground speed (§13).

Every variant has a name, a one-line description, and whether K is identifiable from its data
("yes"; "limited": a scale error no estimator can see bounds the precision; "no").  Runs are
reproducible: the simulator's noise comes from ``seed``, and any random draw of a variant (the
IMU bias's signs) from a generator seeded by ``(seed, crc32(name))``.
"""

from __future__ import annotations

import math
import zlib
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Literal, Optional

import numpy as np

from soilocp.schemas.sensor import SensorSample

from soilocp.model.constants import DEFAULT_CONSTANTS, REFERENCE_SOILS, ModelConstants
from soilocp.sim.scenarios import Scenario, Segment, SweepParams
from soilocp.sim.controller import ControllerParams, DEFAULT_CONTROLLER
from soilocp.sim.simulator import DEFAULT_SIM, SimParams, simulate
from soilocp.sim.truth import TruthRecord
from soilocp.model.vehicle import DEFAULT_VEHICLE, VehicleParams

Identifiability = Literal["yes", "limited", "no"]
SampleMap = Callable[[SensorSample], SensorSample]

#: The drive every variant starts from: four soils in an order and with one strength (K = 100,
#: between the reference classes) that the product's own scenarios do not use, 10 m each at
#: 1 m/s, so that a 1-seed table of all variants runs in a few minutes on two cores.
ROBUST_DRIVE = Scenario(
    "robust-mix",
    "grass (K=200) -> sand (K=50) -> firm (K=300) -> loam (K=100), 10 m each at 1 m/s, traction test",
    (
        Segment("grass", REFERENCE_SOILS["grass"], length=10.0),
        Segment("sand", REFERENCE_SOILS["sand"], length=10.0),
        Segment("firm", REFERENCE_SOILS["firm"], length=10.0),
        Segment("loam", 100.0),
    ),
    duration=42.0,
)

#: Cruise down a 12 deg slope over the same soils: the only slip is the braking slip the grade asks
#: for (mu ~ -0.21 on every wheel), so K is not identifiable.
SLOPE_DRIVE = Scenario(
    "robust-mix-descent",
    "the robust-mix soils on a 12 deg descent, 10 m each at 1 m/s, constant speed",
    tuple(Segment(s.soil_class, s.soil_strength, s.length, grade=-math.radians(12.0)) for s in ROBUST_DRIVE.segments),
    duration=42.0,
    mode="cruise",
)

#: A skid steer turning on the spot over loam (K = 100).
SPOT_DRIVE = Scenario("loam-spot", "loam (K=100), turning on the spot", (Segment("loam", 100.0),), duration=20.0,
                      mode="cruise")

#: Firm soil (K = 300) at 0.5 m/s, towing a draft that ends in a stall.
DRAFT_DRIVE = Scenario("firm-draft", "firm (K=300) at 0.5 m/s with a towed load", (Segment("firm", REFERENCE_SOILS["firm"]),),
                       speed=0.5, duration=30.0, mode="cruise")

#: The vehicle changes of a skid steer (docs/maps/skid-steer-rover.json): one motor per side.
SKID_STEER = (("drive", "per_side"), ("wheel_speed_reading", "interval_mean"))
#: A skid steer's wheels slide sideways in a turn: eq. 12's lateral resistance mu_y 0.5 (the default
#: 0.2 is a differentially steered rover's), so that turning asks each wheel for |mu| ~ mu_y.
SKID_SIM = SimParams(lateral_resistance=0.5)


# --- stream transforms (one sample in, one out; state per run) -----------------------------------
@dataclass(frozen=True)
class EpochStamps:
    """Stamps as a real logger writes them: Unix epoch seconds (offset + simulated time)."""

    offset: float = 1.7e9

    def bind(self, rng: np.random.Generator) -> SampleMap:
        return lambda s: s.model_copy(update={"stamp": s.stamp + self.offset})


@dataclass(frozen=True)
class TorqueScale:
    """The torque channel reads ``scale`` x the true torque (a motor constant that is off)."""

    scale: float

    def bind(self, rng: np.random.Generator) -> SampleMap:
        return lambda s: s.model_copy(update={"wheel_torque": tuple(self.scale * q for q in s.wheel_torque)})


@dataclass(frozen=True)
class ImuBias:
    """Constant accelerometer bias (``accel`` m/s^2 on each axis) and gyro bias (``gyro`` rad/s),
    signs drawn once per run from the variant's generator."""

    accel: float = 0.1
    gyro: float = 0.01

    def bind(self, rng: np.random.Generator) -> SampleMap:
        signs = rng.choice((-1.0, 1.0), size=4)
        bias = tuple(float(self.accel * q) for q in signs[:3])
        gyro = float(self.gyro * signs[3])
        return lambda s: s.model_copy(
            update={
                "specific_force": tuple(f + b for f, b in zip(s.specific_force, bias)),
                "yaw_rate": s.yaw_rate + gyro,
            }
        )


@dataclass(frozen=True)
class HeldChannel:
    """A channel that refreshes at ``refresh`` Hz (instants k / refresh on the stamp clock) and is
    held between refreshes; each refresh reports the channel's value ``lag`` seconds earlier
    (linear interpolation between the stream's samples; before the first sample, the first)."""

    channel: Literal["wheel_speed", "wheel_torque", "ground_speed"]
    refresh: float
    lag: float = 0.0
    #: 1-sigma of white noise added to each refresh (a GNSS fix's speed error), in the channel's unit
    noise: float = 0.0

    def bind(self, rng: np.random.Generator) -> SampleMap:
        history: deque[tuple[float, np.ndarray]] = deque()
        state: dict = {"k": None, "held": None}
        keep = self.lag + 2.0 / self.refresh

        def value_at(t: float) -> np.ndarray:
            prev = history[0]
            for cur in history:
                if cur[0] >= t:
                    if cur[0] == prev[0]:
                        return cur[1]
                    w = (t - prev[0]) / (cur[0] - prev[0])
                    return prev[1] + max(w, 0.0) * (cur[1] - prev[1])
                prev = cur
            return prev[1]

        def apply(s: SensorSample) -> SensorSample:
            history.append((s.stamp, np.atleast_1d(np.asarray(getattr(s, self.channel), dtype=float))))
            while history[0][0] < s.stamp - keep:
                history.popleft()
            k = math.floor(s.stamp * self.refresh + 1e-9)
            if k != state["k"]:
                state["k"] = k
                state["held"] = value_at(k / self.refresh - self.lag)
                if self.noise > 0:
                    state["held"] = state["held"] + rng.normal(0.0, self.noise, state["held"].shape)
            held = state["held"]
            new = float(held[0]) if self.channel == "ground_speed" else tuple(float(q) for q in held)
            return s.model_copy(update={self.channel: new})

        return apply


@dataclass(frozen=True)
class LostRows:
    """A logger that loses rows and stamps late: each sample is dropped with probability ``lost``,
    repeated once with probability ``duplicated``, and its stamp moved by uniform jitter of up to
    ``jitter`` s (kept after the previous stamp, so that time still runs forward)."""

    lost: float = 0.05
    duplicated: float = 0.01
    jitter: float = 0.003

    def bind(self, rng: np.random.Generator):
        state = {"last": -math.inf}

        def apply(s: SensorSample):
            if rng.random() < self.lost:
                return None
            stamp = max(s.stamp + rng.uniform(-self.jitter, self.jitter), state["last"] + 1e-4)
            state["last"] = stamp
            out = s.model_copy(update={"stamp": stamp})
            return (out, out) if rng.random() < self.duplicated else out

        return apply


StreamTransform = EpochStamps | TorqueScale | ImuBias | HeldChannel | LostRows


#: Tyres that are not the paper's testbed wheel (their true eq. 6 constants; docs/method.md §14).  A slower
#: rise (S_T 0.37 / 0.51 on K = 50 / 100 where the paper's curve says 0.26 / 0.38), a grippier one (S_T 0.29-0.40,
#: mu_T 0.80-1.41 on K = 80-300), and method.md's test-vector tyre (S_T 0.41 / 0.53 on K = 80 / 200).
TYRE_SLOW = ModelConstants(C1=1.2, C2=0.015, C3=5.2, C5=-3.0, C6=3.4)
TYRE_GRIPPY = ModelConstants(C1=1.6, C2=0.012, C3=9.5, C5=-4.0, C6=5.5)
TYRE_VECTOR = ModelConstants(C1=1.2, C2=0.015, C3=6.4, C5=-3.0, C6=3.5)
#: A robot whose vehicle file names no traction curve (its wheel is not known to be the paper's)
UNCHECKED_CURVE = (("traction_curve", None),)

TYRE_TWO_SOILS = Scenario("tyre-sand-loam", "sand (K=50) -> loam (K=100), 12 m each at 1 m/s, traction test",
                          (Segment("sand", REFERENCE_SOILS["sand"], length=12.0), Segment("loam", 100.0)), duration=25.0)
TYRE_SOFT_FIRM_SOFT = Scenario(
    "tyre-soft-firm-soft", "gravel (K=80) -> K=160 -> firm (K=300) -> gravel (K=80), 10 m each at 1 m/s, traction test",
    (Segment("gravel", REFERENCE_SOILS["gravel"], length=10.0), Segment("loam", 160.0, length=10.0),
     Segment("firm", REFERENCE_SOILS["firm"], length=10.0), Segment("gravel", REFERENCE_SOILS["gravel"])),
    duration=42.0)
GRAVEL_GRASS = Scenario("gravel-grass", "gravel (K=80) -> grass (K=200), 12 m each at 1 m/s, traction test",
                        (Segment("gravel", REFERENCE_SOILS["gravel"], length=12.0), Segment("grass", REFERENCE_SOILS["grass"])),
                        duration=25.0)
GRAVEL_FIRMER = Scenario("gravel-k160", "gravel (K=80) -> twice as firm (K=160), 16 m each at 1 m/s, traction test",
                         (Segment("gravel", REFERENCE_SOILS["gravel"], length=16.0), Segment("loam", 160.0)), duration=33.0)
#: GNSS-grade ground speed: fixes at ``refresh`` Hz, ``lag`` s late, a few cm/s of noise, held between fixes
def gnss(refresh: float = 10.0, lag: float = 0.1, noise: float = 0.03) -> HeldChannel:
    return HeldChannel("ground_speed", refresh, lag=lag, noise=noise)




@dataclass(frozen=True)
class Draft:
    """A towed load's draft (N, opposing the motion; simulator's ``drawbar_load``): 0 until
    ``start`` s, then rising smoothly to ``fraction`` x mu_T x the robot's weight over ``ramp`` s
    and held.  Above 1 the wheels cannot pull it: the robot stalls while they spin."""

    fraction: float = 1.3
    start: float = 5.0
    ramp: float = 10.0

    def load(self, vehicle: VehicleParams, soil_strength: float, constants: ModelConstants):
        from soilocp.model.ocp import ocp_from_soil_strength
        from soilocp.model.normal_force import STANDARD_GRAVITY
        from soilocp.sim.controller import smoothstep

        full = self.fraction * ocp_from_soil_strength(soil_strength, constants).mu_T * vehicle.mass * STANDARD_GRAVITY
        return lambda t, v: full * smoothstep((t - self.start) / self.ramp)


@dataclass(frozen=True)
class VehicleChange:
    """The TRUE vehicle relative to the nominal one the estimator uses: mass (and yaw inertia)
    x ``mass``, CoM-to-rear-axle distance a x ``com`` (wheelbase kept: b = L - a), CoM height
    x ``height``, wheel radius x ``radius``."""

    mass: float = 1.0
    com: float = 1.0
    height: float = 1.0
    radius: float = 1.0

    def apply(self, nominal: VehicleParams) -> VehicleParams:
        base = nominal.a + nominal.b
        a = nominal.a * self.com
        if not 0 < a < base:
            raise ValueError(f"com factor {self.com} puts the CoM outside the wheelbase (a={a:.3f} m of {base:.3f} m)")
        return nominal.model_copy(
            update=dict(
                mass=nominal.mass * self.mass,
                yaw_inertia=nominal.yaw_inertia * self.mass,
                a=a,
                b=base - a,
                h=nominal.h * self.height,
                wheel_radius=nominal.wheel_radius * self.radius,
            )
        )


@dataclass(frozen=True)
class Variant:
    """A named, seeded, reproducible drive that the estimator does not know about."""

    name: str
    description: str
    identifiable: Identifiability = "yes"
    why_limited: str = ""
    scenario: Scenario = ROBUST_DRIVE
    rate: float = 100.0
    mode: Optional[str] = None
    sweep: Optional[SweepParams] = None
    controller: ControllerParams = DEFAULT_CONTROLLER
    vehicle: VehicleChange = field(default_factory=VehicleChange)
    transforms: tuple[StreamTransform, ...] = ()
    #: The robot itself, known to the estimator too (its vehicle file): updates of the nominal
    #: vehicle, e.g. SKID_STEER.  The VehicleChange is the unknown on top of it.
    robot: tuple[tuple[str, str], ...] = ()
    draft: Optional[Draft] = None
    #: The true wheels' traction constants (eqs. 3-6), when they are not the ones the estimator is
    #: configured with: another tyre, whose curve nobody gave the estimator (None: the estimator's)
    tyre: Optional[ModelConstants] = None
    #: Whether the drive shows the tyre's curve (slips past its peak): where it does not, no estimator can
    #: know the OCPs, and the row is judged by its honesty alone (no ok record with the OCPs off)
    curve_shown: bool = True
    sim: SimParams = DEFAULT_SIM  #: the simulator's settings (a skid steer's lateral resistance, eq. 12)
    #: What a flagged record's reason must name where K is limited or not identifiable (the table
    #: checks it on the settled samples); "" = not checked.
    reason_names: str = ""

    def rng(self, seed: int) -> np.random.Generator:
        return np.random.default_rng([int(seed), zlib.crc32(self.name.encode())])

    @property
    def judged_from(self) -> float:
        """s into the drive from which K and the OCPs are judged (the targets' median, p90 and OCP errors):
        the end of the first speed swing on a drive that accelerates and brakes (its slip, <= 0.02, gives no
        K, and the torque scale is learnt once both signs were seen: it "converges to the right K
        once it has accelerated"); 0 otherwise.  The ok>30% count and the band judge every settled record."""
        return self.controller.speed_swing_period if self.controller.speed_swing > 0 else 0.0

    @property
    def ocp_after(self) -> float:
        """s after each segment's settle from which another tyre's OCPs are judged: one traction-sweep cycle, the
        first that can show the new soil's curve (0 for the estimator's own tyre)."""
        if self.tyre is None:
            return 0.0
        sweep = self.sweep or SweepParams()
        return sweep.period + sweep.dwell

    def known_vehicle(self, nominal: VehicleParams = DEFAULT_VEHICLE) -> VehicleParams:
        """The vehicle the estimator is configured with: the nominal one with ``robot``'s updates."""
        return nominal.model_copy(update=dict(self.robot)) if self.robot else nominal

    def true_vehicle(self, nominal: VehicleParams = DEFAULT_VEHICLE) -> VehicleParams:
        return self.vehicle.apply(self.known_vehicle(nominal))

    def simulate(
        self,
        seed: int = 0,
        *,
        duration: Optional[float] = None,
        nominal: VehicleParams = DEFAULT_VEHICLE,
        constants: ModelConstants = DEFAULT_CONSTANTS,
    ) -> Iterator[tuple[SensorSample, TruthRecord]]:
        """(sensor sample as the estimator sees it, truth) pairs; truth keeps the simulator's
        stamps (seq / rate), the sample carries the variant's."""
        rng = self.rng(seed)
        maps = [t.bind(rng) for t in self.transforms]
        true = self.true_vehicle(nominal)
        constants = self.tyre or constants
        draft = self.draft and self.draft.load(true, self.scenario.segments[0].soil_strength, constants)
        pairs = simulate(
            self.scenario, duration=duration, rate=self.rate, seed=seed, vehicle=true,
            constants=constants, mode=self.mode, sweep=self.sweep, controller=self.controller, drawbar_load=draft,
            params=self.sim,
        )  # fmt: skip
        for sample, truth in pairs:
            out = [sample]
            for m in maps:  # a transform returns one sample, None (a lost row) or a tuple (duplicates)
                out = [q for s in out for q in _as_rows(m(s))]
            for s in out:
                yield s, truth


def _as_rows(result) -> tuple:
    return () if result is None else result if isinstance(result, tuple) else (result,)


def _sweep(period: float, peak: float) -> Variant:
    return Variant(
        f"sweep-{period:g}s-{peak:g}",
        f"traction test sweeping 0.02..{peak:g} slip in {period:g} s (+{period / 4:g} s dwell)",
        sweep=SweepParams(s_min=0.02, s_max=peak, period=period, dwell=period / 4),
    )


def _tyre(name: str, description: str, tyre: ModelConstants, robot: tuple = (), **kw) -> Variant:
    """A robot on another tyre whose vehicle file names no traction curve: the OCPs must come from
    the curve the drive shows, or be flagged."""
    return Variant(name, description, tyre=tyre, robot=robot + UNCHECKED_CURVE, **kw)


def _limited(name: str, description: str, why: str, **kw) -> Variant:
    return Variant(name, description, "limited", why, **kw)


VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("nominal", "the base drive as the estimator expects it: 100 Hz, default sweep, nominal vehicle"),
        Variant(
            "rear-mirror",
            "rear axle brakes at about -S while the front drives at S (0.02..0.35 in 3 s + 0.5 s dwell)",
            sweep=SweepParams(s_min=0.02, s_max=0.35, period=3.0, dwell=0.5),
            controller=ControllerParams(rear_mirror=1.0),
        ),
        _sweep(3.0, 0.1),
        _sweep(3.0, 0.5),
        _sweep(6.0, 0.3),
        _sweep(12.0, 0.1),
        _sweep(12.0, 0.5),
        Variant("rate-20hz", "sensor log at 20 Hz", rate=20.0),
        Variant("rate-50hz", "sensor log at 50 Hz", rate=50.0),
        Variant("rate-200hz", "sensor log at 200 Hz", rate=200.0),
        Variant("epoch-stamps", "stamps in Unix epoch seconds (1.7e9 + t)", transforms=(EpochStamps(),)),
        _limited("torque+10", "torque channel reads 1.10 x the true torque", "torque scale", transforms=(TorqueScale(1.10),)),
        _limited("torque-10", "torque channel reads 0.90 x the true torque", "torque scale", transforms=(TorqueScale(0.90),)),
        _limited("radius+3", "true wheel radius 3 % above the nominal", "wheel-speed scale", vehicle=VehicleChange(radius=1.03)),
        _limited("radius-3", "true wheel radius 3 % below the nominal", "wheel-speed scale", vehicle=VehicleChange(radius=0.97)),
        Variant("imu-bias", "accelerometer bias +-0.1 m/s^2 per axis and gyro bias +-0.01 rad/s (seeded signs)",
                transforms=(ImuBias(),)),
        Variant("ground-speed-lag", "ground speed 50 ms late and refreshed at 10 Hz (held)",
                transforms=(HeldChannel("ground_speed", 10.0, lag=0.05),)),
        Variant("wheel-speed-5hz", "wheel speeds refreshed at 5 Hz (held)", transforms=(HeldChannel("wheel_speed", 5.0),)),
        # the default sweep's kinks (0.8 s triangle + 0.4 s dwell) fall on multiples of 0.2 s, as 5 Hz refreshes
        # do: every refresh then samples the same phases of the sweep.  4.7 Hz locks to no phase of it
        Variant("wheel-speed-4.7hz", "wheel speeds refreshed at 4.7 Hz (held; no phase lock with the sweep)",
                transforms=(HeldChannel("wheel_speed", 4.7),)),
        Variant("torque-10hz", "wheel torques (motor currents) refreshed at 10 Hz (held)",
                transforms=(HeldChannel("wheel_torque", 10.0),)),
        Variant("torque-2hz", "wheel torques (motor currents) refreshed at 2 Hz (held)",
                transforms=(HeldChannel("wheel_torque", 2.0),)),
        _limited("mass-com+20", "true mass +20 %, CoM 20 % further from the rear axle and 20 % higher",
                 "mass / normal-force scale", vehicle=VehicleChange(mass=1.2, com=1.2, height=1.2)),
        _limited("mass-com-20", "true mass -20 %, CoM 20 % closer to the rear axle and 20 % lower",
                 "mass / normal-force scale", vehicle=VehicleChange(mass=0.8, com=0.8, height=0.8)),
        Variant("s-turns", "S-turns during the traction test: yaw rate 0.3 sin(2 pi t / 4 s) rad/s",
                controller=ControllerParams(s_turn_rate=0.3, s_turn_period=4.0)),
        Variant("cruise", "constant speed, no traction test: slip ~0, K not identifiable", "no", mode="cruise"),
        # reversing, skid turns, an unknown payload or motor constant, a descent, a stall
        Variant("reverse", "traction test travelling backwards at 1 m/s: the rear (leading) axle sweeps, the front brakes",
                controller=ControllerParams(reverse=True)),
        Variant("reverse-braking", "the reverse traction test while the speed set-point swings 0.5..1.5 m/s every 4 s "
                "(accelerates and brakes)", controller=ControllerParams(reverse=True, speed_swing=0.5)),
        Variant("skid-spot-turn", "skid steer (one motor per side) turning on the spot at 0.6 rad/s on loam (K=100)", "no",
                scenario=SPOT_DRIVE, robot=SKID_STEER, sim=SKID_SIM, controller=ControllerParams(turn_in_place=True, turn_rate=0.6)),
        Variant("skid-arcs", "skid steer on a 2.5 m arc (0.4 rad/s at 1 m/s) during the traction test", robot=SKID_STEER, sim=SKID_SIM,
                controller=ControllerParams(turn_rate=0.4)),
        Variant("payload+25-accel-brake", "true mass +25 % (a payload the vehicle file does not know); the speed "
                "set-point swings 0.5..1.5 m/s every 4 s", vehicle=VehicleChange(mass=1.25),
                controller=ControllerParams(speed_swing=0.5)),
        _limited("payload+25", "true mass +25 % (a payload the vehicle file does not know), constant speed",
                 "mass (a common gross-traction scale)", vehicle=VehicleChange(mass=1.25), reason_names="torque scale"),
        Variant("motor+8-accel-brake", "motor constant 8 % above the vehicle file's (torque reads true / 1.08); the speed "
                "set-point swings 0.5..1.5 m/s every 4 s", transforms=(TorqueScale(1.0 / 1.08),),
                controller=ControllerParams(speed_swing=0.5)),
        _limited("motor+8", "motor constant 8 % above the vehicle file's (torque reads true / 1.08), constant speed",
                 "torque scale", transforms=(TorqueScale(1.0 / 1.08),), reason_names="torque scale"),
        Variant("slope-cruise-12", "cruise down a 12 deg slope over the four soils: only the grade's braking slip", "no",
                scenario=SLOPE_DRIVE),
        # another tyre, a payload with other swings, GNSS-grade ground speed: the estimator is not told
        _tyre("tyre-slow", "a tyre whose curve rises more slowly (S_T 0.37 / 0.51), sand -> loam, sweep 0.05..0.7 in 1.6 s",
              TYRE_SLOW, scenario=TYRE_TWO_SOILS, sweep=SweepParams(s_min=0.05, s_max=0.7, period=1.6, dwell=0.4)),
        _tyre("tyre-grippy", "a grippier tyre (S_T 0.29-0.40, mu_T 0.80-1.41), gravel -> K=160 -> firm -> gravel; the "
              "rear axle brakes at about -S while the front drives at S (a held speed cannot brake the grippy front's "
              "pull past its peak)", TYRE_GRIPPY, scenario=TYRE_SOFT_FIRM_SOFT, controller=ControllerParams(rear_mirror=1.0)),
        _tyre("tyre-grippy-skid", "the grippier tyre on a 120 kg skid steer (one motor per side: no axle sweeps, and "
              "its 40 N m motors cannot reach the peak; slips within +-0.15), gravel -> K=160 -> firm -> gravel: the drive "
              "never shows the peak", TYRE_GRIPPY,
              scenario=TYRE_SOFT_FIRM_SOFT, sim=SKID_SIM, robot=SKID_STEER + (("mass", 120.0), ("yaw_inertia", 7.0)),
              curve_shown=False),
        _tyre("tyre-gnss-50hz", "method.md's test tyre (S_T 0.41 / 0.53) at 50 Hz, GNSS speed (10 Hz, 0.1 s late, "
              "0.03 m/s), 5 % lost rows with jitter and duplicates, gravel -> grass, sweep 0.05..0.7 in 2 s", TYRE_VECTOR,
              scenario=GRAVEL_GRASS, rate=50.0, sweep=SweepParams(s_min=0.05, s_max=0.7, period=2.0, dwell=0.5),
              transforms=(gnss(), LostRows())),
        Variant("payload+25-swing30-sweep", "true mass +25 % (unknown payload), speed set-point swinging +-30 % every "
                "6 s between traction tests, gravel (K=80) -> K=160", vehicle=VehicleChange(mass=1.25),
                scenario=GRAVEL_FIRMER, controller=ControllerParams(speed_swing=0.3, speed_swing_period=6.0)),
        Variant("gnss-5hz-lost", "traction test with GNSS speed at 5 Hz, 0.15 s late, 0.03 m/s noise; 5 % lost rows "
                "with jitter and duplicates", transforms=(gnss(5.0, 0.15), LostRows())),
        Variant("gnss-cruise", "constant speed with GNSS speed (10 Hz, 0.1 s late, 0.03 m/s noise, held): slip ~0, "
                "K not identifiable", "no", mode="cruise", transforms=(gnss(),)),
        Variant("stall-draft", "firm soil (K=300) at 0.5 m/s towing a draft that rises to 1.3 x mu_T x weight: "
                "the robot stalls (V < 0.1 m/s) with its wheels spinning", "no", scenario=DRAFT_DRIVE, draft=Draft()),
    )
}


def list_variants() -> list[Variant]:
    return list(VARIANTS.values())


def get_variant(name: str) -> Variant:
    try:
        return VARIANTS[name]
    except (KeyError, TypeError):
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}; got {name!r}") from None
