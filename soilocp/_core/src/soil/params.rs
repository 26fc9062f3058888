//! The settings of the soil update: the numbers of `soilocp.estimation.soil_config.SoilConfig`
//! (which stays the validated, documented configuration) that the per-sample update reads.

use std::collections::HashMap;

/// SoilConfig's per-sample numbers (their meaning: soil_config.py's field descriptions).
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    pub slip_min: f64,
    pub slip_max: f64,
    pub slip_snr: f64,
    pub observable_max_gross_sigma: f64,
    pub q_log_k: f64,
    pub change_per_metre: f64,
    pub change_evidence: f64,
    pub stay_forgetting: f64,
    pub model_sigma: f64,
    pub outlier_prob: f64,
    pub temper: f64,
    pub temper_interval: f64,
    pub temper_max: f64,
    pub evidence_window: f64,
    pub gross_scale_sigma: f64,
    pub hold_after: f64,
    pub axle_mismatch_z: f64,
    pub axle_scale_sigma: f64,
    pub mismatch_min_evidence: f64,
    /// m/s: the ground speed assumed where none is given (the change hazard's distance)
    pub unknown_speed: f64,
}

impl Params {
    /// The field names, in the order of the struct (the Python side passes a dict of them).
    pub const NAMES: [&'static str; 20] = [
        "slip_min",
        "slip_max",
        "slip_snr",
        "observable_max_gross_sigma",
        "q_log_k",
        "change_per_metre",
        "change_evidence",
        "stay_forgetting",
        "model_sigma",
        "outlier_prob",
        "temper",
        "temper_interval",
        "temper_max",
        "evidence_window",
        "gross_scale_sigma",
        "hold_after",
        "axle_mismatch_z",
        "axle_scale_sigma",
        "mismatch_min_evidence",
        "unknown_speed",
    ];

    /// From a name -> value map with exactly the names of [`Params::NAMES`]; the error names
    /// the missing or unknown field.
    pub fn from_map(m: &HashMap<String, f64>) -> Result<Params, String> {
        for k in m.keys() {
            if !Self::NAMES.contains(&k.as_str()) {
                return Err(format!("soil params: unknown field {k:?}"));
            }
        }
        let get = |name: &str| -> Result<f64, String> {
            let v = *m
                .get(name)
                .ok_or_else(|| format!("soil params: missing field {name:?}"))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("soil params: {name} = {v} must be finite"))
            }
        };
        Ok(Params {
            slip_min: get("slip_min")?,
            slip_max: get("slip_max")?,
            slip_snr: get("slip_snr")?,
            observable_max_gross_sigma: get("observable_max_gross_sigma")?,
            q_log_k: get("q_log_k")?,
            change_per_metre: get("change_per_metre")?,
            change_evidence: get("change_evidence")?,
            stay_forgetting: get("stay_forgetting")?,
            model_sigma: get("model_sigma")?,
            outlier_prob: get("outlier_prob")?,
            temper: get("temper")?,
            temper_interval: get("temper_interval")?,
            temper_max: get("temper_max")?,
            evidence_window: get("evidence_window")?,
            gross_scale_sigma: get("gross_scale_sigma")?,
            hold_after: get("hold_after")?,
            axle_mismatch_z: get("axle_mismatch_z")?,
            axle_scale_sigma: get("axle_scale_sigma")?,
            mismatch_min_evidence: get("mismatch_min_evidence")?,
            unknown_speed: get("unknown_speed")?,
        })
    }

    /// SoilConfig's defaults (for the Rust tests).
    pub fn defaults() -> Params {
        Params {
            slip_min: 0.04,
            slip_max: 0.95,
            slip_snr: 3.0,
            observable_max_gross_sigma: 0.4,
            q_log_k: 0.1,
            change_per_metre: 0.5,
            change_evidence: 1.0,
            stay_forgetting: 0.5,
            model_sigma: 0.03,
            outlier_prob: 0.02,
            temper: 0.15,
            temper_interval: 0.01,
            temper_max: 0.3,
            evidence_window: 3.0,
            gross_scale_sigma: 0.05,
            hold_after: 0.5,
            axle_mismatch_z: 2.5,
            axle_scale_sigma: 0.03,
            mismatch_min_evidence: 1.0,
            unknown_speed: 1.0,
        }
    }
}
