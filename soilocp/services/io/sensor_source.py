"""Synthetic vehicle: publishes sensor samples on ``soilocp/<vid>/sensors/raw``.

Either a simulator scenario in real time (``--scenario NAME``, :func:`soilocp.sim.simulator.simulate`)
or a sensor log replayed line by line (``--replay FILE``), paced by the samples' stamps divided by
``--speed`` (``--speed 0``: as fast as possible).  A replayed line is published byte for byte, bad
lines included, so a log with hostile samples exercises the gateway.  Before publishing it waits
(bounded) until the pipeline services' liveliness tokens are visible, so that no sample is lost to
a subscriber that is not there yet.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Iterator, Optional

from soilocp.schemas import keys
from soilocp.services.supervisor.liveliness import wait_alive
from soilocp.services.stages.graph import PIPELINE_SERVICES

from soilocp.services.runtime.service import Service


def replay_source(path: str, duration: Optional[float] = None) -> Iterator[tuple[bytes, Optional[float]]]:
    """Lines of a sensor log as ``(payload, stamp or None)``; blank lines are skipped.

    Not a generator itself: a missing file or a bad duration raises ValueError here, at startup.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"replay file {path!r} does not exist or is not a file")
    if duration is not None and not duration > 0:
        raise ValueError(f"duration {duration!r}: must be > 0 s")
    return _replay_lines(p, duration)


def _replay_lines(p: Path, duration: Optional[float]) -> Iterator[tuple[bytes, Optional[float]]]:
    first: Optional[float] = None
    with p.open("rb") as fh:
        for line in fh:
            line = line.strip()
            if not line:
                continue
            stamp: Optional[float] = None
            try:
                obj = json.loads(line)
                s = obj.get("stamp") if isinstance(obj, dict) else None
                if isinstance(s, (int, float)) and not isinstance(s, bool) and s == s and abs(s) != float("inf"):
                    stamp = float(s)
            except (ValueError, UnicodeDecodeError, RecursionError):
                pass
            if stamp is not None:
                if first is None:
                    first = stamp
                elif duration is not None and stamp - first > duration:
                    return
            yield line, stamp


def scenario_source(scenario: str, vehicle_id: str, *, duration: Optional[float], rate: float, seed: int
                    ) -> Iterator[tuple[bytes, Optional[float]]]:
    """Samples of a simulator scenario as ``(SensorSample JSON, stamp)``.

    Not a generator itself: a bad scenario name or argument raises ValueError here, at startup.
    """
    import os

    from soilocp.sim.field import ENV_START_POSE, parse_start_pose
    from soilocp.sim.simulator import simulate  # the simulator is only needed for this source

    # SOILOCP_START_POSE: the vehicle drives in a map frame and its samples carry positions (docs/map.md)
    start = parse_start_pose(os.environ[ENV_START_POSE]) if os.environ.get(ENV_START_POSE) else None
    samples = simulate(scenario, duration=duration, rate=rate, seed=seed, vehicle_id=vehicle_id, start=start)
    return ((sample.model_dump_json().encode(), sample.stamp) for sample, _truth in samples)


class VehicleService(Service):
    name = "vehicle"

    def __init__(self, cfg, log, *, source: Iterator[tuple[bytes, Optional[float]]], speed: float = 1.0,
                 wait_for: tuple[str, ...] = PIPELINE_SERVICES, wait_timeout_s: float = 20.0,
                 describe: str = "", inbox=None):
        super().__init__(cfg, log)
        if speed < 0 or speed != speed:
            raise ValueError(f"speed {speed!r}: must be >= 0 (0 = as fast as possible)")
        self.source = source
        self.speed = float(speed)
        self.wait_for = tuple(wait_for)
        self.wait_timeout_s = float(wait_timeout_s)
        self.describe = describe
        self.inbox = inbox  # closed loop: soilocp.services.control.vehicle_control.SetpointInbox (None: open loop)
        self.pub = None
        self._thread: Optional[threading.Thread] = None
        self._done = threading.Event()

    def declare(self, session, vehicle_id: str) -> None:
        if vehicle_id != self.cfg.vehicle_id:
            return  # one source feeds one vehicle
        self.pub = self.publisher(session, keys.raw(vehicle_id))
        if self.inbox is not None:  # the callback only stores: the torque loop reads the latest
            offer, counters = self.inbox.offer, self.counters[vehicle_id]

            def _setpoint(sample) -> None:
                counters.received += 1
                offer(sample.payload.to_bytes())

            key = getattr(self.inbox, "key", keys.control_slip)  # a calibration drive's inbox has its own key
            self.keep(session.declare_subscriber(key(vehicle_id), _setpoint))
        self._thread = threading.Thread(target=self._publish_all, name="vehicle-source", daemon=True)
        self._thread.start()

    def handle(self, item) -> None:  # the vehicle has no inputs
        return None

    def _wait_for_pipeline(self) -> None:
        if not self.wait_for:
            return
        vid = self.cfg.vehicle_id
        missing = wait_alive(self.session, [vid], self.wait_for, self.wait_timeout_s, stop=self.stop_event)
        if self.stop_event.is_set():
            return
        if missing:
            self.log.warning("pipeline_not_ready", vehicle_id=vid, missing=sorted(s for _v, s in missing),
                             waited_s=self.wait_timeout_s)
        else:
            self.log.info("pipeline_ready", vehicle_id=vid, services=sorted(self.wait_for))

    def _publish_all(self) -> None:
        vid = self.cfg.vehicle_id
        c = self.counters[vid]
        try:
            self._wait_for_pipeline()
            self.log.info("publishing", vehicle_id=vid, source=self.describe, speed=self.speed)
            t0: Optional[float] = None
            s0: Optional[float] = None
            for payload, stamp in self.source:
                if self.stop_event.is_set():
                    break
                if self.speed > 0 and stamp is not None:
                    if t0 is None:
                        t0, s0 = time.monotonic(), stamp
                    delay = t0 + (stamp - s0) / self.speed - time.monotonic()
                    if delay > 0 and self.stop_event.wait(delay):
                        break
                if self.inbox is not None and stamp is not None:
                    self.inbox.sent(stamp, time.perf_counter())
                self.pub.put(payload)
                c.published += 1
                c.last_stamp = stamp
            self.log.info("source_done", vehicle_id=vid, published=c.published,
                          **(self.inbox.latency_summary() if self.inbox is not None else {}))
        except Exception as exc:  # a broken source (bad scenario, unreadable file) ends the process non-zero
            self.exit_code = 1
            self.log.error("source_failed", vehicle_id=vid, error=f"{type(exc).__name__}: {exc}"[:500])
        finally:
            self._done.set()

    def health_extra(self, vehicle_id: str) -> dict:
        if self.inbox is None:
            return {}
        sp = self.inbox.current()
        return {"detail": {**self.counters[vehicle_id].detail, **self.inbox.latency_summary(),
                           "control": self.inbox.control, "setpoint": sp.value, "setpoint_source": sp.source,
                           "setpoints_received": self.inbox.received,
                           **{f"setpoints_{k}": v for k, v in self.inbox.sources.items()}}}

    def tick(self, now: float) -> None:
        if self._done.is_set():
            # let the last puts leave the process before the session closes
            time.sleep(0.2)
            self.stop_event.set()
