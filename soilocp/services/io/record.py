"""``soilocp record``: the live OCP and sensor streams of one vehicle or a fleet -> MCAP files for
Foxglove.

A client session subscribes to ``soilocp/<vid>/ocp`` and ``soilocp/<vid>/sensors/raw``
(``--vehicle-id``, repeatable) or to every vehicle's (``soilocp/*/...``); each valid OCP record and
sensor sample is written through the library's MCAP writer (:mod:`soilocp.export.mcap_out`: the
channels of ``soilocp estimate --out E.mcap`` and of the live Foxglove server) into rotating files
of bounded size.  A payload that fails its contract (``OcpEstimate``, ``SensorSample``), or whose
vehicle id is not its key's, is counted (``invalid``) and not written.  The Zenoh callbacks only
enqueue (bounded; the oldest item is dropped and counted when the disk falls behind), a worker
thread writes.  SIGINT / SIGTERM close the current file properly (a readable MCAP with its summary)
and exit 0.
"""

from __future__ import annotations

import queue
import signal
import threading
import time
from typing import Optional

import click

from soilocp.schemas import keys

from soilocp.services.runtime.config import DEFAULT_ENDPOINT

from soilocp.services.runtime.log import JsonLog

from soilocp.services.runtime.process import open_session

from soilocp.services.io.streams import decode, selectors

QUEUE_MAX = 10_000  # OCP records and sensor samples; ~50 s of one vehicle at 100 Hz


def run_record(connect: list[str], vehicle_ids: list[str], out: str, *, max_bytes: int, max_files: int,
               duration: Optional[float] = None, log: Optional[JsonLog] = None) -> int:
    from soilocp.export.mcap_out import RotatingMcapWriter

    log = log or JsonLog("record")
    for vid in vehicle_ids:
        keys.check_vehicle_id(vid)
    writer = RotatingMcapWriter(out, max_bytes=max_bytes, max_files=max_files)
    stop = threading.Event()
    q: "queue.Queue[tuple[str, str, bytes]]" = queue.Queue(maxsize=QUEUE_MAX)
    # written: OCP records; sensors: sensor samples
    counts = {"written": 0, "sensors": 0, "invalid": 0, "dropped": 0}

    def on_signal(_sig, _frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def enqueue(item: tuple[str, str, bytes]) -> None:
        while True:
            try:
                q.put_nowait(item)
                return
            except queue.Full:
                try:
                    q.get_nowait()
                    counts["dropped"] += 1
                except queue.Empty:
                    pass

    def callback(kind: str):
        return lambda sample: enqueue((kind, str(sample.key_expr), bytes(sample.payload.to_bytes())))

    def worker() -> None:
        while not (stop.is_set() and q.empty()):
            try:
                kind, key, payload = q.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                data = decode(kind, key, payload)
            except ValueError as exc:
                counts["invalid"] += 1
                if counts["invalid"] <= 5:
                    log.warning("invalid_sample", key=key, error=str(exc)[:200])
                continue
            if kind == "ocp":
                writer.write(data)
                counts["written"] += 1
            else:
                writer.write_sensor(data)
                counts["sensors"] += 1

    streams = selectors(vehicle_ids)
    keys_subscribed = [sel for _kind, sel in streams]
    session = open_session("client", connect, [], multicast=False, stop=stop, log=log)
    if session is None:
        writer.close()
        return 0
    th = threading.Thread(target=worker, name="record-writer", daemon=True)
    th.start()
    subs = []
    try:
        subs = [session.declare_subscriber(sel, callback(kind)) for kind, sel in streams]
        log.info("recording", keys=keys_subscribed, out=out, max_bytes=max_bytes, max_files=max_files)
        t_end = None if duration is None else time.monotonic() + duration
        last = dict(counts)
        while not stop.is_set():
            if t_end is not None and time.monotonic() >= t_end:
                break
            stop.wait(0.5)
            if counts != last:  # progress for operators (and tests): what is on disk so far
                last = dict(counts)
                log.info("progress", files=len(writer.files), **last)
    finally:
        for s in subs:
            s.undeclare()
        stop.set()
        th.join(timeout=10)
        writer.close()
        session.close()
        for s, h in old.items():
            signal.signal(s, h)
    log.info("stopped", files=[str(p) for p in writer.files], **counts)
    return 0


@click.command("record")
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="F.mcap: files F_0000.mcap, F_0001.mcap, ... are written")
@click.option("--vehicle-id", "vehicle_ids", multiple=True, help="Vehicle to record (repeatable); default: every vehicle")
@click.option("--connect", multiple=True, help=f"Router endpoint(s); default {DEFAULT_ENDPOINT}")
@click.option("--max-mb", type=float, default=64.0, show_default=True, help="Start a new file past this size, MB")
@click.option("--max-files", type=int, default=10, show_default=True, help="Keep at most this many files (oldest deleted)")
@click.option("--duration", type=float, help="Stop after this many seconds (default: at SIGINT/SIGTERM)")
def record_cmd(out, vehicle_ids, connect, max_mb, max_files, duration) -> None:
    """Record the live estimates and sensors of one vehicle or the fleet to rotating MCAP files (Foxglove)."""
    import sys

    try:
        code = run_record(list(connect) or [DEFAULT_ENDPOINT], list(vehicle_ids), out,
                          max_bytes=int(max_mb * 1024 * 1024), max_files=max_files, duration=duration)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    sys.exit(code)


COMMANDS = [record_cmd]
