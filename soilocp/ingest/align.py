"""Streams of different rates on one clock, and the sensor samples made from them.

Every importer (ROS 2 bag, CSV) turns its source into :class:`Stream` objects (integer nanosecond
stamps, non-decreasing, and named value arrays), then :func:`align` puts them on one clock of
``rate_hz`` ticks: at each tick a stream contributes its newest value stamped at or before the
tick (last value held), unless that value is older than the stream's ``max_age``: then the
stream is stale there and the tick is skipped, with the reason counted.  Stale data is never
written as fresh.  :func:`samples_from_aligned` makes the sensor-log objects and
:class:`Provenance` records what the log cannot say on its own (e.g. that there was no
independent ground speed).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterator, Optional

import numpy as np
from pydantic import ValidationError

from soilocp.schemas.sensor import SensorSample

NS = 1_000_000_000


@dataclass
class Stream:
    """One source of values with its own stamps (ns, non-decreasing) and its maximum age (s)."""

    name: str  # e.g. "imu (/imu/data)": used in reasons
    stamps: np.ndarray  # int64 ns
    values: dict[str, np.ndarray]  # field -> (n,) or (n, k)
    max_age: float
    optional: bool = False  # where the vehicle is: attached where fresh, never a reason to skip a tick

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=np.int64)
        if self.stamps.size and np.any(np.diff(self.stamps) < 0):
            raise ValueError(f"{self.name}: stamps must not go backwards (importer bug)")


@dataclass
class Aligned:
    stamps: np.ndarray  # int64 ns of the kept ticks
    seq: np.ndarray  # tick index from the first tick (gaps where ticks were skipped)
    values: dict[str, np.ndarray]
    ticks: int
    skipped: Counter


def align(streams: list[Stream], rate_hz: float) -> Aligned:
    """Put ``streams`` on one clock of ``rate_hz`` ticks (last value held up to each stream's max age).

    Ticks run from the first instant every stream has a value to the last instant any of them is
    still fresh (beyond that every tick would be stale).  A skipped tick counts one reason: the
    first stale stream, as ``"stale <name>"``.
    """
    optional = [s for s in streams if s.optional]
    streams = [s for s in streams if not s.optional]
    if not streams:
        raise ValueError("nothing to align: no streams")
    for s in streams:
        if s.stamps.size == 0:
            raise ValueError(f"{s.name}: no usable messages")
    start = max(int(s.stamps[0]) for s in streams)
    end = min(int(s.stamps[-1]) + int(s.max_age * NS) for s in streams)
    n = tick_count(start, end, rate_hz)
    if n <= 0:
        raise ValueError("the streams do not overlap in time: " + ", ".join(
            f"{s.name} {s.stamps[0] / NS:.3f}..{s.stamps[-1] / NS:.3f} s" for s in streams))
    return pick(streams + optional, start, 0, n, rate_hz)


def tick_count(start: int, end: int, rate_hz: float) -> int:
    """Ticks of ``rate_hz`` from ``start`` up to and including ``end`` (ns)."""
    period = NS / rate_hz
    return int(math.floor((end - start) / period)) + 1 if end >= start else 0


def tick_stamps(start: int, first: int, n: int, rate_hz: float) -> np.ndarray:
    """Stamps (ns) of ticks ``first .. first + n - 1`` of the clock that starts at ``start``."""
    return start + np.round(np.arange(first, first + n) * (NS / rate_hz)).astype(np.int64)


def pick(streams: list[Stream], start: int, first: int, n: int, rate_hz: float) -> Aligned:
    """Ticks ``first .. first + n - 1`` of the clock that starts at ``start``: for each stream the
    newest value stamped at or before the tick, unless older than its max age (then the tick is
    skipped, counted under the first stale stream).  The bag import calls it once for the whole
    log (:func:`align`), the live reader (:mod:`soilocp.ingest.live`) once per batch of ticks that
    no later message can change; both get the same ticks, seqs and values."""
    optional = [s for s in streams if s.optional]  # positions: attached where fresh, never skip a tick
    streams = [s for s in streams if not s.optional]
    ticks = tick_stamps(start, first, n, rate_hz)
    keep = np.ones(n, dtype=bool)
    skipped: Counter = Counter()
    picks = []
    for s in streams:
        idx = np.searchsorted(s.stamps, ticks, side="right") - 1
        fresh = (idx >= 0) & (ticks - s.stamps[np.maximum(idx, 0)] <= int(round(s.max_age * NS)))
        newly = keep & ~fresh
        if newly.any():
            skipped[f"stale {s.name} (older than {s.max_age:g} s)"] += int(newly.sum())
        keep &= fresh
        picks.append(np.maximum(idx, 0))
    values: dict[str, np.ndarray] = {}
    for s, idx in zip(streams, picks):
        for k, v in s.values.items():
            values[k] = np.asarray(v)[idx[keep]]
    kept = ticks[keep]
    for s in optional:  # fresh value or none (NaN), per kept tick
        idx = np.searchsorted(s.stamps, kept, side="right") - 1
        fresh = (idx >= 0) & (kept - s.stamps[np.maximum(idx, 0)] <= int(round(s.max_age * NS))) if s.stamps.size \
            else np.zeros(kept.size, dtype=bool)
        for k, v in s.values.items():
            v = np.asarray(v)
            if not s.stamps.size:
                values[k] = np.full(kept.size, np.nan if v.dtype != object else None, dtype=v.dtype)
                continue
            col = v[np.maximum(idx, 0)]
            values[k] = np.where(fresh, col, None) if v.dtype == object else np.where(fresh, col, np.nan)
    return Aligned(kept, first + np.flatnonzero(keep), values, n, skipped)


@dataclass
class Provenance:
    """What the sensor log itself cannot say: where each field came from and what is identifiable.

    Written beside the log as ``<log>.provenance.json``; ``soilocp estimate`` reads it and withholds
    K and the OCPs when ``identifiable`` is false (status no_estimate, reason not_identifiable).
    """

    source: str
    ground_speed: str = "measured"  # measured | absent (null in the log: slip, eq. 1, and K are not identifiable)
    wheel_torque: str = "torque"  # torque | current_unknown_scale
    drive: str = "per_wheel"
    attitude: str = "orientation"  # orientation | gyro+accelerometer (complementary filter)
    identifiable: bool = True
    reasons: list[str] = field(default_factory=list)
    ticks: int = 0
    samples: int = 0
    skipped: dict = field(default_factory=dict)
    dropped_messages: dict = field(default_factory=dict)

    def withhold_reason(self) -> Optional[str]:
        return None if self.identifiable else "not_identifiable: " + "; ".join(self.reasons)

    def write(self, log_path: str | Path) -> Path:
        p = provenance_path(log_path)
        p.write_text(json.dumps(asdict(self), indent=2) + "\n", encoding="utf-8")
        return p


def provenance_path(log_path: str | Path) -> Path:
    return Path(str(log_path) + ".provenance.json")


def read_provenance(log_path: str | Path) -> Optional[Provenance]:
    p = provenance_path(log_path)
    if not p.is_file():
        return None
    try:
        return Provenance(**json.loads(p.read_text(encoding="utf-8")))
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{p}: not a provenance file: {exc}") from None


def samples_from_aligned(al: Aligned, vehicle_id: str, skipped: Counter) -> Iterator[SensorSample]:
    """SensorSamples from aligned values (keys: specific_force (n,3), roll, pitch, yaw_rate,
    wheel_speed (n,4), wheel_torque (n,4), ground_speed); stamps in seconds (Unix time when the
    source is).  A tick whose values break the sensor contract is skipped and counted by field."""
    v = al.values
    for i in range(al.stamps.size):
        try:
            yield SensorSample(
                vehicle_id=vehicle_id,
                seq=int(al.seq[i]),
                stamp=int(al.stamps[i]) / NS,
                specific_force=tuple(float(x) for x in v["specific_force"][i]),
                roll=float(v["roll"][i]),
                pitch=float(v["pitch"][i]),
                yaw_rate=float(v["yaw_rate"][i]),
                wheel_speed=tuple(float(x) for x in v["wheel_speed"][i]),
                wheel_torque=tuple(float(x) for x in v["wheel_torque"][i]),
                ground_speed=None if np.isnan(v["ground_speed"][i]) else float(v["ground_speed"][i]),
                **sample_position(v, i),
            )
        except ValidationError as exc:
            first = exc.errors(include_url=False)[0]
            skipped[f"out of the sensor contract: {'.'.join(str(p) for p in first['loc'])}: {first['msg']}"] += 1


def sample_position(v: dict, i: int) -> dict:
    """The optional position fields of tick i (soilocp.schemas.position), where the aligned values hold them."""
    out: dict = {}
    if "position_x" in v and not np.isnan(v["position_x"][i]):
        from soilocp.schemas.position import MapPosition

        h = float(v["position_heading"][i])
        out["position"] = MapPosition(frame=str(v["position_frame"][i]), x=float(v["position_x"][i]),
                                      y=float(v["position_y"][i]), heading=None if math.isnan(h) else h)
    if "latitude" in v and not np.isnan(v["latitude"][i]):
        from soilocp.schemas.position import GeoPosition

        out["geo"] = GeoPosition(latitude=float(v["latitude"][i]), longitude=float(v["longitude"][i]))
    return out


def in_time_order(stamps) -> np.ndarray:
    """Mask of the messages to keep so that the stamps never go backwards: the longest
    non-decreasing subsequence (O(n log n)).  A stretch stamped in the past loses its own messages,
    and a single stamp far in the future loses only itself, not everything after it."""
    import bisect

    a = np.asarray(stamps)
    n = a.size
    keep = np.zeros(n, dtype=bool)
    if n == 0 or bool(np.all(np.diff(a) >= 0)):
        keep[:] = True
        return keep
    tails: list = []
    tail_idx: list[int] = []
    prev = [-1] * n
    for i, x in enumerate(a.tolist()):
        j = bisect.bisect_right(tails, x)
        if j:
            prev[i] = tail_idx[j - 1]
        if j == len(tails):
            tails.append(x)
            tail_idx.append(i)
        else:
            tails[j] = x
            tail_idx[j] = i
    k = tail_idx[-1]
    while k >= 0:
        keep[k] = True
        k = prev[k]
    return keep


def order_reason(stamps, keep: np.ndarray, i: int) -> tuple[str, str]:
    """Why message i was not kept by :func:`in_time_order`: (reason, detail)."""
    kept_before = np.flatnonzero(keep[:i])
    if kept_before.size and stamps[i] < stamps[kept_before[-1]]:
        return "goes backwards (earlier than the previous message)", f"by {(stamps[kept_before[-1]] - stamps[i]) / NS:.3f} s"
    kept_after = np.flatnonzero(keep[i + 1:])
    nxt = stamps[i + 1 + kept_after[0]] if kept_after.size else stamps[i]
    return "jumps ahead (later than the messages after it)", f"by {(stamps[i] - nxt) / NS:.3f} s"


def complementary_tilt(t_ns: np.ndarray, gyro: np.ndarray, acc: np.ndarray, tau: float = 1.0,
                       prev: Optional[tuple[int, float, float]] = None) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (REP-103: pitch > 0 nose down) for an IMU without orientation output.

    Complementary filter: the gyro (body rates ~ Euler rates at small tilt) carries the fast part,
    the accelerometer's gravity direction (eq. 20 inverted at rest: pitch = atan2(-f_x, sqrt(f_y^2 +
    f_z^2)), roll = atan2(f_y, f_z)) the slow part, crossover time constant ``tau`` seconds.
    Accelerations of the body leak into the slow part; that is the known limit of this estimate.
    ``prev`` = (stamp ns, roll, pitch) of the sample before ``t_ns[0]``: the live reader filters
    message by message and gets what one call over the whole log gives.
    """
    n = len(t_ns)
    roll = np.empty(n)
    pitch = np.empty(n)
    acc_roll = np.arctan2(acc[:, 1], acc[:, 2])
    acc_pitch = np.arctan2(-acc[:, 0], np.hypot(acc[:, 1], acc[:, 2]))
    if prev is None:
        r, p = float(acc_roll[0]) if n else 0.0, float(acc_pitch[0]) if n else 0.0
        t_prev = int(t_ns[0]) if n else 0
    else:
        t_prev, r, p = prev
    for i in range(n):
        if i or prev is not None:
            dt = max((int(t_ns[i]) - int(t_prev)) / NS, 0.0)
            a = tau / (tau + dt)
            r = a * (r + gyro[i, 0] * dt) + (1 - a) * acc_roll[i]
            p = a * (p + gyro[i, 1] * dt) + (1 - a) * acc_pitch[i]
        t_prev = int(t_ns[i])
        roll[i], pitch[i] = r, p
    return roll, pitch


def write_samples(samples, out: str | Path) -> int:
    n = 0
    with open(out, "w", encoding="utf-8") as f:
        for s in samples:
            f.write(s.model_dump_json() + "\n")
            n += 1
    return n


def align_and_write(streams: list[Stream], tmap, prov: Provenance, out: str | Path, dropped: dict,
                    error: type[Exception]) -> Provenance:
    """Align ``streams`` on the map's clock (``tmap.rate_hz``), write the samples to ``out`` and
    the provenance beside it, with the counts of skipped ticks and dropped messages.  An alignment
    that cannot be done raises ``error`` (the importer's own error type)."""
    try:
        al = align(streams, tmap.rate_hz)
    except ValueError as exc:
        raise error(str(exc)) from None
    skipped = Counter(al.skipped)
    prov.samples = write_samples(samples_from_aligned(al, tmap.vehicle_id, skipped), out)
    prov.ticks = al.ticks
    prov.skipped = dict(skipped)
    prov.dropped_messages = dict(dropped)
    prov.write(out)
    return prov


WITHHELD_FIELDS = ("soil_strength", "soil_strength_std", "soil_strength_low", "soil_strength_high", "soil_class",
                   "soil_class_confidence", "mu_T", "S_T", "S_E", "te_at_S_E")


def withhold(rec: dict, reason: str) -> dict:
    """An OCP record with K, class and OCPs withheld (status no_estimate) because the log cannot
    identify them; slip and traction stay (they are what the log says, not an estimate of K)."""
    out = dict(rec)
    for k in WITHHELD_FIELDS:
        if k in out:
            out[k] = None
    out["status"] = "no_estimate"
    out["reason"] = reason
    out["reason_code"] = "not_identifiable"
    out["confirmed"] = False
    return out
