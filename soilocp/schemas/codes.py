"""The statuses and reason codes of a soil / OCP record: name -> (who sets it, its meaning), in code
order.  Generated from the compiled core's tables (soilocp/_core/src/codes.rs) by
``python -m soilocp.cli.generate_codes``: do not edit by hand (tests/test_codes.py fails when this module and
the core differ).  Who sets it: "soil" (the soil stage), "publisher" (the live publisher), "ocp" (the
OCP stage)."""

from __future__ import annotations

STATUSES: dict[str, tuple[str, str]] = {
    'ok': ('soil', 'K is confirmed: within +-30 % at 2 sigma, and every model check vouches for it'),
    'uncertain': ('soil', 'K is reported with a wide band; the reason says why'),
    'holding': ('soil', 'slip is uninformative now: the last estimate is held'),
    'no_estimate': ('soil', 'no K: none yet, or withdrawn'),
    'not_observable': ('soil', 'the data do not determine K now'),
    'model_mismatch': ('soil', 'the model does not explain the data: the traction curve, or the axles read different soils'),
    'stale': ('publisher', 'live publisher: the inputs stopped'),
}

REASONS: dict[str, tuple[str, str]] = {
    'none': ('soil', 'no reason: the estimate is ok (or a record written before reason codes existed)'),
    'not_yet': ('soil', 'slip has not been informative yet: no K so far'),
    'stamp_backwards': ('soil', 'the stamps went backwards (source restarted): estimate withdrawn'),
    'withdrawn': ('soil', 'slip uninformative for longer than hold_after + expire_after: estimate withdrawn'),
    'holding': ('soil', 'slip uninformative now: the last K is held'),
    'wide': ('soil', "K's band is wider than uncertain_log_sigma: K poorly determined"),
    'systematic_scale': ('soil', "K's band is mostly the torque constant's uncertainty"),
    'systematic_scale_calibrate': ('soil', "K's band is mostly the torque constant's, and the data suggest a wrong constant"),
    'systematic_radius': ('soil', "K's band is mostly the wheel radius's uncertainty at these small slips"),
    'not_identifiable': ('soil', 'no independent ground speed (or a log that cannot identify K): slip and K not identifiable'),
    'axles': ('soil', "the front and rear axles read different soils (normal forces or an axle's torque constant off)"),
    'nis': ('soil', 'the traction curve does not explain the (slip, traction) pairs at any K'),
    'below_floor': ('soil', 'traction below what the weakest soil gives at this slip (torque scale or units?): no K'),
    'ground_stale': ('soil', 'slip is informative but the ground speed reading is stale'),
    'readings_held': ('soil', 'slip is informative but the wheel speed / torque readings are held (refresh too slow)'),
    'undetermined': ('soil', 'slip is informative but the torque balance does not determine gross traction'),
    'leans': ('soil', 'the data lean to another torque scale, which a drive at constant speed cannot tell from K'),
    'axle_window': ('soil', 'the axles read different soils for most of the evidence window'),
    'evidence': ('soil', 'K from too few seconds of informative slip for the model checks: not yet ok'),
    'out_skid': ('soil', 'wheels in a skid turn (outside the longitudinal model): no K while it lasts'),
    'out_no_wheel': ('soil', 'no wheel inside the longitudinal model (stall, slip beyond eq. 1, stopped unpowered)'),
    'out_holding': ('soil', 'no wheel inside the longitudinal model: the last K is held'),
    'out_others': ('soil', 'some wheels outside the longitudinal model: K from the others'),
    'stale': ('publisher', 'live publisher: no input for longer than stale_timeout_s'),
    'curve_unchecked': ('ocp', "OCP record: the OCPs rest on the paper's traction curve, which nobody checked for this wheel"),
    'curve_learnt': ('ocp', 'OCP record: the OCPs are the traction curve this drive showed, not checked by a calibration'),
    'curve_extrapolated': ('ocp', "OCP record: K is beyond the soils the wheel's calibration was fitted over"),
}
