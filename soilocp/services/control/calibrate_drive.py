"""The command side of a calibration drive over Zenoh (``soilocp calibrate-drive``).

It listens to the robot's sensor samples on ``soilocp/<vid>/sensors/raw`` (the gateway's input key, what any
driver of the robot publishes), and once they flow it publishes the protocol
(:mod:`soilocp.control.calibration_drive`) as :class:`soilocp.schemas.messages.DriveSetpoint` on
``soilocp/<vid>/control/drive`` at :data:`SETPOINT_HZ`, and with ROS 2 also as ``geometry_msgs/msg/Twist`` on
``cmd_vel`` through rmw_zenoh (the speed only: a Twist carries no slip).  It records every sample with the
protocol phase in force when it arrived, and ends with ``done`` set-points (speed 0).

It stops early, with a :class:`DriveFailed` that says what to check, when the robot does not answer (no sample
within ``answer_timeout_s``), stops publishing mid-drive (no sample for :data:`SILENCE_S`), or does not follow the
set-points (its speed stays far below the command).  Whatever happens, the last set-points it sends say stop.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import DriveSetpoint
from soilocp.control.calibration_drive import DriveProtocol

#: set-points per second
SETPOINT_HZ = 50.0
#: the robot stops by itself if no set-point arrives for this long (DriveSetpoint.timeout_s)
ROBOT_TIMEOUT_S = 0.5
#: a robot whose samples stop for this long mid-drive has gone
SILENCE_S = 2.0
#: s into the first swing at which the robot must move at least FOLLOW_SHARE of the commanded speed
FOLLOW_CHECK_S = 3.0
FOLLOW_SHARE = 0.3
#: ``done`` set-points at the end, s
DONE_S = 0.5


class DriveFailed(RuntimeError):
    """The drive could not be done; the message says why and what to check."""


@dataclass
class DriveRecording:
    """The samples the robot published during the drive, each with the protocol phase in force when it came."""

    lines: list[str] = field(default_factory=list)
    phases: list[str] = field(default_factory=list)
    setpoints: int = 0
    duration_s: float = 0.0


class _Recorder:
    def __init__(self, vehicle_id: str):
        self.vehicle_id = vehicle_id
        self.lock = threading.Lock()
        self.items: list[tuple[float, str]] = []  # (monotonic arrival, payload)
        self.last_wall: Optional[float] = None
        self.last_speed: Optional[float] = None

    def __call__(self, sample) -> None:
        now = time.monotonic()
        text = sample.payload.to_bytes().decode("utf-8", "replace")
        speed = None
        try:  # the speed only, for the follow check; the fit reads and validates every line later
            d = json.loads(text)
            speed = d.get("ground_speed")
        except ValueError:
            pass
        with self.lock:
            self.items.append((now, text))
            self.last_wall = now
            if isinstance(speed, (int, float)):
                self.last_speed = float(speed)

    def snapshot(self):
        with self.lock:
            return self.last_wall, self.last_speed, len(self.items)


class CmdVelPublisher:
    """``geometry_msgs/msg/Twist`` on ``topic`` through rmw_zenoh (a second session on the robot's router)."""

    def __init__(self, connect: list[str], topic: str = "/cmd_vel", domain_id: int = 0):
        import zenoh

        from soilocp.services.ros2 import rmw_zenoh

        self.rmw = rmw_zenoh
        self.session = zenoh.open(rmw_zenoh.ros_session_config(list(connect), connect_timeout_ms=3000))
        self.node = rmw_zenoh.RosNode(self.session, domain_id, "soilocp_calibrate_drive")
        self.pub = self.node.publisher(rmw_zenoh.check_topic(topic), "geometry_msgs/msg/Twist")
        types = rmw_zenoh.typestore().types
        self.Twist, self.Vector3 = types["geometry_msgs/msg/Twist"], types["geometry_msgs/msg/Vector3"]

    def publish(self, speed: float) -> None:
        self.pub.publish(self.Twist(linear=self.Vector3(x=float(speed), y=0.0, z=0.0),
                                    angular=self.Vector3(x=0.0, y=0.0, z=0.0)))

    def close(self) -> None:
        self.rmw.close_ros(self.node, self.session)


def run_drive(vehicle_id: str, connect: list[str], protocol: DriveProtocol, *, answer_timeout_s: float = 10.0,
              ros2: Optional[dict] = None, progress: Callable[[str], None] = print,
              stop: Optional[threading.Event] = None) -> DriveRecording:
    """Drive ``protocol`` on the robot ``vehicle_id`` reached through the Zenoh router(s) ``connect`` (module doc).

    ``ros2``: ``{"connect": [...], "topic": "/cmd_vel", "domain_id": 0}`` to publish the speed as ``cmd_vel`` too."""
    import zenoh

    from soilocp.services.runtime.settings import zenoh_config

    keys.check_vehicle_id(vehicle_id)
    stop = stop or threading.Event()
    conf = zenoh_config("client", list(connect), [], multicast=False, connect_timeout_ms=3000)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise DriveFailed(f"no Zenoh router answers at {', '.join(connect)} ({exc}): start the robot's router, or "
                          "give its endpoint with --connect") from None
    rec = _Recorder(vehicle_id)
    cmd_vel = None
    sub = pub = None
    t0 = None
    seq = 0
    try:
        sub = session.declare_subscriber(keys.raw(vehicle_id), rec)
        pub = session.declare_publisher(keys.control_drive(vehicle_id))
        if ros2 is not None:
            try:
                cmd_vel = CmdVelPublisher(ros2["connect"], ros2.get("topic", "/cmd_vel"), ros2.get("domain_id", 0))
            except Exception as exc:  # noqa: BLE001 - said to the user with the endpoint
                raise DriveFailed(f"cannot publish cmd_vel through rmw_zenoh at {', '.join(ros2['connect'])}: {exc}") from None
        progress(f"waiting for the robot's samples on {keys.raw(vehicle_id)} (at most {answer_timeout_s:g} s)")
        deadline = time.monotonic() + answer_timeout_s
        while rec.snapshot()[2] == 0:
            if stop.is_set():
                raise DriveFailed("interrupted before the drive started")
            if time.monotonic() > deadline:
                raise DriveFailed(f"the robot does not answer: no sensor sample on {keys.raw(vehicle_id)} within "
                                  f"{answer_timeout_s:g} s; check that it runs with vehicle id {vehicle_id!r} and is "
                                  f"connected to {', '.join(connect)}")
            time.sleep(0.05)
        progress(f"robot {vehicle_id} answers; driving {protocol.duration:g} s: "
                 + ", ".join(f"{p} {a:.1f}-{b:.1f} s" for p, a, b in protocol.phases()))
        period = 1.0 / SETPOINT_HZ
        t0 = time.monotonic()
        next_report = 5.0
        swing_start = next(a for p, a, _b in protocol.phases() if p == "swing")
        followed = False
        while True:
            now = time.monotonic()
            t = now - t0
            if t >= protocol.duration or stop.is_set():
                break
            cmd = protocol.at(t)
            _put(pub, cmd_vel, vehicle_id, seq, t, cmd.phase, cmd.speed, cmd.slip)
            seq += 1
            last_wall, speed, n = rec.snapshot()
            if last_wall is not None and now - last_wall > SILENCE_S:
                raise DriveFailed(f"the robot stopped publishing at t = {last_wall - t0:.1f} s of the drive (no sample "
                                  f"for {now - last_wall:.1f} s): check the robot and its link; nothing was written")
            if not followed and t >= swing_start + FOLLOW_CHECK_S:
                if speed is None or speed < FOLLOW_SHARE * cmd.speed:
                    raise DriveFailed(
                        f"the robot does not follow the set-points: at t = {t:.1f} s the command is {cmd.speed:.2f} m/s "
                        f"and its ground speed reads {'none' if speed is None else format(speed, '.2f')}; check that it "
                        f"listens on {keys.control_drive(vehicle_id)}"
                        + (" or on cmd_vel" if ros2 else " (a ROS 2 robot: --ros2)") + " and is allowed to move")
                followed = True
            if t >= next_report:
                progress(f"t = {t:4.1f} s  {cmd.phase:5s}  speed set-point {cmd.speed:.2f} m/s"
                         + (f", slip {cmd.slip:.2f}" if cmd.slip is not None else "")
                         + f"; robot {'?' if speed is None else format(speed, '.2f')} m/s, {n} samples")
                next_report += 5.0
            time.sleep(max(0.0, t0 + seq * period - time.monotonic()))
        if stop.is_set():
            raise DriveFailed("interrupted: the robot was told to stop; nothing was written")
    finally:
        if pub is not None:  # whatever happened: stop
            t_end = time.monotonic() + DONE_S
            while time.monotonic() < t_end:
                try:
                    _put(pub, cmd_vel, vehicle_id, seq, 0.0 if t0 is None else time.monotonic() - t0, "done", 0.0, None)
                except Exception:  # noqa: BLE001 - a closing session must not hide the first error
                    break
                seq += 1
                time.sleep(1.0 / SETPOINT_HZ)
        for ent in (sub, pub):
            if ent is not None:
                try:
                    ent.undeclare()
                except Exception:  # noqa: BLE001
                    pass
        if cmd_vel is not None:
            cmd_vel.close()
        session.close()
    out = DriveRecording(setpoints=seq, duration_s=protocol.duration)
    for wall, text in rec.items:
        ph = protocol.at(wall - t0).phase if wall >= t0 else "before"
        if ph in ("before", "done"):
            continue  # at rest before the start and after the end: nothing to fit
        out.lines.append(text)
        out.phases.append(ph)
    return out


def _put(pub, cmd_vel, vehicle_id, seq, t, phase, speed, slip) -> None:
    msg = DriveSetpoint(vehicle_id=vehicle_id, seq=seq, t=max(t, 0.0), phase=phase, speed=max(speed, 0.0), slip=slip,
                        timeout_s=ROBOT_TIMEOUT_S, issued_at=time.time())
    pub.put(msg.model_dump_json())
    if cmd_vel is not None:
        cmd_vel.publish(speed)
