"""One batch of received soil estimates -> the store: parse and check each (refusals with a reason,
counted), the cells of the usable ones, one committed transaction.  The map service calls it on
its worker; the bench and the tests call it directly (no Zenoh here)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Optional, Sequence

from soilocp.schemas import keys

from soilocp.map.cells import CellIndex
from soilocp.map.fusion import MapInputError, Observation, check_estimate, observations, parse_estimate, reduce_batch
from soilocp.map.store import MapStore


@dataclass
class Refusal:
    """An estimate the map refused."""

    key: str
    vehicle_id: Optional[str]
    seq: Optional[int]
    code: str
    field: Optional[str]
    message: str
    received_at: float


@dataclass
class BatchResult:
    applied: dict[str, tuple[int, int]] = field(default_factory=dict)  # vehicle -> (last seq, estimates in batch)
    cells: list[str] = field(default_factory=list)  # cells touched
    refused: list[Refusal] = field(default_factory=list)
    skipped: Counter = field(default_factory=Counter)


def vehicle_of_soil_key(key: str) -> str:
    """The vehicle id of ``soilocp/<vid>/soil``; MapInputError(bad_key) for anything else."""
    try:
        vid, rest = keys.split_key(key)
    except ValueError as exc:
        raise MapInputError("bad_key", str(exc)) from None
    if rest != "soil":
        raise MapInputError("bad_key", f"key {key!r} is not a soil estimate key (soilocp/<vid>/soil)")
    return vid


class MapUpdater:
    """Turns received estimates into committed cell rows."""

    def __init__(self, store: MapStore, index: Optional[CellIndex] = None):
        self.store = store
        self.index = index or CellIndex(store.cell_config)
        self._vids: dict[str, str] = {}  # key -> vehicle id, checked once

    def apply(self, items: Sequence[tuple[str, bytes, float]]) -> BatchResult:
        """``items``: (key, payload, received_at).  Commits before it returns (then the batch may be
        acknowledged); a database error propagates and nothing of the batch counts as applied."""
        res = BatchResult()
        obs: list[Observation] = []
        per_vehicle: dict[str, list[int]] = {}
        for key, payload, seen_at in items:
            vid = None
            try:
                vid = self._vids.get(key)
                if vid is None:
                    vid = vehicle_of_soil_key(key)
                    if len(self._vids) < 100_000:
                        self._vids[key] = vid
                est = parse_estimate(payload, vid)
                why = check_estimate(est)
            except MapInputError as exc:
                res.refused.append(Refusal(key, vid, exc.seq, exc.code, exc.field, exc.message, seen_at))
                continue
            if why is not None:
                res.skipped[why] += 1
                continue
            obs += observations(est, self.index, seen_at)
            pv = per_vehicle.setdefault(vid, [est.seq, 0])
            pv[0] = est.seq
            pv[1] += 1
        if obs:
            batch = reduce_batch(obs)
            ledger = {v: (s, n) for v, (s, n) in per_vehicle.items()}
            self.store.apply(batch, ledger)
            res.cells = sorted({o.cell.cell for o, _n in batch})
            totals = self.store.ledger()  # committed totals, across restarts of the service
            res.applied = {v: totals[v] for v in ledger}
        return res
