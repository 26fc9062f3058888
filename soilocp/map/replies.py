"""Box replies from memory: each frame's stored cells, kept in centre order with their JSON
already written, brought up to date from the store's change counter before each reply.

Why: a 1 km² box of a fleet map holds ten thousand cells.  Reading them through a database driver
costs a Python object per row and field (~21 ms of CPU for 9441 cells), and neither SQLite nor
PostgreSQL writes floats as text fast enough to build the reply in SQL (SQLite: ~0.5 µs per double,
no faster than the driver).  Writing the reply from per-cell fragments still cost ~5 ms of CPU a
query (fancy indexing of the fragments, and the three aged columns written as text at every
query: ~0.5 µs a cell), which a loaded 2-core machine turned into a p99 over 20 ms.  So:

* **Columns of the grid.**  A frame's cells are in (cx, cy) order, so the cells of one cx (a
  column of square cells) whose centre lies in a box's y range are one contiguous run.  Each
  column's text is joined once per field; a reply is the whole columns' texts joined, and only a
  column the box cuts joins its run of per-cell fragments.  A frame of irregular centres (H3
  hexagons: one cell per cx) is cut per cell instead.
* **Ageing on a clock of ``age_step_s``.**  The aged columns (log_k_std, K_lo, K_hi: the fused
  variance aged to the reply's time, :func:`soilocp.map.fusion.aged_columns`' formula) are written
  once per step of the clock, for the step's start, and a reply says that it is aged to that time
  (``MapQueryReply.time``).  At the default ageing rate (0.02 per hour in ln K variance) one second
  adds 6e-6 to a variance: below the printed precision of any band.  :meth:`ReplyCache.warm` lays
  out the next step ahead of it while the query worker is idle.

A cell's fragments are rewritten only when a commit changed it
(:meth:`soilocp.map.store.MapStore.changed_cells`)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from typing import Optional

import numpy as np
from pydantic_core import to_json

from soilocp.map.fusion import BAND_Z

_FIXED = ("cell", "cx", "cy", "K", "count", "last_seen", "vehicles")
_AGED = ("log_k_std", "K_lo", "K_hi")


class _Text:
    """A field's values as one JSON text (ASCII bytes, comma-separated), with each cell's offset in
    it: the cells lo..hi-1 (a run of consecutive cells) are one slice, ``text[off[lo]:off[hi] - 1]``."""

    __slots__ = ("text", "off")

    def __init__(self, text: bytes, off: np.ndarray):
        self.text, self.off = text, off

    @classmethod
    def of_numbers(cls, values: list) -> "_Text":
        """Numbers: one serialiser call for the whole list, the offsets from its commas (numbers have none)."""
        if not values:
            return cls(b"", np.zeros(1, dtype=np.int64))
        text = to_json(values)[1:-1]
        commas = np.flatnonzero(np.frombuffer(text, dtype=np.uint8) == 44)
        return cls(text, np.concatenate([[0], commas + 1, [len(text) + 1]]))

    @classmethod
    def of_json(cls, values: Sequence) -> "_Text":
        """Strings or lists (commas inside): each value written alone (json.dumps: ASCII), offsets from their lengths."""
        frag = [json.dumps(v, separators=(",", ":")).encode() for v in values]
        return cls(b",".join(frag), np.concatenate([[0], np.cumsum(np.fromiter(map(len, frag), dtype=np.int64,
                                                                                 count=len(frag)) + 1)]))

    def runs(self, lo: np.ndarray, hi: np.ndarray, out: list[bytes]) -> None:
        """Append the JSON list of the runs lo..hi to ``out`` (slices and commas: the reply is joined once)."""
        t = self.text
        out.append(b"[")
        for a, b in zip(self.off[lo].tolist(), (self.off[hi] - 1).tolist()):
            out += (t[a:b], b",")
        if lo.size:
            out.pop()
        out.append(b"]")


class _Frame:
    """One frame's cells in (cx, cy) order: numeric columns and each field's text (:class:`_Text`)."""

    def __init__(self):
        self.rows: dict[str, tuple] = {}  # cell -> (cx, cy, ln_k, var, t, n, last_seen, vehicles)
        self.stale = True
        self.aged: dict[float, dict[str, _Text]] = {}  # time -> the aged fields' texts

    def build(self) -> None:
        cells = sorted(self.rows, key=lambda c: (self.rows[c][0], self.rows[c][1]))
        rs = [self.rows[c] for c in cells]
        cx, cy, lk, var, t, n, last, veh = zip(*rs) if rs else ((),) * 8
        self.cx, self.cy = np.asarray(cx, dtype=float), np.asarray(cy, dtype=float)
        self.ln_k, self.var, self.t = np.asarray(lk, dtype=float), np.asarray(var, dtype=float), np.asarray(t, dtype=float)
        self.fixed = {"cell": _Text.of_json(cells), "cx": _Text.of_numbers(list(cx)), "cy": _Text.of_numbers(list(cy)),
                      "K": _Text.of_numbers(np.exp(self.ln_k).tolist()), "count": _Text.of_numbers(list(n)),
                      "last_seen": _Text.of_numbers(list(last)), "vehicles": _Text.of_json([v.split(",") for v in veh])}
        self.stale = False
        self.aged = {}

    def age(self, at: float, q_per_s: float) -> None:
        """The aged fields' texts for ``at`` (fusion.aged_columns' formula: sigma^2 + q (at - t),
        never younger than the cell's own time); this and the latest other time are kept (the
        current step's and the next's, laid out ahead)."""
        s = np.sqrt(self.var + q_per_s * np.maximum(at - self.t, 0.0))
        cols = {"log_k_std": s, "K_lo": np.exp(self.ln_k - BAND_Z * s), "K_hi": np.exp(self.ln_k + BAND_Z * s)}
        texts = {name: _Text.of_numbers(cols[name].tolist()) for name in _AGED}
        latest = max(self.aged, default=None)
        self.aged = {at: texts} if latest is None else {latest: self.aged[latest], at: texts}

    def select(self, bbox: Sequence[float], limit: int) -> tuple[np.ndarray, np.ndarray, int, bool]:
        """The cells whose centre lies in ``bbox``, in order, as runs of consecutive cells (lo, hi:
        cells lo..hi-1; a column of square cells is one run, whole columns side by side one);
        their number; whether ``limit`` cut them."""
        xmin, ymin, xmax, ymax = bbox
        a, b = np.searchsorted(self.cx, xmin, "left"), np.searchsorted(self.cx, xmax, "right")
        idx = a + np.flatnonzero((self.cy[a:b] >= ymin) & (self.cy[a:b] <= ymax))
        cut = idx.size > limit
        idx = idx[:limit]
        if not idx.size:
            return idx, idx, 0, bool(cut)
        brk = np.flatnonzero(np.diff(idx) != 1) + 1
        return idx[np.concatenate([[0], brk])], idx[np.concatenate([brk - 1, [idx.size - 1]])] + 1, int(idx.size), bool(cut)

    def text(self, name: str, lo: np.ndarray, hi: np.ndarray, at: float, out: list[bytes]) -> None:
        """Append the JSON list of field ``name`` (aged to ``at``) over the runs lo..hi to ``out``."""
        (self.aged[at] if name in _AGED else self.fixed)[name].runs(lo, hi, out)


class ReplyCache:
    """Box replies of one store, for one caller at a time (the map service holds a lock).

    ``changed_cells(since)`` reads the store's commit number and the cells changed since a number
    (:meth:`soilocp.map.store.MapStore.changed_cells`); ``ageing_rate`` is the fused variance's growth in
    ln K per hour (:class:`soilocp.map.fusion.FusionConfig`)."""

    def __init__(self, changed_cells: Callable[[int], tuple[int, list[tuple]]], ageing_rate: float,
                 age_step_s: float = 1.0):
        if not (math.isfinite(age_step_s) and age_step_s > 0):
            raise ValueError(f"age_step_s = {age_step_s!r}: the ageing clock's step must be a positive number of seconds")
        self.changed_cells = changed_cells
        self.ageing_rate = ageing_rate
        self.age_step_s = age_step_s
        self.version = -1
        self.frames: dict[str, _Frame] = {}

    def refresh(self) -> None:
        """Take in the cells changed since the last refresh (all of them the first time)."""
        version, rows = self.changed_cells(self.version)
        for frame, cell, *rest in rows:
            f = self.frames.get(frame)
            if f is None:
                f = self.frames[frame] = _Frame()
            row = tuple(rest)
            if f.rows.get(cell) != row:  # the last commit's cells come again (changed_cells: >=)
                f.rows[cell] = row
                f.stale = True
        self.version = version

    def aged_to(self, now: float) -> float:
        """The time a reply at ``now`` is aged to: the start of the ageing clock's step."""
        return math.floor(now / self.age_step_s) * self.age_step_s

    def _ready(self, f: _Frame, at: float) -> None:
        if f.stale:
            f.build()
        if at not in f.aged:
            f.age(at, self.ageing_rate / 3600.0)

    def warm(self, now: Optional[float], ahead_s: float = 0.25) -> None:
        """Between queries: take in the last commits and lay out every frame for the clock's step
        at ``now`` (None: the wall clock's), or already for the next step when it begins within
        ``ahead_s``, so that a query finds its frame ready."""
        import time

        now = time.time() if now is None else now
        self.refresh()
        at = self.aged_to(now)
        if now + ahead_s >= at + self.age_step_s:
            at += self.age_step_s
        for f in self.frames.values():
            self._ready(f, at)

    def columns_json(self, frame: str, bbox: Sequence[float], now: float, limit: int, ready_only: bool = False
                     ) -> Optional[tuple[bytes, int, bool, float]]:
        """The reply's ``columns`` (soilocp.schemas.map.MapCellColumns) as JSON for the cells of ``frame``
        whose centre lies in ``bbox``, ordered by centre (x, then y); their number; whether
        ``limit`` cut them; and the time they are aged to (:meth:`aged_to` of ``now``).
        ``ready_only``: from what is laid out already, without reading the store (the caller knows
        nothing was committed since the last refresh), or None when the frame is not laid out for
        that time."""
        at = self.aged_to(now)
        if ready_only:
            f = self.frames.get(frame)
            if f is None or f.stale or at not in f.aged:
                return None
        else:
            self.refresh()
            f = self.frames.get(frame) or _Frame()
            self._ready(f, at)
        lo, hi, n, cut = f.select(bbox, limit)
        out = [b'{"frame":' + json.dumps(frame).encode()]
        for name in _FIXED + _AGED:
            out.append(b',"' + name.encode() + b'":')
            f.text(name, lo, hi, at, out)
        out.append(b"}")
        return b"".join(out), n, cut, at
