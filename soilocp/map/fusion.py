"""How the map turns soil estimates into cells.

An estimate (``SoilEstimate`` with a ``where``) updates the cells its informing wheels' contact
patches fall in, if its status makes it usable: ``ok``, or ``uncertain`` (with its wide band).
``holding``, ``no_estimate``, ``not_observable``, ``model_mismatch`` and ``stale`` never do.

Per cell the store keeps, for each vehicle, only that vehicle's **latest** estimate there (ln K,
its variance, seq, stamp, when the map received it) and how many of its estimates hit the cell.
A vehicle's estimates at 100 Hz are running posteriors of one Bayes filter, not independent
measurements: adding them up would shrink the band by sqrt(N) with nothing learnt, so the newest
replaces the older (it has seen the most of the cell).  The vehicles are independent, so the cell
fuses them by inverse variance in ln K, each variance first grown by its age (soil changes with
rain; a random walk of ln K at ``ageing_rate`` per hour)::

    w_v = 1 / (sigma_v^2 + q (t - t_v)),   ln K = sum_v w_v ln K_v / sum_v w_v,   sigma^2 = 1 / sum_v w_v

This is a function of the set of latest estimates, so it does not depend on the order in which
vehicles' estimates arrive, and applying the same estimate twice changes nothing (a row is
replaced only by a newer estimate of the same vehicle: a higher (stamp, seq), or any estimate
received ``restart_gap_s`` after the row's, which is a restarted vehicle whose clock began again).
Two map services that receive the same estimates therefore hold the same cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Optional, Sequence

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from soilocp.schemas.map import MapCell
from soilocp.schemas.pipeline import SoilEstimate

from soilocp.map.cells import CellIndex, CellRef

USABLE_STATUS = ("ok", "uncertain")
#: Plausible soil strength for a map cell (the paper's soils are 50-300; the estimator's grid 5-5000).
MIN_K, MAX_K = 1.0, 1.0e4
MAX_LOG_K_STD = 5.0
BAND_Z = 1.959963984540054  # two-sided 95 %


class FusionConfig(BaseModel):
    """How estimates age and when a vehicle's older-looking estimate is a restart, not a duplicate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ageing_rate: float = Field(0.02, ge=0, le=100,
                               description="Growth of an estimate's ln K variance with age, per hour (0: no ageing)")
    restart_gap_s: float = Field(60.0, gt=0, description="An estimate with a lower (stamp, seq) received this long "
                                 "after the cell's row of that vehicle replaces it (the vehicle restarted)")


class MapInputError(ValueError):
    """An estimate the map refuses: machine-readable ``code``, the ``field`` and a reason."""

    def __init__(self, code: str, message: str, field: Optional[str] = None, seq: Optional[int] = None):
        super().__init__(f"{code}: {message}")
        self.code, self.message, self.field, self.seq = code, message, field, seq


@dataclass(frozen=True)
class Observation:
    """One vehicle's estimate in one cell."""

    cell: CellRef
    vehicle: str
    ln_k: float
    var: float
    seq: int
    stamp: float
    seen_at: float


_RANGE = {"less_than_equal", "greater_than_equal", "less_than", "greater_than", "too_short", "too_long"}


def parse_estimate(payload: bytes | str, key_vehicle: Optional[str] = None) -> SoilEstimate:
    """A soil estimate from a payload, or MapInputError naming the field, the value and why.  With
    ``key_vehicle`` the estimate must be that vehicle's (a vehicle writes only its own)."""
    try:
        est = SoilEstimate.model_validate_json(payload)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in err.get("loc", ())) or "<estimate>"
        typ = err.get("type", "")
        code = ("malformed_json" if typ in ("json_invalid", "json_type") else "non_finite" if typ == "finite_number"
                else "out_of_range" if typ in _RANGE else "schema")
        got = repr(err.get("input"))
        raise MapInputError(code, f"{loc}: {err.get('msg')} (got {got[:60]})", loc) from None
    except (UnicodeDecodeError, RecursionError) as exc:
        raise MapInputError("malformed_json", f"payload: {exc}"[:200]) from None
    if key_vehicle is not None and est.vehicle_id != key_vehicle:
        raise MapInputError("vehicle_mismatch", f"vehicle_id {est.vehicle_id!r} arrived on vehicle {key_vehicle!r}'s "
                            "key: a vehicle may write only its own estimates", "vehicle_id", est.seq)
    return est


