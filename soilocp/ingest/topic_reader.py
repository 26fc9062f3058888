"""One topic's messages as rows, each bad message dropped with a counted, specific reason (or, strict,
an error that names the topic, the field and the reason): what the bag import
(:mod:`soilocp.ingest.rosbag_import`), its position streams (:mod:`soilocp.ingest.positions`) and the live
ROS 2 reader (:mod:`soilocp.ingest.live`) fill, one reader per mapped topic."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from soilocp.ingest.align import NS, in_time_order, order_reason


class BagImportError(ValueError):
    """A bag that cannot be imported with this map: names the topic, the field and the reason."""


@dataclass
class BagIssues:
    """Dropped messages by (topic, field, reason), with the first stamp seen."""

    counts: Counter = field(default_factory=Counter)
    first: dict = field(default_factory=dict)

    def add(self, topic: str, fieldname: str, reason: str, stamp_ns: int, detail: str = "") -> None:
        key = (topic, fieldname, reason)
        self.counts[key] += 1
        self.first.setdefault(key, (stamp_ns, detail))

    def lines(self) -> list[str]:
        out = []
        for (t, f, r), n in sorted(self.counts.items()):
            st, detail = self.first[(t, f, r)]
            out.append(f"{t}: {f}: {r} ({n} message{'s' if n != 1 else ''} dropped, first at stamp {st / NS:.3f}"
                       + (f", {detail}" if detail else "") + ")")
        return out


class TopicReader:
    """Collects one topic's values, dropping bad messages with a reason (the bag import and the
    live ROS 2 reader, :mod:`soilocp.ingest.live`, both fill one per mapped topic)."""

    def __init__(self, key: str, topic: str, issues: BagIssues, strict: bool):
        self.key, self.topic, self.issues, self.strict = key, topic, issues, strict
        self.stamps: list[int] = []
        self.rows: list[tuple] = []

    def drop(self, fieldname: str, reason: str, stamp: int, detail: str = "") -> None:
        if self.strict:
            raise BagImportError(f"{self.topic}: {fieldname}: {reason} (at stamp {stamp / NS:.3f}"
                                 + (f", {detail}" if detail else "") + "; --strict)")
        self.issues.add(self.topic, fieldname, reason, stamp, detail)

    def accept_stamp(self, stamp: int) -> bool:
        if stamp <= 0:
            self.drop("header.stamp", "zero or negative: the driver does not stamp its messages "
                      "(map key clock: receive uses the bag's receive time instead)", stamp)
            return False
        return True

    def in_order(self) -> tuple[np.ndarray, list]:
        """Stamps and rows with the out-of-order messages dropped (each with its reason)."""
        st = np.asarray(self.stamps, dtype=np.int64)
        keep = in_time_order(st)
        for i in np.flatnonzero(~keep):
            reason, detail = order_reason(st, keep, int(i))
            self.drop("header.stamp", reason, int(st[i]), detail)
        return st[keep], [row for row, k in zip(self.rows, keep) if k]

    def check_finite(self, stamp: int, named: dict[str, float]) -> bool:
        for name, v in named.items():
            if not math.isfinite(v):
                self.drop(name, f"{'NaN' if v != v else 'infinite'} value", stamp)
                return False
        return True

    def keep(self, stamp: int, row: tuple) -> None:
        self.stamps.append(stamp)
        self.rows.append(row)
