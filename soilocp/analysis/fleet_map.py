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

from soilocp.schemas import keys
from soilocp.schemas.map import MapCell

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


#: The second passes of docs/map.md §4: (vehicle, start pose, length m, seed), the first soil change of each.
SECOND_PASSES = {
    "alpha2": (FLEET["alpha"], 23.0, 10),  # sand 50 -> grass 200
    "bravo2": (FLEET["bravo"], 23.0, 11),  # gravel 80 -> firm 300
    "charlie2": (FLEET["charlie"], 23.0, 12),  # grass 200 -> firm 300
}


def second_passes(cells: Sequence[MapCell], jobs: int = 2) -> dict[str, PassResult]:
    """Every pass of :data:`SECOND_PASSES` over the map ``cells`` (:func:`second_pass`), in parallel."""
    args = [(cells, vid, st, length, seed) for vid, (st, length, seed) in SECOND_PASSES.items()]
    if jobs <= 1:
        return {a[1]: second_pass(*a) for a in args}
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return dict(zip(SECOND_PASSES, ex.map(_second_pass, args)))


def _second_pass(a):
    return second_pass(*a)


def main() -> None:
    """``python -m soilocp.analysis.fleet_map``: the fleet's first pass, the map, its score, and
    the second passes with and without the map (docs/map.md §4, §5)."""
    import tempfile

    from soilocp.map.store import open_store
    from soilocp.map.updater import MapUpdater

    t0 = 1_800_000_000.0
    with tempfile.TemporaryDirectory() as d:
        st = open_store(f"sqlite:{d}/fleet.db")
        MapUpdater(st).apply(map_items(fleet_drives(40.0, seed=0), t0))
        cells = st.all_cells(t0 + 60.0)
        st.close()
    s = score_cells(cells, mixed_field())
    print(f"fleet map: {s.cells} cells, median |K error| {s.median_error:.3f}, 95 % band coverage {s.coverage:.2f}")
    for vid, r in second_passes(cells).items():
        gain = r.without_map_s / r.with_map_s if r.with_map_s > 0 else math.inf
        print(f"{vid}: -> K {r.k_new:g} at {r.change_stamp:.2f} s: within 10 % for 1 s after {r.with_map_s:.2f} s "
              f"with the map, {r.without_map_s:.2f} s without ({gain:.1f}x; {r.priors_given} cells entered)")


if __name__ == "__main__":
    main()
