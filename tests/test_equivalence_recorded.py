"""scripts/equivalence.py's comparison against a recording: numbers within their field's tolerance, a status
or reason change listed (and its record's numbers left to it), anything else a difference."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("equivalence", ROOT / "scripts/equivalence.py")
eq = importlib.util.module_from_spec(spec)
sys.modules.setdefault("equivalence", eq)  # the dataclasses resolve their module
spec.loader.exec_module(eq)


def _compare(a: dict, b: dict) -> "eq.Against":
    res = eq.Against({"name": "d", "group": "g"})
    sa, sb = eq._statuses(a), eq._statuses(b)
    changed = False
    for k in sa.keys() | sb.keys():
        if sa.get(k) != sb.get(k):
            changed = True
            res.transitions[(k, sa.get(k), sb.get(k))] = res.transitions.get((k, sa.get(k), sb.get(k)), 0) + 1
    eq._walk_tol(a, b, "", res, 1, skip_numbers=changed)
    return res


def test_numbers_within_their_fields_tolerance_pass_and_beyond_it_fail():
    rec = {"status": "ok", "reason_code": "none", "k": 100.0, "mu": [0.1, 0.2]}
    close = {**rec, "k": 100.0 * (1 + 5e-5), "mu": [0.1 * (1 + 1e-7), 0.2]}
    assert _compare(rec, close).verdict == "within"
    far = {**rec, "mu": [0.1 * (1 + 1e-4), 0.2]}  # mu takes the default 1e-6
    r = _compare(rec, far)
    assert r.over == 1 and r.verdict == "OUTSIDE" and "mu[0]" in r.examples[0]


def test_a_status_change_is_listed_not_compared_and_a_text_change_is_a_difference():
    a = {"status": "ok", "reason_code": "none", "k": 100.0}
    b = {"status": "uncertain", "reason_code": "wide", "k": 180.0}
    r = _compare(a, b)
    assert r.over == 0 and r.transitions == {("status", "ok", "uncertain"): 1, ("reason_code", "none", "wide"): 1}
    assert r.verdict == "within (statuses differ)"
    report = eq.against_report([r], {"commit": "0123456789"}, 1.0)
    assert "status: ok -> uncertain: 1 records in 1 drives" in report
    r = _compare({"status": "ok", "soil_class": "sand"}, {"status": "ok", "soil_class": "grass"})
    assert r.shape_diffs == 1 and r.verdict == "OUTSIDE"


def test_every_tolerance_states_its_reason():
    assert all(len(t) == 3 and t[2] for t in [eq.RECORDED_DEFAULT, *eq.RECORDED_TOLERANCE.values()])
