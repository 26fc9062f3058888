"""A simulated fleet maps a mixed field, and the map is judged against the field's truth
(docs/map.md, tests/test_map_fleet.py).

The field (:func:`mixed_field`): four 20 m x 20 m regions of known K in the local frame
``field`` (sand, grass, gravel, firm) on a background of EST.  Each vehicle drives straight
across it from its start pose (:func:`soilocp.sim.field.straight_drive`), its samples carry the
true positions, and its soil estimates (the library's VehiclePipeline, as ``soilocp estimate``)
carry the contact patches; the map fuses them (:class:`soilocp.map.updater.MapUpdater`).
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Optional, Sequence

from schemas import keys
from schemas.map import MapCell

from soilocp.sim.field import Field, Region, StartPose, straight_drive


def mixed_field() -> Field:
    return Field((Region("sand", 0, 20, 0, 20), Region("grass", 20, 40, 0, 20),
                  Region("gravel", 0, 20, 20, 40), Region("firm", 20, 40, 20, 40)), background="EST", frame="field")


#: Three vehicles: two drive east along the rows y = 7.5 and y = 27.5, one north along x = 27.5.
FLEET = {
    "alpha": StartPose(frame="field", x=0.0, y=7.5, heading=0.0),
    "bravo": StartPose(frame="field", x=0.0, y=27.5, heading=0.0),
    "charlie": StartPose(frame="field", x=27.5, y=0.0, heading=math.pi / 2),
}


@dataclass
class Drive:
    vehicle_id: str
    estimates: list  # SoilEstimate JSON payloads (bytes), in order
    stamps: list  # their stamps


def drive_estimates(vehicle_id: str, start: StartPose, length: float, seed: int = 0, fld: Optional[Field] = None,
                    config=None) -> Drive:
    """One vehicle's straight drive across the field: its soil estimates as the soil stage
    publishes them (JSON), for the map."""
    from soilocp.estimation.pipeline import VehiclePipeline
    from soilocp.sim.simulator import simulate

    fld = fld or mixed_field()
    sc = straight_drive(fld, start, length, name=f"field-{vehicle_id}")
    pipe = VehiclePipeline(config)
    out, stamps = [], []
    for sample, _truth in simulate(sc, seed=seed, start=start, vehicle_id=vehicle_id):
        soil = pipe.process_all(sample)[2]
        out.append(soil.model_dump_json().encode())
        stamps.append(soil.stamp)
    return Drive(vehicle_id, out, stamps)


def fleet_drives(length: float = 40.0, seed: int = 0, jobs: int = 2,
                 fleet: Optional[dict[str, StartPose]] = None) -> list[Drive]:
    """Every vehicle of ``fleet`` (default :data:`FLEET`) across :func:`mixed_field`, in parallel."""
    fleet = fleet or FLEET
    args = [(vid, st, length, seed + i) for i, (vid, st) in enumerate(fleet.items())]
    if jobs <= 1:
        return [drive_estimates(*a) for a in args]
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(_drive, args))


def _drive(a):
    return drive_estimates(*a)


def map_items(drives: Sequence[Drive], t0: float) -> list[tuple[str, bytes, float]]:
    """The drives' estimates as a map service receives them: (key, payload, received_at), the
    vehicles interleaved by stamp, received at t0 + stamp."""
    items = [(keys.soil(d.vehicle_id), p, t0 + s) for d in drives for p, s in zip(d.estimates, d.stamps)]
    items.sort(key=lambda it: it[2])
    return items


@dataclass
class MapScore:
    cells: int
    median_error: float  # |K - K_true| / K_true, median over the cells
    coverage: float  # share of cells whose 95 % band holds K_true
    worst: list  # (cell, K, band, K_true), the largest errors


def score_cells(cells: Sequence[MapCell], fld: Field) -> MapScore:
    """The map against the field's truth at each cell's centre (cells lie inside one region: the
    regions' edges are on the 5 m grid)."""
    import numpy as np

    errs, cover, rows = [], [], []
    for c in cells:
        k_true = fld.soil_at(*c.center)[1]
        e = abs(c.K - k_true) / k_true
        errs.append(e)
        cover.append(c.K_lo <= k_true <= c.K_hi)
        rows.append((e, c.cell, round(c.K, 1), (round(c.K_lo, 1), round(c.K_hi, 1)), k_true))
    rows.sort(reverse=True)
    return MapScore(len(cells), float(np.median(errs)) if errs else math.nan,
                    float(np.mean(cover)) if cover else math.nan, [r[1:] for r in rows[:5]])


@dataclass
class PassResult:
    change_stamp: float  # when the first wheel met the new soil, s
    k_new: float
    with_map_s: float  # convergence time after the change, with the map's prior
    without_map_s: float
    priors_given: int


def convergence_after(stamps: Sequence[float], k_est: Sequence[Optional[float]], t_change: float, k_true: float,
                      tol: float = 0.10, hold_s: float = 1.0) -> float:
    """Seconds from ``t_change`` until K is within ``tol`` of ``k_true`` and stays there for
    ``hold_s`` (inf if never)."""
    start = None
    for t, k in zip(stamps, k_est):
        if t < t_change:
            continue
        good = k is not None and abs(k - k_true) <= tol * k_true
        if good and start is None:
            start = t
        elif not good:
            start = None
        if start is not None and t - start >= hold_s:
            return start - t_change
    return math.inf


def second_pass(cells: Sequence[MapCell], vehicle_id: str, start: StartPose, length: float, seed: int,
                fld: Optional[Field] = None) -> PassResult:
    """One drive over mapped ground, through two estimators on the very same samples: one that
    trusts the map (:class:`soilocp.map.prior.MapPrior`) and one that does not; the convergence
    after the drive's first soil change."""
    from soilocp.estimation.pipeline import VehiclePipeline
    from soilocp.map.prior import MapPrior
    from soilocp.sim.simulator import simulate

    fld = fld or mixed_field()
    sc = straight_drive(fld, start, length, name=f"second-pass-{vehicle_id}")
    prior = MapPrior(cells)
    with_map, without = VehiclePipeline(prior=prior), VehiclePipeline()
    stamps, k_with, k_without, t_change, k_new = [], [], [], None, None
    first = None
    for sample, truth in simulate(sc, seed=seed, start=start, vehicle_id=vehicle_id):
        if first is None:
            first = truth.soil_strength
        if t_change is None and any(k != first for k in truth.wheel_soil_strength):
            t_change, k_new = truth.stamp, next(k for k in truth.wheel_soil_strength if k != first)
        stamps.append(sample.stamp)
        k_with.append(with_map.process_all(sample)[2].soil_strength)
        k_without.append(without.process_all(sample)[2].soil_strength)
    if t_change is None:
        raise ValueError("the drive crosses no soil change")
    return PassResult(t_change, k_new, convergence_after(stamps, k_with, t_change, k_new),
                      convergence_after(stamps, k_without, t_change, k_new), prior.entered)
