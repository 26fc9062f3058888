"""Testbed data for calibration (paper §2.2): drawbar-pull measurements of a single-wheel testbed
at controlled slips, read from CSV, built from arrays, or synthesised from a model.

Data (:func:`read_testbed_csv`): one row per measurement, with a header naming the columns

* ``slip``  - slip ratio S (eq. 1), S > 0 driving, S < 0 braking;
* ``soil``  - soil label (e.g. ``sand``);
* either ``mu`` (net drawbar coefficient F_DP / W) or ``drawbar_pull`` [N] and ``normal_load`` [N];
* optionally gross traction: ``gross_traction`` (F_GT / W) with ``mu``, or ``gross_force`` [N] with
  ``drawbar_pull``.  Other columns are ignored.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from soilocp.model.checks import as_float_array, positive_scalar
from soilocp.model.parse import parse_finite
from soilocp.model.constants import ModelConstants
from soilocp.model.traction import gross_traction, net_traction

#: The testbed's controlled slips (paper §2.2).
TESTBED_SLIPS: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)


@dataclass(frozen=True)
class TestbedData:
    """Testbed measurements: slip, net drawbar coefficient mu, optional gross coefficient, soil."""

    __test__ = False  # not a pytest test class, despite the name

    slip: np.ndarray
    mu: np.ndarray
    soil: tuple[str, ...]
    gross: np.ndarray | None = None
    source: str = "<arrays>"

    @property
    def soils(self) -> list[str]:
        """Soil labels in order of first appearance."""
        return list(dict.fromkeys(self.soil))

    def __len__(self) -> int:
        return len(self.soil)


def build_testbed(slip, mu, soil: Sequence[str], gross=None, source: str = "<arrays>") -> TestbedData:
    """Validate arrays into :class:`TestbedData` (1-D, equal length, finite, |slip| <= 1)."""
    s = as_float_array("slip", slip, shape=(-1,))
    m = as_float_array("mu", mu, shape=(-1,))
    labels = tuple(str(x).strip() for x in soil)
    g = None if gross is None else as_float_array("gross", gross, shape=(-1,))
    lengths = {"slip": len(s), "mu": len(m), "soil": len(labels)} | ({} if g is None else {"gross": len(g)})
    if len(set(lengths.values())) != 1:
        raise ValueError(f"testbed arrays must have equal lengths, got {lengths}")
    if len(s) == 0:
        raise ValueError("testbed data is empty")
    if np.any(np.abs(s) > 1):
        raise ValueError(f"slip must be in [-1, 1], got {s[np.abs(s) > 1][:4].tolist()}")
    if any(not x for x in labels):
        raise ValueError("soil labels must be non-empty")
    return TestbedData(slip=s, mu=m, soil=labels, gross=g, source=source)


def read_testbed_csv(path: str | Path) -> TestbedData:
    """Read testbed data from CSV (columns in the module docstring).

    Errors name the file, the line (the header is line 1) and the column.
    """
    p = Path(path)
    try:
        fh = p.open(newline="")
    except FileNotFoundError:
        raise ValueError(f"data file {str(p)!r} does not exist") from None
    with fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        if not header:
            raise ValueError(f"{p}: empty file, expected a header line with columns slip, soil, mu")
        reader.fieldnames = header
        cols = set(header)
        if "mu" in cols and "drawbar_pull" in cols:
            raise ValueError(f"{p} line 1: give either 'mu' or 'drawbar_pull' + 'normal_load', not both")
        force_mode = "mu" not in cols and ("drawbar_pull" in cols or "normal_load" in cols)
        need = ["slip", "soil"] + (["drawbar_pull", "normal_load"] if force_mode else ["mu"])
        missing = [c for c in need if c not in cols]
        if missing:
            raise ValueError(
                f"{p} line 1: missing column(s) {missing}; need slip, soil and either mu or "
                f"drawbar_pull + normal_load; found {header}"
            )
        gross_col = "gross_force" if force_mode else "gross_traction"
        has_gross = gross_col in cols
        slip, mu, soil, gross = [], [], [], []
        for row in reader:
            line = reader.line_num
            if all((v or "").strip() == "" for k, v in row.items() if k is not None):
                continue  # blank line
            if None in row:
                raise ValueError(f"{p} line {line}: more fields than header columns")

            def num(col: str) -> float:
                text = row.get(col)
                if text is None or text.strip() == "":
                    raise ValueError(f"{p} line {line}, column {col!r}: missing value")
                return parse_finite(text.strip(), f"{p} line {line}, column {col!r}")

            s = num("slip")
            if abs(s) > 1:
                raise ValueError(f"{p} line {line}, column 'slip': {s} is outside [-1, 1]")
            label = (row.get("soil") or "").strip()
            if not label:
                raise ValueError(f"{p} line {line}, column 'soil': empty soil label")
            if force_mode:
                w = num("normal_load")
                if w <= 0:
                    raise ValueError(f"{p} line {line}, column 'normal_load': {w} must be > 0 N")
                m = num("drawbar_pull") / w
                gr = num(gross_col) / w if has_gross else None
            else:
                m = num("mu")
                gr = num(gross_col) if has_gross else None
            slip.append(s)
            mu.append(m)
            soil.append(label)
            gross.append(gr)
    if not slip:
        raise ValueError(f"{p}: no data rows after the header")
    return TestbedData(
        slip=np.array(slip),
        mu=np.array(mu),
        soil=tuple(soil),
        gross=np.array(gross) if has_gross else None,
        source=str(p),
    )


def synthetic_testbed(
    constants: ModelConstants,
    soils: Mapping[str, float],
    *,
    slips: Sequence[float] = TESTBED_SLIPS,
    repeats: int = 5,
    noise: float = 0.01,
    seed: int = 0,
    with_gross: bool = False,
) -> TestbedData:
    """Testbed data generated from the model (eq. 6, and eq. 3 if ``with_gross``) with Gaussian noise.

    ``noise`` is the standard deviation of the coefficient noise; the generator is seeded.  This is
    how the calibration is tested (recover known constants) and demonstrated.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a finite standard deviation >= 0, got {noise!r}")
    rng = np.random.default_rng(seed)
    s_one = as_float_array("slips", slips, shape=(-1,))
    names = list(soils)
    ks = np.array([positive_scalar(f"soils[{n!r}]", soils[n]) for n in names])
    s = np.tile(np.repeat(s_one, repeats), len(names))
    k = np.repeat(ks, len(s_one) * repeats)
    labels = tuple(np.repeat(np.array(names, dtype=object), len(s_one) * repeats))
    mu = net_traction(s, k, constants) + rng.normal(0.0, noise, s.shape)
    gross = gross_traction(s, k, constants) + rng.normal(0.0, noise, s.shape) if with_gross else None
    return TestbedData(slip=s, mu=mu, soil=labels, gross=gross, source=f"synthetic(seed={seed})")


def write_testbed_csv(data: TestbedData, path: str | Path) -> None:
    """Write :class:`TestbedData` as a CSV that :func:`read_testbed_csv` reads back."""
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["soil", "slip", "mu"] + (["gross_traction"] if data.gross is not None else []))
        for i in range(len(data)):
            row = [data.soil[i], f"{data.slip[i]:.6g}", f"{data.mu[i]:.6g}"]
            if data.gross is not None:
                row.append(f"{data.gross[i]:.6g}")
            w.writerow(row)
