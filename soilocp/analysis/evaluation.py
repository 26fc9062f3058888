"""Accuracy of estimates against simulator truth: K error per terrain segment after a settle
time, convergence after each change, OCP errors and soil-class accuracy, checked against the
project's targets."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable, Optional

import numpy as np
from soilocp.model.files import read_jsonl

#: The accuracy targets a simulated drive is judged by against its truth: K's relative error, convergence, the OCPs'
#: error, the soil-class accuracy and the settling time after a change of soil.
TARGETS = {
    "k_median_rel": 0.10,
    "k_p90_rel": 0.25,
    "convergence_s": 1.5,
    "convergence_band": 0.15,
    "ocp_median_abs": 0.02,
    "class_accuracy": 0.95,
    "settle_s": 2.0,
}

#: Relative K error beyond which a number served with status "ok" counts as confidently wrong
#: (where K is not identifiable the output must say so "instead of a number more than
#: 30 % off").
UNFLAGGED_ERROR_REL = 0.30

#: OCP errors beyond which an OCP served with status "ok" counts as confidently wrong: a controller acts
#: on an ok record's mu_T and S_T (|mu_T| or |S_T| error against the true curve's peak)
UNFLAGGED_OCP_ERROR = {"mu_T": 0.10, "S_T": 0.05}


@dataclass
class SegmentResult:
    index: int
    soil_class: str
    soil_strength: float
    start: float
    end: float
    settled_samples: int
    coverage: float  # fraction of settled samples with an estimate
    k_median_rel: Optional[float]
    k_p90_rel: Optional[float]
    convergence_s: Optional[float]  # None: never converged within the band
    mu_T_median_abs: Optional[float]
    S_T_median_abs: Optional[float]
    S_E_median_abs: Optional[float]
    class_accuracy: Optional[float]
    #: 90th percentiles of the same OCP errors (a record without the OCP counts as a miss)
    mu_T_p90_abs: Optional[float] = None
    S_T_p90_abs: Optional[float] = None
    #: settled samples with status "ok" whose mu_T or S_T is off by more than UNFLAGGED_OCP_ERROR
    ok_ocp_off: int = 0
    statuses: dict = field(default_factory=dict)
    #: settled samples that report K and its std; share of them with |K - K_true| <= 2 std
    band_samples: int = 0
    band_coverage: Optional[float] = None
    std_rel_median: Optional[float] = None  # median K_std / K over the settled samples that report both
    std_rel: tuple = field(default=(), repr=False)  # those K_std / K values, to pool segments (not in the JSON)
    #: settled samples with status "ok" and K more than UNFLAGGED_ERROR_REL off (a confident wrong number)
    confident_wrong: int = 0
    #: settled samples that report K with a status other than "ok", and how many of them name
    #: ``reason_names`` in their reason (evaluate_records' argument; 0 when not asked)
    flagged: int = 0
    flagged_named: int = 0

    def passes(self) -> dict[str, bool]:
        t = TARGETS

        def le(v, lim):
            return v is not None and v <= lim

        return {
            "k_median": le(self.k_median_rel, t["k_median_rel"]),
            "k_p90": le(self.k_p90_rel, t["k_p90_rel"]),
            "convergence": le(self.convergence_s, t["convergence_s"]),
            "ocp": all(le(v, t["ocp_median_abs"]) for v in (self.mu_T_median_abs, self.S_T_median_abs, self.S_E_median_abs)),
            "class": self.class_accuracy is not None and self.class_accuracy >= t["class_accuracy"],
        }


def _segments(stamps: np.ndarray, k_true: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [i0, i1) of constant true K under the CoM."""
    change = np.flatnonzero(np.abs(np.diff(k_true)) > 1e-9 * np.maximum(k_true[1:], 1)) + 1
    bounds = np.concatenate([[0], change, [len(k_true)]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def evaluate_records(truth: list[dict], estimates: list[dict], settle: float = TARGETS["settle_s"],
                     reason_names: str = "", judged_from: float = 0.0, ocp_after: float = 0.0) -> list[SegmentResult]:
    """Join truth and estimates on (vehicle_id, seq) and score each terrain segment.  With
    ``reason_names``, also count the flagged settled records whose reason names it.  K's median and p90
    and the OCP errors judge the settled samples from the truth stamp ``judged_from`` on (a drive whose
    first seconds cannot give K: :attr:`soilocp.sim.variants.Variant.judged_from`); coverage, the band,
    the class and the confidently wrong records judge every settled sample.  ``ocp_after`` s more after the
    settle the OCP errors' median and p90 start (another tyre's curve is learnt from one sweep of the new soil;
    the ok records whose OCPs are off count from the settle on)."""
    est_by_key = {(e["vehicle_id"], e["seq"]): e for e in estimates}
    rows = [(t, est_by_key.get((t["vehicle_id"], t["seq"]))) for t in truth]
    if not rows:
        raise ValueError("truth log is empty")
    if all(e is None for _, e in rows):
        raise ValueError("no estimate matches the truth log (vehicle_id/seq differ?)")
    stamps = np.array([t["stamp"] for t, _ in rows])
    k_true = np.array([t["soil_strength"] for t, _ in rows])
    results = []
    for idx, (i0, i1) in enumerate(_segments(stamps, k_true)):
        t0, t_end = stamps[i0], stamps[i1 - 1]
        seg = rows[i0:i1]
        kt = k_true[i0]
        k_est = np.array([e["soil_strength"] if e and e.get("soil_strength") is not None else np.nan for _, e in seg])
        rel = np.abs(k_est - kt) / kt
        ts = stamps[i0:i1]
        settled = ts >= t0 + settle
        judged = settled & (ts >= judged_from)
        ocp_judged = judged & (ts >= t0 + settle + ocp_after)
        rel_settled = rel[settled]
        n_settled = int(settled.sum())
        have = np.isfinite(rel_settled)
        statuses: dict[str, int] = {}
        for _, e in seg:
            s = e["status"] if e else "missing"
            statuses[s] = statuses.get(s, 0) + 1

        def med_p(vals):
            if n_settled == 0:
                return None, None
            v = np.sort(np.where(np.isfinite(vals), vals, np.inf))  # no estimate counts as a miss
            # order statistics, not interpolation: inf - inf would give nan
            return float(v[(len(v) - 1) // 2]), float(v[min(int(np.ceil(0.9 * len(v))) - 1, len(v) - 1)])

        kmed, kp90 = med_p(rel[judged]) if judged.any() else (None, None)
        # convergence: first time after which the estimate stays inside the band to segment end,
        # where the end is the last sample with every wheel on this soil: the front wheels reach
        # the next soil b/V s before the CoM, and an estimate that follows them is fast, not wrong
        wheels_on = [all(abs(w - kt) <= 1e-9 * kt for w in t.get("wheel_soil_strength", (kt,))) for t, _ in seg]
        n_judged = len(seg)
        while n_judged > 1 and not wheels_on[n_judged - 1]:
            n_judged -= 1
        inside = (np.isfinite(rel) & (rel <= TARGETS["convergence_band"]))[:n_judged]
        conv = None
        if inside[-1]:
            outside = np.flatnonzero(~inside)
            first_ok = 0 if outside.size == 0 else int(outside[-1]) + 1
            conv = float(ts[first_ok] - t0)

        def ocp_errs(name, pick):
            return [np.inf if e is None or e.get(name) is None else abs(e[name] - t[name])
                    for (t, e), ok in zip(seg, pick) if ok]

        def ocp_err(name):
            vals = ocp_errs(name, ocp_judged)
            return float(np.median(vals)) if vals else None

        def ocp_p90(name):
            vals = np.sort(ocp_errs(name, ocp_judged))
            return float(vals[min(int(np.ceil(0.9 * len(vals))) - 1, len(vals) - 1)]) if len(vals) else None

        # the served band, over the settled samples that report K and its std: the record's 2-sigma band
        # (soil_strength_low..high, Gaussian in ln K) where it gives one, else K +- 2 std
        def field(name):
            return np.array([e[name] if e and e.get(name) is not None else np.nan for _, e in seg])[settled]

        k_std, low, high = field("soil_strength_std"), field("soil_strength_low"), field("soil_strength_high")
        k_set = k_est[settled]
        banded = np.isfinite(k_set) & np.isfinite(k_std)
        low = np.where(np.isfinite(low), low, k_set - 2.0 * k_std)
        high = np.where(np.isfinite(high), high, k_set + 2.0 * k_std)
        band_hits = (low[banded] <= kt) & (kt <= high[banded])
        status_ok = np.array([bool(e) and e["status"] == "ok" for _, e in seg])[settled]
        # judged against the nearest soil under the wheels: in the b/V s before the CoM reaches the next soil
        # the front wheels are on it, and a K that reads either soil is not wrong (the convergence rule above
        # ends the segment there for the same reason); a K between the two, far from both, still counts
        rel_wheels = np.array([min(abs(k - w) / w for w in t.get("wheel_soil_strength", (kt,))) if np.isfinite(k)
                               else np.nan for (t, _), k in zip(seg, k_est)])[settled]
        confident_wrong = int(np.sum(status_ok & np.isfinite(rel_wheels) & (rel_wheels > UNFLAGGED_ERROR_REL)))
        ok_ocp_off = sum(
            1 for (t, e), ok in zip(seg, settled)
            if ok and e and e["status"] == "ok" and any(
                e.get(n) is not None and abs(e[n] - t[n]) > lim for n, lim in UNFLAGGED_OCP_ERROR.items()))
        flagged_recs = [e for (_, e), ok in zip(seg, settled)
                        if ok and e and e["status"] != "ok" and e.get("soil_strength") is not None]
        named = sum(reason_names.lower() in str(e.get("reason", "")).lower() for e in flagged_recs) if reason_names else 0

        cls_ok = [bool(e and e.get("soil_class") == t.get("soil_class")) for (t, e), ok in zip(seg, settled) if ok]
        results.append(
            SegmentResult(
                index=idx,
                soil_class=str(seg[0][0].get("soil_class", "?")),
                soil_strength=float(kt),
                start=float(t0),
                end=float(t_end),
                settled_samples=n_settled,
                coverage=float(have.mean()) if n_settled else 0.0,
                k_median_rel=None if kmed is None or math.isinf(kmed) else kmed,
                k_p90_rel=None if kp90 is None or math.isinf(kp90) else kp90,
                convergence_s=conv,
                mu_T_median_abs=_fin(ocp_err("mu_T")),
                S_T_median_abs=_fin(ocp_err("S_T")),
                S_E_median_abs=_fin(ocp_err("S_E")),
                class_accuracy=float(np.mean(cls_ok)) if cls_ok else None,
                mu_T_p90_abs=_fin(ocp_p90("mu_T")),
                S_T_p90_abs=_fin(ocp_p90("S_T")),
                ok_ocp_off=int(ok_ocp_off),
                statuses=statuses,
                band_samples=int(banded.sum()),
                band_coverage=float(band_hits.mean()) if band_hits.size else None,
                std_rel_median=float(np.median(k_std[banded] / k_set[banded])) if banded.any() else None,
                std_rel=tuple((k_std[banded] / k_set[banded]).tolist()),
                confident_wrong=confident_wrong,
                flagged=len(flagged_recs),
                flagged_named=int(named),
            )
        )
    return results


def _fin(v):
    return None if v is None or not math.isfinite(v) else v


def evaluate_files(truth: str | Path, estimates: str | Path, settle: float = TARGETS["settle_s"]) -> list[SegmentResult]:
    return evaluate_records(read_jsonl(truth), read_jsonl(estimates), settle)


def results_as_json(results: Iterable[SegmentResult]) -> list[dict]:
    out = []
    for r in results:
        d = asdict(r)
        d.pop("std_rel")
        d["passes"] = r.passes()
        out.append(d)
    return out
