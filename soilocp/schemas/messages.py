"""Service messages: rejections, health/status and the OCP query reply.

The stage messages (NormalForces, ObserverOutput, SoilEstimate, OcpEstimate) live in
:mod:`soilocp.schemas.pipeline`; the raw sample in :mod:`soilocp.schemas.sensor`.
"""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field

from soilocp.schemas.pipeline import OcpEstimate
from soilocp.schemas.sensor import VehicleId

SERVICE_SCHEMA_VERSION = 1

#: Longest raw payload excerpt a Rejection carries (characters).
REJECTION_PAYLOAD_MAX = 512
#: Rejections per second and vehicle the gateway publishes at most, in bursts of as many: a flood of garbage
#: must not flood the bus and every subscriber of it; the rest are counted (``Rejection.suppressed`` and the
#: gateway's health), not published
REJECTION_PUBLISH_RATE = 50.0

RejectionCode = Literal[
    "malformed_json",  # not JSON / not UTF-8
    "too_large",  # payload longer than the gateway's limit
    "schema",  # wrong type, missing or extra key, not an object
    "non_finite",  # NaN or +-inf anywhere (JSON literals or overflowing numbers)
    "out_of_range",  # outside the schema's plausibility limits / physically impossible
    "stamp_backwards",  # stamp not after the last accepted stamp of this vehicle
    "duplicate_seq",  # seq equal to the last accepted seq
    "old_seq",  # seq below the last accepted seq
    "vehicle_mismatch",  # payload vehicle_id differs from the id in its key
    "bad_key",  # sample arrived on a key that is not exactly this vehicle's raw key
]


