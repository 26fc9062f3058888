"""What a user can do about each reason a record is not ``ok``: the next step per reason code, and the
table ``soilocp estimate`` and ``soilocp run`` end with (records per status and reason code, each with its
next step).  The codes are :data:`soilocp.schemas.pipeline.REASON_CODES`; docs/from-no-estimate-to-ok.md walks a
real log through them.  Lean: no numpy (``soilocp run`` prints it)."""

from __future__ import annotations

from typing import Iterable, Mapping

from soilocp.schemas.pipeline import REASON_CODES

_TRACTION_TEST = "drive a traction test (straight; accelerate and brake so the wheels slip 5-30 % for seconds)"
_CALIBRATE = ("calibrate the torque constant (soilocp calibrate-torque LOG --vehicle V.json --json k.json), then "
              "--torque-constant k.json")
_OUT_OF_MODEL = ("drive straight with moderate slip: skid turns, stalls and slips beyond eq. 1 are outside the "
                 "longitudinal model")

#: reason code -> the next step a user can take (every code of soilocp.schemas.pipeline.REASON_CODES)
NEXT_STEPS: dict[str, str] = {
    "none": "nothing: K and the OCPs are confirmed",
    "not_yet": _TRACTION_TEST,
    "stamp_backwards": "split the log where its source restarted, or sort it by stamp",
    "withdrawn": "informative slip too long ago: " + _TRACTION_TEST,
    "holding": "K held from earlier slip; to refresh it, " + _TRACTION_TEST,
    "wide": "more and higher slip narrows K: " + _TRACTION_TEST,
    "systematic_scale": _CALIBRATE + "; lower soil.gross_scale_sigma to its relative uncertainty",
    "systematic_scale_calibrate": _CALIBRATE,
    "systematic_radius": "measure the wheels' rolling radius (distance / wheel turns / 2 pi) into the vehicle "
                         "file's wheel_radius, and lower soil.radius_sigma",
    "not_identifiable": "record an independent ground speed (GNSS, visual or lidar odometry; wheel odometry is "
                        "not one) into the log's ground_speed",
    "axles": "check the vehicle file's mass, a, b and h (the normal forces) and each axle's torque constant",
    "nis": "check the torque unit (--torque-constant), the vehicle file (--vehicle) and the sensor signs "
           "(docs/sensor-log.md)",
    "below_floor": "the torques are too small for any soil: give the torque constant (--torque-constant; "
                   "soilocp calibrate-torque) or the vehicle file (--vehicle)",
    "ground_stale": "log the ground speed faster (10 Hz or more), or raise soil.max_input_age if its refresh is "
                    "known to be slow",
    "readings_held": "log wheel speeds and torques at the full rate (their refresh is too slow to measure "
                     "traction)",
    "undetermined": "check the vehicle file's wheel_inertia and the torque signal's noise",
    "leans": _TRACTION_TEST + "; or " + _CALIBRATE,
    "axle_window": "check the vehicle file's mass, a, b and h and each axle's torque constant",
    "evidence": "keep driving with informative slip: the model checks need soil.mismatch_min_evidence s of it",
    "out_skid": _OUT_OF_MODEL,
    "out_no_wheel": _OUT_OF_MODEL,
    "out_holding": _OUT_OF_MODEL,
    "out_others": "nothing needed (K comes from the other wheels); " + _OUT_OF_MODEL,
    "stale": "the inputs stopped: check the sensor source and the services' health (soilocp fleet status)",
    "curve_unchecked": "fit the wheel's own traction curve: drive a traction sweep past the peak on two soils (or run "
                       "soilocp calibrate-drive), soilocp calibrate --from-drive LOG --vehicle V.json --out C.json, and "
                       "name C.json as the vehicle file's traction_curve (docs/calibration.md)",
    "curve_learnt": "the OCPs are this drive's learnt curve: fit a calibration from such drives (soilocp calibrate "
                    "--from-drive) and name it as the vehicle file's traction_curve (docs/calibration.md)",
    "ocp_wide": "keep driving with informative slip (a traction test narrows K's band), or, if the controller "
                "tolerates more, raise curve.ok_mu_t / curve.ok_s_t; a constant-speed drive with an uncalibrated "
                "torque constant needs soilocp calibrate-torque",
    "curve_extrapolated": "calibrate on this soil too: drive the calibration sweep here and refit with all the "
                          "drives (soilocp calibrate --from-drive OLD.jsonl NEW.jsonl ...)",
}
if set(NEXT_STEPS) != set(REASON_CODES):
    raise ImportError(f"next steps for {sorted(set(REASON_CODES) ^ set(NEXT_STEPS))} missing or unknown")


def next_step(reason_code: str) -> str:
    """The next step for ``reason_code`` (an unknown code: say so, never a blank)."""
    return NEXT_STEPS.get(reason_code, f"unknown reason code {reason_code!r}: see the record's reason")


def tally(records: Iterable[Mapping]) -> dict[tuple[str, str], int]:
    """Records (dicts with status and reason_code) counted per (status, reason code)."""
    out: dict[tuple[str, str], int] = {}
    for r in records:
        key = (r["status"], r.get("reason_code", "none"))
        out[key] = out.get(key, 0) + 1
    return out


def status_rows(counts: Mapping[tuple[str, str], int]) -> list[tuple[str, str, int, float, str]]:
    """(status, reason code, records, share, next step), the most frequent first."""
    total = sum(counts.values()) or 1
    rows = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))
    return [(st, code, n, n / total, next_step(code)) for (st, code), n in rows]


def status_table(counts: Mapping[tuple[str, str], int], title: str = "records per status and reason"):
    """The rich table of :func:`status_rows` (the end of ``soilocp estimate`` and ``soilocp run``)."""
    from rich.table import Table

    t = Table(title=title, title_justify="left", show_lines=False)
    t.add_column("status", no_wrap=True)
    t.add_column("reason_code", no_wrap=True)
    t.add_column("records", justify="right", no_wrap=True)
    t.add_column("share", justify="right", no_wrap=True)
    t.add_column("next step", overflow="fold")
    for st, code, n, share, step in status_rows(counts):
        t.add_row(st, code, str(n), f"{share:.1%}", step)
    return t


def verdict(counts: Mapping[tuple[str, str], int]) -> str:
    """One line: how many records are ok, and what to do first when few are."""
    total = sum(counts.values())
    ok = sum(n for (st, _), n in counts.items() if st == "ok")
    if total == 0:
        return "no records"
    if ok == total:
        return f"all {total} records ok"
    worst = [code for st, code, *_ in status_rows(counts) if st != "ok"]
    return (f"{ok} of {total} records ok ({ok / total:.1%}); the commonest other reason is {worst[0]!r}: "
            f"{next_step(worst[0])}. How to get from no_estimate to ok: docs/from-no-estimate-to-ok.md")