def check_estimate(est: SoilEstimate) -> Optional[str]:
    """None if ``est`` should update cells; else why not (a skip, not an error).  MapInputError
    for a usable estimate whose values are out of range or inconsistent."""
    if est.status not in USABLE_STATUS:
        return f"status_{est.status}"
    if est.where is None:
        return "no_place"
    k, s = est.soil_strength, est.log_k_std
    if k is None or s is None:
        raise MapInputError("inconsistent", f"status {est.status} without K or its band "
                            f"(soil_strength={k!r}, log_k_std={s!r})", "soil_strength", est.seq)
    if not MIN_K <= k <= MAX_K:
        raise MapInputError("out_of_range", f"soil_strength: {k!r} outside [{MIN_K:g}, {MAX_K:g}]", "soil_strength",
                            est.seq)
    if not s > 0.0:
        raise MapInputError("out_of_range", f"log_k_std: {s!r} must be > 0", "log_k_std", est.seq)
    if s > MAX_LOG_K_STD:
        # a finite band this wide is the estimator being honest (e.g. small slips under a wheel-radius
        # uncertainty), not bad input: it carries no weight worth storing, so it is skipped, not refused
        return "band_too_wide"
    w = est.where  # coordinates and wheel numbers are range-checked by the schema (soilocp.schemas.position)
    if len(set(w.wheels)) != len(w.wheels):
        raise MapInputError("inconsistent", f"where.wheels: {list(w.wheels)} must be distinct wheel numbers 1..4",
                            "where.wheels", est.seq)
    if w.xy is None and w.latlon is None:
        raise MapInputError("inconsistent", "where: neither xy nor latlon", "where", est.seq)
    for name, pts in (("xy", w.xy), ("latlon", w.latlon)):
        if pts is not None and len(pts) != len(w.wheels):
            raise MapInputError("inconsistent", f"where.{name}: {len(pts)} points for {len(w.wheels)} wheels",
                                f"where.{name}", est.seq)
    if w.xy is not None and w.frame is None:
        raise MapInputError("inconsistent", "where.xy without where.frame", "where.frame", est.seq)
    return None


def observations(est: SoilEstimate, index: CellIndex, seen_at: float) -> list[Observation]:
    """The observations of a checked, usable estimate: one per distinct cell its patches touch."""
    w = est.where
    ln_k, var = math.log(est.soil_strength), est.log_k_std ** 2
    cells: dict[str, CellRef] = {}
    if w.xy is not None:
        for x, y in w.xy:
            c = index.local(w.frame, x, y)
            cells[c.cell] = c
    if w.latlon is not None:
        for la, lo in w.latlon:
            c = index.geo(la, lo)
            cells[c.cell] = c
    return [Observation(c, est.vehicle_id, ln_k, var, est.seq, est.stamp, seen_at) for c in cells.values()]


def reduce_batch(obs: Iterable[Observation]) -> list[tuple[Observation, int]]:
    """Per (cell, vehicle): the newest observation of a batch and how many there were (the store
    then writes one row per pair)."""
    out: dict[tuple[str, str], list] = {}
    for o in obs:
        k = (o.cell.cell, o.vehicle)
        cur = out.get(k)
        if cur is None:
            out[k] = [o, 1]
        else:
            cur[1] += 1
            if (o.stamp, o.seq) > (cur[0].stamp, cur[0].seq):
                cur[0] = o
    return [(o, n) for o, n in out.values()]


