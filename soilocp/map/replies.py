"""Box replies from memory: each frame's stored cells, kept in centre order with their fixed JSON
already written, brought up to date from the store's change counter before each reply.

Why: a 1 km² box of a fleet map holds ten thousand cells.  Reading them through a database driver
costs a Python object per row and field (~21 ms of CPU for 9441 cells), and neither SQLite nor
PostgreSQL writes floats as text fast enough to build the reply in SQL (SQLite: ~0.5 µs per double,
no faster than the driver).  Here a reply costs a binary search on x, a mask on y, the ageing of
the selected cells (:func:`soilocp.map.fusion.aged_columns`' formula, vectorised), and joins of
pre-written fragments; a cell's fragments are rewritten only when a commit changed it
(:meth:`soilocp.map.store.MapStore.changed_cells`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from pydantic_core import to_json

from soilocp.map.fusion import BAND_Z

if TYPE_CHECKING:
    from soilocp.map.store import MapStore

_FIXED = ("cell", "cx", "cy", "K", "count", "last_seen", "vehicles")


class _Frame:
    """One frame's cells in (cx, cy) order: numeric columns and each cell's fixed JSON fragments."""

    def __init__(self):
        self.rows: dict[str, tuple] = {}  # cell -> (cx, cy, ln_k, var, t, n, last_seen, vehicles)
        self.stale = True

    def build(self) -> None:
        cells = sorted(self.rows, key=lambda c: (self.rows[c][0], self.rows[c][1]))
        rs = [self.rows[c] for c in cells]
        cx, cy, lk, var, t, n, last, veh = zip(*rs) if rs else ((),) * 8
        self.cx, self.cy = np.asarray(cx, dtype=float), np.asarray(cy, dtype=float)
        self.ln_k, self.var, self.t = np.asarray(lk, dtype=float), np.asarray(var, dtype=float), np.asarray(t, dtype=float)
        k = np.exp(self.ln_k)
        # to_json of one list, split: each value as the reply's serializer writes it
        frag = {"cell": cells, "cx": cx, "cy": cy, "K": k.tolist(), "count": n, "last_seen": last,
                "vehicles": [v.split(",") for v in veh]}
        self.frag = {name: np.asarray(_fragments(frag[name]) if rs else [], dtype=object) for name in _FIXED}
        self.stale = False


def _fragments(values: Sequence) -> list[str]:
    """Each value's JSON text; numbers with one serialiser call for the whole list (no commas in them)."""
    if isinstance(values[0], (int, float)):
        return to_json(list(values)).decode()[1:-1].split(",")
    return [json.dumps(v, separators=(",", ":")) for v in values]


class ReplyCache:
    """Box replies of one store, for one reading thread (the map service's query worker)."""

    def __init__(self, store: "MapStore"):
        self.store = store
        self.version = -1
        self.frames: dict[str, _Frame] = {}

    def refresh(self) -> None:
        """Take in the cells changed since the last refresh (all of them the first time)."""
        version, rows = self.store.changed_cells(self.version)
        for frame, cell, *rest in rows:
            f = self.frames.get(frame)
            if f is None:
                f = self.frames[frame] = _Frame()
            row = tuple(rest)
            if f.rows.get(cell) != row:  # the last commit's cells come again (changed_cells: >=)
                f.rows[cell] = row
                f.stale = True
        self.version = version

    def prepare(self) -> None:
        """Read and lay out every frame now (the map service does so before its first query)."""
        self.refresh()
        for f in self.frames.values():
            if f.stale:
                f.build()

    def columns_json(self, frame: str, bbox: Sequence[float], now: float, limit: int) -> tuple[str, int, bool]:
        """The reply's ``columns`` (schemas.map.MapCellColumns) as JSON for the cells of ``frame``
        whose centre lies in ``bbox``, ordered by centre and aged to ``now``; their number; and
        whether ``limit`` cut them."""
        self.refresh()
        f = self.frames.get(frame)
        if f is None:
            f = _Frame()
        if f.stale:
            f.build()
        xmin, ymin, xmax, ymax = bbox
        lo, hi = np.searchsorted(f.cx, xmin, "left"), np.searchsorted(f.cx, xmax, "right")
        idx = lo + np.flatnonzero((f.cy[lo:hi] >= ymin) & (f.cy[lo:hi] <= ymax))
        cut = idx.size > limit
        idx = idx[:limit]
        # fusion.aged_columns: the fused variance aged to now, sigma^2 + q (now - t)
        lk = f.ln_k[idx]
        s = np.sqrt(f.var[idx] + (self.store.fusion.ageing_rate / 3600.0) * np.maximum(now - f.t[idx], 0.0))
        parts = [f'"frame":{json.dumps(frame)}']
        for name in _FIXED:
            parts.append(f'"{name}":[{",".join(f.frag[name][idx].tolist())}]')
        for name, col in (("log_k_std", s), ("K_lo", np.exp(lk - BAND_Z * s)), ("K_hi", np.exp(lk + BAND_Z * s))):
            parts.append(f'"{name}":{to_json(col.tolist()).decode()}')
        return "{" + ",".join(parts) + "}", int(idx.size), bool(cut)
