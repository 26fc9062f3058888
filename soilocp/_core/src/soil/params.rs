//! The soil estimator's settings, each declared once (crate::settings): the per-sample update,
//! the record's status and the slip gate read them here, and `soilocp.estimation.soil_config`
//! builds the validated, documented `SoilConfig` from these declarations.

use crate::settings::settings_struct;

settings_struct! {
    /// The soil estimator's settings (docs/method.md §4, §9, §11-13, §16).
    pub struct Params("soil") {
        /// |slip| below this carries no usable information.
        slip_min: Float = 0.04, Internal, "", [gt 0.0, lt 1.0];
        /// |slip| above this is wheel spin or lock, outside the traction curve's fitted range.
        slip_max: Float = 0.95, Internal, "", [gt 0.0, le 1.0];
        /// Lower end of the K grid: below the weakest soil the traction constants were fitted on.
        k_min: Float = 5.0, Internal, "kPa/m^n", [gt 0.0];
        /// Upper end of the K grid: above it the traction curve no longer changes with K.
        k_max: Float = 5000.0, Internal, "kPa/m^n", [gt 0.0];
        /// Nodes of the K grid, evenly spaced in ln K from k_min to k_max: fine enough that
        /// the band's quantiles do not depend on it.
        grid_points: Int = 241.0, Internal, "", [ge 20.0, le 5000.0];
        /// Random walk of ln K: how fast the same soil's K may drift.
        q_log_k: Float = 0.1, Internal, "1/sqrt(s)", [ge 0.0];
        /// Hazard of an abrupt terrain change per metre travelled (0.5: a new soil every 2 m on
        /// average).  Raise it where the soil changes more often than that, lower it on uniform
        /// ground for a steadier K.
        change_per_metre: Float = 0.5, User, "1/m", [ge 0.0];
        /// Seconds of informative samples over which the evidence for a terrain change is weighed
        /// before K is reported from the changed belief (0: always the pooled belief's median).
        change_evidence: Float = 1.0, Internal, "s", [ge 0.0];
        /// Share of the change hazard at which the no-change belief forgets old evidence: without
        /// it the belief keeps the observer's early errors.
        stay_forgetting: Float = 0.5, Internal, "", [ge 0.0, le 1.0];
        /// 1-sigma error of the traction coefficient the model leaves unexplained.
        model_sigma: Float = 0.03, Internal, "", [gt 0.0];
        /// 1-sigma uncertainty of the filtered slip at speed.
        slip_sigma: Float = 0.005, Internal, "", [ge 0.0];
        /// 1-sigma error of the filtered speeds; slip's error grows as speed_sigma / speed at low
        /// speed.  Raise it for a noisy ground-speed sensor.
        speed_sigma: Float = 0.008, User, "m/s", [ge 0.0];
        /// A wheel informs K only while |slip| is at least this many times its slip uncertainty.
        slip_snr: Float = 3.0, Internal, "", [ge 0.0];
        /// Time constant of the low-pass slip the gate looks at: gating on the raw slip keeps the
        /// samples whose noise raised |slip| and biases K low.
        gate_smoothing: Float = 0.15, Internal, "s", [ge 0.0];
        /// Weight of the outlier component of the likelihood.
        outlier_prob: Float = 0.02, Internal, "", [ge 0.0, lt 1.0];
        /// Likelihood exponent of a sample temper_interval after the previous one: the observer's
        /// gross traction carries a per-wheel bias that samples do not average out.
        temper: Float = 0.15, Internal, "", [gt 0.0, le 1.0];
        /// The sample interval temper is stated for; a sample dt after the previous one weighs
        /// temper dt / temper_interval, up to temper_max.
        temper_interval: Float = 0.01, Internal, "s", [gt 0.0];
        /// Largest likelihood exponent of one sample: at low rates consecutive observer outputs
        /// are correlated, so a sample carries less than its interval's share.
        temper_max: Float = 0.3, Internal, "", [gt 0.0, le 1.0];
        /// ln K 1-sigma above which the record says uncertain: ok promises K within +-30 %, which
        /// holds where 2 x 0.13 = ln 1.30.  Lower it for a stricter ok.
        uncertain_log_sigma: Float = 0.13, User, "", [gt 0.0];
        /// Seconds without an informative update before the record says holding.  Raise it when
        /// the robot drives long stretches at steady speed and a held K is acceptable.
        hold_after: Float = 0.5, User, "s", [gt 0.0];
        /// Seconds of holding after which the estimate is withdrawn (no_estimate).
        expire_after: Float = 10.0, User, "s", [gt 0.0];
        /// Prior 1-sigma relative error of the gross traction common to all samples (torque
        /// constant, mass): it does not average out, so it enters K's band as a systematic term.
        /// Set it to the torque constant's relative uncertainty (lower after a calibration).
        gross_scale_sigma: Float = 0.05, User, "", [ge 0.0];
        /// 1-sigma relative error of the wheel radius (a systematic slip error).  Lower it once the
        /// rolling radius is measured.
        radius_sigma: Float = 0.01, User, "", [ge 0.0];
        /// No wheel informs K while the ground-speed reading has not changed for longer than this
        /// (a held reading is not a measurement).  Raise it for a ground-speed sensor known to
        /// refresh slowly.
        max_input_age: Float = 0.5, User, "s", [gt 0.0];
        /// A wheel informs K only while its normal force is at least this share of the static
        /// m g / 4: the torque balance hardly determines a nearly unloaded wheel's traction.
        min_load_fraction: Float = 0.25, Internal, "", [ge 0.0, lt 1.0];
        /// A wheel informs K only at samples whose speed and torque readings are both at most this
        /// old.  Raise it for wheel sensors that refresh more slowly than 20 Hz.
        fresh_age: Float = 0.05, User, "s", [ge 0.0];
        /// Memory of the mismatch and systematic-error statistics.
        evidence_window: Float = 3.0, Internal, "s", [gt 0.0];
        /// Mean normalised residual (NIS) of the used wheels above which the traction curve does not
        /// explain the (slip, traction) pairs: model_mismatch.
        mismatch_nis: Float = 4.0, Internal, "", [gt 0.0];
        /// The front-only and rear-only beliefs' disagreement in ln K, in its 1-sigma, above which
        /// (now and for most of evidence_window) the status is model_mismatch (0: no check).
        axle_mismatch_z: Float = 2.5, Internal, "", [ge 0.0];
        /// 1-sigma relative difference of gross traction between the axles that is ordinary model
        /// error (tyres, load transfer): it widens the disagreement the axle check tolerates.
        axle_scale_sigma: Float = 0.03, Internal, "", [ge 0.0];
        /// Seconds of informative samples in the window before a mismatch is judged.
        mismatch_min_evidence: Float = 1.0, Internal, "s", [gt 0.0];
        /// A wheel whose gross traction 1-sigma exceeds this cannot inform K (the torque balance
        /// does not determine it).
        observable_max_gross_sigma: Float = 0.4, Internal, "", [gt 0.0];
        /// lambda of eq. 36 (the paper method only).
        learning_rate: Float = 0.5, Internal, "", [gt 0.0, le 1.0];
        /// K_0 of the paper method.
        k_initial: Float = 120.0, Internal, "kPa/m^n", [gt 0.0];
        /// The ground speed the terrain-change hazard assumes when a caller gives none: a typical
        /// rover's.
        unknown_speed: Float = 1.0, Internal, "m/s", [gt 0.0];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn the_declarations_are_the_defaults_and_a_bad_value_is_named() {
        let d = Params::default();
        assert_eq!(Params::from_map(&HashMap::<String, f64>::new()).unwrap(), d);
        assert_eq!(Params::SPECS.len(), 35);
        assert_eq!(d.grid_points, 241.0);
        let m: HashMap<String, f64> = [("temper".to_string(), 1.5)].into();
        assert!(Params::from_map(&m)
            .unwrap_err()
            .contains("soil settings: temper = 1.5 must be <= 1"));
    }
}
