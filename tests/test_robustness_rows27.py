"""The robustness rows of the drives beyond straight forward traction (reverse, skid turns, payload and motor
changes, a slope, a stall) and their verdicts: every row counts its `ok` records more than 30 % off (none allowed); rows where K is limited or not identifiable are judged by their band and their
reason, not by the K error."""

from __future__ import annotations

from soilocp.analysis.robustness import _verdict
from soilocp.sim.variants import VARIANTS


def _row(**kw):
    row = dict(k_median_rel=0.5, k_p90_rel=0.9, band_coverage=0.95, std_rel_median=0.3, change_convergence_s=None,
               terrain_changes=3, mu_T_err=0.1, S_T_err=0.1, S_E_err=0.1, confident_wrong=0, reason_named_share=0.8,
               ok_ocp_off=0, mu_T_p90=0.2, S_T_p90=0.2)
    row.update(kw)
    return row


def test_the_robustness_rows_exist_with_their_identifiability():
    want = {"reverse": "yes", "reverse-braking": "yes", "skid-spot-turn": "no", "skid-arcs": "yes",
            "payload+25-accel-brake": "yes", "payload+25": "limited", "motor+8-accel-brake": "yes",
            "motor+8": "limited", "slope-cruise-12": "no", "stall-draft": "no"}
    assert {n: VARIANTS[n].identifiable for n in want} == want
    assert VARIANTS["payload+25"].reason_names == VARIANTS["motor+8"].reason_names == "torque scale"


def test_one_confident_wrong_record_misses_any_row():
    for ident in ("yes", "limited", "no"):
        ok, missed = _verdict(ident, _row(confident_wrong=1))
        assert not ok and "ok>30%" in missed


def test_limited_and_no_rows_are_judged_by_band_and_reason_not_by_k():
    assert _verdict("limited", _row(), "torque scale") == (True, [])  # K 50 % off: not judged
    assert _verdict("no", _row(band_coverage=None)) == (True, [])  # serves no band: nothing to cover
    assert _verdict("no", _row(band_coverage=0.5)) == (False, ["2std"])  # a band it serves must hold the truth
    assert _verdict("limited", _row(reason_named_share=0.2), "torque scale") == (False, ["reason"])
    assert _verdict("limited", _row(reason_named_share=None), "torque scale") == (False, ["reason"])
    ok, missed = _verdict("yes", _row())
    assert not ok and {"K med", "K p90", "conv", "std/K", "OCP"} <= set(missed)