def fuse(ln_k: Sequence[float], var: Sequence[float], seen_at: Sequence[float], now: float, ageing_rate: float,
         ) -> tuple[float, float]:
    """Inverse-variance fusion in ln K of one cell's per-vehicle rows, each variance aged by
    ``ageing_rate`` per hour (module docstring): (ln K, its variance).  Plain floats: a cell holds
    a handful of vehicles, and a query fuses thousands of cells."""
    q = ageing_rate / 3600.0
    sw = swx = 0.0
    for lk, v, t in zip(ln_k, var, seen_at):
        w = 1.0 / (v + q * (now - t if now > t else 0.0))
        sw += w
        swx += w * lk
    return swx / sw, 1.0 / sw


def fuse_cells(rows: Sequence[tuple], ageing_rate: float) -> list[tuple]:
    """Each cell's fused state at its own last-seen time from store rows ``(cell, frame, cx, cy,
    vehicle, ln_k, var, n, seen_at)`` in any order: ``(cell, ln K, its variance, count, last seen,
    vehicles)``, :func:`fuse` over the cell's vehicles in name order.  A function of the cell's rows
    alone (not of when or in which batches they arrived), so two services agree.

    The store keeps this per cell, written in the transaction that changed the cell; a reply ages it
    to its own time as one estimate, sigma^2 + q (now - last seen) (:func:`aged_columns`).  For one
    vehicle that is :func:`fuse` at ``now`` exactly; for several it is wider (adding q dt to the fused
    variance exceeds fusing the aged variances): the reported band errs on the safe side."""
    groups: dict[str, list] = {}
    for r in rows:
        groups.setdefault(r[0], []).append(r)
    out = []
    for cell in sorted(groups):
        grp = sorted(groups[cell], key=lambda r: r[4])
        last = max(r[8] for r in grp)
        ln_k, var = fuse([r[5] for r in grp], [r[6] for r in grp], [r[8] for r in grp], last, ageing_rate)
        out.append((cell, ln_k, var, sum(r[7] for r in grp), last, [r[4] for r in grp]))
    return out


def aged_columns(rows: Sequence[tuple], frame: str, now: float, ageing_rate: float) -> dict:
    """Reply columns (soilocp.schemas.map.MapCellColumns) from stored cells ``(cell, cx, cy, ln_k, var, t,
    n, last_seen, vehicles)``: each cell's fused variance aged to ``now`` (:func:`fuse_cells`),
    vectorised (a box may hold ten thousand cells)."""
    import numpy as np

    if not rows:
        return {"frame": frame, "cell": [], "cx": [], "cy": [], "K": [], "log_k_std": [], "K_lo": [], "K_hi": [],
                "count": [], "last_seen": [], "vehicles": []}
    cell, cx, cy, ln_k, var, t, n, last, veh = zip(*rows)
    lk = np.asarray(ln_k, dtype=float)
    s = np.sqrt(np.asarray(var, dtype=float) + (ageing_rate / 3600.0) * np.maximum(now - np.asarray(t, dtype=float), 0.0))
    return {"frame": frame, "cell": list(cell), "cx": list(cx), "cy": list(cy), "K": np.exp(lk).tolist(),
            "log_k_std": s.tolist(), "K_lo": np.exp(lk - BAND_Z * s).tolist(), "K_hi": np.exp(lk + BAND_Z * s).tolist(),
            "count": list(n), "last_seen": list(last), "vehicles": [v.split(",") for v in veh]}


def cells_of_columns(cols: dict) -> list[MapCell]:
    """:class:`MapCell` models of reply columns (one validation of the whole list)."""
    f = cols["frame"]
    return _CELLS.validate_python([
        {"cell": c, "frame": f, "center": (x, y), "K": k, "log_k_std": s, "K_lo": lo, "K_hi": hi, "count": n,
         "last_seen": t, "vehicles": v}
        for c, x, y, k, s, lo, hi, n, t, v in zip(cols["cell"], cols["cx"], cols["cy"], cols["K"], cols["log_k_std"],
                                                  cols["K_lo"], cols["K_hi"], cols["count"], cols["last_seen"],
                                                  cols["vehicles"])])


_CELLS = TypeAdapter(list[MapCell])