class _ServiceMessage(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    schema_version: Literal[1] = SERVICE_SCHEMA_VERSION


class Rejection(_ServiceMessage):
    """A raw sample the gateway refused, with a machine-readable reason. Never forwarded."""

    vehicle_id: VehicleId = Field(description="Vehicle id taken from the key the sample arrived on")
    seq: Optional[int] = Field(default=None, description="The sample's seq, if it could be read")
    stamp: Optional[float] = Field(default=None, description="The sample's stamp, if it could be read")
    code: RejectionCode = Field(description="Machine-readable reason")
    field: Optional[str] = Field(default=None, description="Offending field path (dotted), when one is known")
    message: str = Field(description="Human-readable reason naming the field and value")
    payload: str = Field(
        description=f"The raw payload as text (invalid UTF-8 replaced), truncated to {REJECTION_PAYLOAD_MAX} characters"
    )
    payload_size: int = Field(ge=0, description="Size of the raw payload, bytes")
    key: str = Field(description="The key the sample arrived on")
    received_at: float = Field(description="Gateway wall-clock time of reception, s since the Unix epoch")
    suppressed: int = Field(
        0, ge=0, description=f"Rejections of this vehicle counted but not published since the previous published "
        f"one: under a flood the gateway publishes at most {REJECTION_PUBLISH_RATE:g} a second; every rejection, "
        "published or not, is in its health's rejected_<code> counters")


class ServiceHealth(_ServiceMessage):
    """Health and counters of one service for one vehicle (``soilocp/<vid>/status/<service>``)."""

    service: str = Field(description="The service's name (gateway, normal-force, observer, soil-strength, ocp, ...)")
    vehicle_id: VehicleId
    pid: int = Field(description="Its process id")
    host: str = Field(description="The host name of the machine it runs on")
    state: Literal["starting", "running", "failing", "stale", "stopping"] = Field(
        description="running; failing (most recent inputs fail: see failure_rate and the log); or stale (OCP "
        "publisher: no input for longer than stale_timeout_s)"
    )
    uptime_s: float = Field(ge=0, description="Seconds since the service started")
    received: int = Field(ge=0, description="Messages received on the service's input keys")
    published: int = Field(ge=0, description="Messages published on its output key")
    rejected: int = Field(ge=0, description="Inputs refused (gateway: rejections published)")
    dropped: int = Field(ge=0, description="Inputs dropped: worker queue full, or never joined (observer)")
    errors: int = Field(ge=0, description="Inputs whose processing raised (logged)")
    failure_rate: float = Field(default=0.0, ge=0, le=1, description="Share of the last ~20 inputs whose processing failed")
    queue_depth: int = Field(ge=0, description="Items waiting in the worker queue")
    last_seq: Optional[int] = Field(default=None, description="seq of the last processed input")
    last_stamp: Optional[float] = Field(default=None, description="stamp of the last processed input")
    last_input_age_s: Optional[float] = Field(default=None, description="Wall-clock seconds since the last input")
    stale: Optional[bool] = Field(default=None, description="OCP publisher only: output is stale")
    detail: dict[str, float | int | str | bool | None] = Field(
        default_factory=dict, description="Service-specific counters (e.g. rejections per code)"
    )
    time: float = Field(description="Wall-clock time of this report, s since the Unix epoch")


ProcessState = Literal["running", "restarted", "died", "stopped", "done", "killed"]


class SupervisedProcess(_ServiceMessage):
    """One process a supervisor runs, under its name (the latest process of that name)."""

    name: str = Field(description="The process's name in the run: router, gateway, ..., map, vehicle")
    pid: Optional[int] = Field(description="Its process id (null: not started)")
    state: ProcessState = Field(description="running; died (not restarted); stopped, done or killed at the end")
    restarts: int = Field(ge=0, description="How often the supervisor started it again after it died")
    last_restart_age_s: Optional[float] = Field(
        default=None, ge=0, description="Seconds from its last restart to this report (null: never restarted)")
    last_exit: Optional[int] = Field(
        default=None, description="Exit status of the process that died last (negative: killed by that signal)")


class SupervisorStatus(_ServiceMessage):
    """What the supervisor of ``soilocp run`` runs for one vehicle and what it restarted
    (``soilocp/<vid>/supervisor``: published at each restart and answered as a query)."""

    vehicle_id: VehicleId
    pid: int = Field(description="The supervisor's process id")
    host: str = Field(description="The host name of the machine it runs on")
    restart: bool = Field(description="Processes that die are restarted (soilocp run --restart); else the run stops")
    processes: list[SupervisedProcess] = Field(description="Each process it runs, with its restarts")
    time: float = Field(description="Wall-clock time of this report, s since the Unix epoch")


class OcpReply(_ServiceMessage):
    """Answer of the OCP queryable ``soilocp/<vid>/ocp`` (``?last=N`` / ``?since=STAMP`` add a history)."""

    vehicle_id: VehicleId
    stale: bool = Field(
        description="True if no input arrived for longer than stale_timeout_s (or none yet): do not use 'latest' blindly"
    )
    age_s: Optional[float] = Field(description="Wall-clock seconds since the latest estimate was produced (null: none yet)")
    stale_timeout_s: float = Field(gt=0, description="Seconds without input after which the publisher is stale")
    latest: Optional[OcpEstimate] = Field(description="The latest estimate (its status says 'stale' when stale)")
    history: Optional[list[OcpEstimate]] = Field(
        default=None, description="Estimates selected by ?last=N or ?since=STAMP, oldest first (null without them)"
    )
    history_capacity: int = Field(ge=1, description="How many estimates the publisher keeps")


SlipSetpointSource = Literal["estimate", "fallback", "fixed", "none"]


class SlipSetpoint(_ServiceMessage):
    """Wheel slip set-points of the controller service (``soilocp/<vid>/control/slip``).

    Published on every OCP estimate, and while the OCPs are stale or missing, every half stale
    timeout with the safe fallback (``source: "fallback"``).  The vehicle's own torque loops track
    them (slip limiters under its speed command); a vehicle that hears no set-point for longer than
    ``stale_timeout_s`` applies ``fallback`` itself."""

    vehicle_id: VehicleId
    controller: str = Field(description="Controller name: speed, fixed_<slip>, ocp_traction, ocp_efficiency")
    slip: Optional[tuple[float, float, float, float]] = Field(
        description="Slip set-point per wheel (1 LR, 2 LF, 3 RF, 4 RR), eq. 1; null: no slip control (speed)")
    source: SlipSetpointSource = Field(description="estimate (from the live OCP), fallback (safe), fixed, none")
    reason: str = Field(default="", description="Why the fallback is in use")
    fallback: Optional[float] = Field(description="The safe slip set-point of this controller (null: none)")
    seq: Optional[int] = Field(default=None, description="seq of the sensor sample whose estimate gave the set-point")
    stamp: Optional[float] = Field(default=None, description="stamp of that sample, s")
    soil_strength: Optional[float] = Field(default=None, description="K the set-point came from")
    ocp_age_s: Optional[float] = Field(default=None, description="Wall-clock s since the last OCP (null: none yet)")
    stale_timeout_s: float = Field(gt=0, description="Seconds without an OCP after which the controller falls back")
    issued_at: float = Field(description="Wall-clock time of publication, s since the Unix epoch")


class DriveSetpoint(_ServiceMessage):
    """One set-point of a calibration drive (``soilocp/<vid>/control/drive``, ``soilocp calibrate-drive``).

    Published at a fixed rate (50 Hz) while the drive lasts, then ``phase: "done"`` with speed 0 a few times.
    The robot drives straight at ``speed``; with ``slip`` set, its front axle tracks that driving slip
    (eq. 1) while the rear axle brakes to hold the speed (a traction test).  A robot that hears no set-point
    for longer than ``timeout_s`` stops by itself: a dead or unplugged command side must not leave a robot
    sweeping its slip."""

    vehicle_id: VehicleId
    seq: int = Field(ge=0, description="Counts the set-points of this drive from 0")
    t: float = Field(ge=0, description="s since the drive's start (the protocol's clock)")
    phase: Literal["start", "swing", "sweep", "stop", "done"] = Field(
        description="start (from rest), swing (accelerate and brake), sweep (front-axle slip sweep), stop, done")
    speed: float = Field(ge=0, le=5, description="Speed set-point, m/s, forward")
    slip: Optional[float] = Field(default=None, ge=0, lt=0.95,
                                  description="Front-axle driving slip set-point (eq. 1); null: every wheel holds the speed")
    timeout_s: float = Field(gt=0, description="Stop if no set-point arrives for this long, s")
    issued_at: float = Field(description="Wall-clock time of publication, s since the Unix epoch")
