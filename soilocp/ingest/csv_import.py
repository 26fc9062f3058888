"""Multi-rate CSV logs -> sensor log, with a column map (the ``csv`` section of the map file).

One CSV file per role, given as ``--csv imu=IMU.csv --csv wheels=WHEELS.csv [--csv ground_speed=V.csv]``,
each with its own time column (seconds) and rate; the rows are put on one clock by
:func:`soilocp.ingest.align.align` (last value held up to the role's ``max_age``).

* ``imu``: specific force (m/s^2, z ~ +g at rest) and gyro (rad/s); roll and pitch come from the
  complementary filter (CSV IMUs rarely log an orientation).
* ``wheels``: speed and motor current per wheel; a column named for two wheels is one motor per
  side (skid steer): both wheels read its speed, each gets half its torque.  Current x
  ``current_to_torque`` = wheel torque, N m.  Unsigned currents take the sign of the wheel speed.
* ``ground_speed``: optional.  Without it the log's ground_speed is null, and the chain reports K
  as not identifiable (slip, eq. 1, compares the wheel speed with an INDEPENDENT ground speed;
  wheel odometry would make slip ~ 0 by construction); the provenance file says so too.

Rows with NaN or a stamp going backwards are dropped with a counted reason naming the file,
column and reason; the rows around them are kept.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from pathlib import Path

import numpy as np

from soilocp.ingest.align import (NS, Provenance, Stream, align_and_write, complementary_tilt, in_time_order,
                                  order_reason)
from soilocp.ingest.mapfile import TopicMap


class CsvImportError(ValueError):
    """A CSV log that cannot be imported with this map: names the file, the column and the reason."""


def _read_columns(path: Path, time_col: str, cols: list[str], dropped: Counter) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns, values (n, len(cols))) of the rows that are finite and in time order."""
    try:
        fh = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise CsvImportError(f"{path}: cannot open: {exc.strerror}") from None
    with fh:
        rd = csv.reader(fh)
        header = next(rd, None)
        if not header:
            raise CsvImportError(f"{path}: empty file (expected a header row)")
        header = [h.strip() for h in header]
        idx = {}
        for c in [time_col, *cols]:
            if c not in header:
                raise CsvImportError(f"{path}: column {c!r} (from the map) not in the header {header}")
            idx[c] = header.index(c)
        stamps, rows = [], []
        for lineno, row in enumerate(rd, start=2):
            if not row:
                continue
            try:
                t = float(row[idx[time_col]])
                vals = [float(row[idx[c]]) for c in cols]
            except (ValueError, IndexError):
                dropped[f"{path.name}: line {lineno}: not a number in a mapped column"] += 1
                continue
            bad = next((c for c, v in zip([time_col, *cols], [t, *vals]) if not math.isfinite(v)), None)
            if bad is not None:
                dropped[f"{path.name}: {bad}: NaN or infinite value"] += 1
                continue
            stamps.append(int(round(t * NS)))
            rows.append(vals)
    st = np.asarray(stamps, dtype=np.int64)
    keep = in_time_order(st)
    for i in np.flatnonzero(~keep):
        reason = order_reason(st, keep, int(i))[0].split(" (")[0]
        dropped[f"{path.name}: {time_col}: {reason}"] += 1
    if not keep.any():
        raise CsvImportError(f"{path}: no usable row")
    return st[keep], np.asarray(rows, dtype=float)[keep]


def import_csv(files: dict[str, str | Path], tmap: TopicMap, out: str | Path) -> tuple[Provenance, list[str]]:
    """Import CSV logs (``files``: role -> path) to the sensor log ``out`` (+ provenance file)."""
    cm = tmap.csv
    if cm is None:
        raise CsvImportError("the map has no 'csv' section (column names per role)")
    need = {"imu", "wheels"} | ({"ground_speed"} if cm.ground_speed is not None else set())
    unknown = set(files) - need
    if unknown:
        raise CsvImportError(f"--csv {sorted(unknown)[0]}=...: unknown role (the map has roles {sorted(need)})")
    missing = need - set(files)
    if missing:
        raise CsvImportError(f"--csv {sorted(missing)[0]}=FILE missing: the map's csv section needs it")
    dropped: Counter = Counter()
    prov = Provenance(source="csv " + ", ".join(f"{k}={Path(v).name}" for k, v in sorted(files.items())),
                      attitude="gyro+accelerometer (complementary filter)")

    st, a = _read_columns(Path(files["imu"]), cm.imu.time, [*cm.imu.specific_force, *cm.imu.gyro], dropped)
    roll, pitch = complementary_tilt(st, a[:, 3:6], a[:, 0:3])
    streams = [Stream(f"imu ({Path(files['imu']).name})", st,
                      {"specific_force": a[:, 0:3], "yaw_rate": a[:, 5], "roll": roll, "pitch": pitch}, cm.imu.max_age)]

    w = cm.wheels
    uniq = list(dict.fromkeys([*w.speed, *w.current]))
    st, a = _read_columns(Path(files["wheels"]), w.time, uniq, dropped)
    col = {c: a[:, i] for i, c in enumerate(uniq)}
    speed = np.stack([col[c] for c in w.speed], axis=1)
    if w.speed_unit == "m/s":
        speed = speed / tmap.wheel_radius
    share = Counter(w.current)
    cur = np.stack([col[c] / share[c] for c in w.current], axis=1)
    if w.unsigned_current:
        cur = np.abs(cur) * np.sign(speed)
    torque = cur * (w.current_to_torque if w.current_to_torque is not None else 1.0)
    if w.current_to_torque is None:
        prov.wheel_torque = "current_unknown_scale"
        prov.identifiable = False
        prov.reasons.append("wheel torque is a motor current with an unknown scale (no current_to_torque in the map)")
    if len(set(w.speed)) < 4:
        prov.drive = "per_side"
    vals = {"wheel_speed": speed, "wheel_torque": torque}
    if cm.ground_speed is None:
        # no independent ground speed: null in the log, and the chain says K is not identifiable
        vals["ground_speed"] = np.full(len(speed), np.nan)
        prov.ground_speed = "absent"
        prov.identifiable = False
        prov.reasons.insert(0, "no independent ground speed in the source (slip, eq. 1, needs it)")
    streams.append(Stream(f"wheels ({Path(files['wheels']).name})", st, vals, w.max_age))
    if cm.ground_speed is not None:
        g = cm.ground_speed
        st, a = _read_columns(Path(files["ground_speed"]), g.time, [g.column], dropped)
        streams.append(Stream(f"ground_speed ({Path(files['ground_speed']).name})", st, {"ground_speed": a[:, 0]}, g.max_age))

    align_and_write(streams, tmap, prov, out, dropped, CsvImportError)
    return prov, [f"{k} ({n} row{'s' if n != 1 else ''} dropped)" for k, n in sorted(dropped.items())]
