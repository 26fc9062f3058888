//! The settings of the online torque scale: the numbers of
//! `soilocp.estimation.torque_scale.TorqueScaleConfig` (which stays the validated, documented
//! configuration; their meaning is in its field descriptions) that the per-sample kernel reads,
//! and the priors the Python side derives from it and from `SoilConfig.gross_scale_sigma`.

use std::collections::HashMap;

/// TorqueScaleConfig's per-sample numbers.  The squares are passed as Python computed them
/// (`x**2`, libm's pow), so that the state's variances are those of the numpy kernel it replaced
/// (tests/reference_torque_scale.py) to the bit.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// s: the force balance is taken over window means
    pub window: f64,
    /// m/s: a window with a slower sample informs nothing
    pub min_speed: f64,
    /// rad/s: nor one turning faster
    pub max_yaw_rate: f64,
    /// s: a larger step between stamps restarts the window
    pub max_gap: f64,
    /// m/s^2: the window's mean acceleration that informs k
    pub min_accel: f64,
    /// |slip| (eq. 1, from the readings) above which a window informs nothing
    pub max_slip: f64,
    /// scale_walk^2: k's random walk, 1/s
    pub scale_walk_var: f64,
    /// resistance_walk^2: F_MR's random walk, N^2/s
    pub resistance_walk_var: f64,
    /// force_sigma^2: one window's balance, N^2
    pub force_var: f64,
    /// resistance_sigma^2: F_MR's prior, N^2
    pub resistance_var: f64,
    /// resistance_jump^2: a window whose squared innovation exceeds this many times its
    /// variance is a jump of F_MR (0: never), which informs F_MR alone
    pub jump_var: f64,
    /// k's prior 1-sigma of the state, and its square
    pub state_sigma: f64,
    pub state_var: f64,
    /// the torque constant's prior 1-sigma (soil.gross_scale_sigma), and its square
    pub prior_sigma: f64,
    pub prior_var: f64,
    /// the soil's K for eq. 4 until the soil stage reports one (the median reference soil)
    pub k_default: f64,
    /// eq. 1's floor of the denominator, m/s (docs/method.md §10)
    pub slip_floor: f64,
    /// subtract eq. 4's motion resistance from the balance (1) or not (0)
    pub model_resistance: bool,
}

impl Params {
    /// The field names the Python side passes (a dict of them, `model_resistance` as 0 or 1).
    pub const NAMES: [&'static str; 18] = [
        "window",
        "min_speed",
        "max_yaw_rate",
        "max_gap",
        "min_accel",
        "max_slip",
        "scale_walk_var",
        "resistance_walk_var",
        "force_var",
        "resistance_var",
        "jump_var",
        "state_sigma",
        "state_var",
        "prior_sigma",
        "prior_var",
        "k_default",
        "slip_floor",
        "model_resistance",
    ];

    /// From a name -> value map with exactly the names of [`Params::NAMES`], every value finite,
    /// the lengths, bounds, sigmas and K > 0 and the walks >= 0; the error names the field.
    pub fn from_map(m: &HashMap<String, f64>) -> Result<Params, String> {
        for k in m.keys() {
            if !Self::NAMES.contains(&k.as_str()) {
                return Err(format!("torque scale params: unknown field {k:?}"));
            }
        }
        let get = |name: &str, zero_ok: bool| -> Result<f64, String> {
            let v = *m
                .get(name)
                .ok_or_else(|| format!("torque scale params: missing field {name:?}"))?;
            if v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0)) {
                Ok(v)
            } else {
                let need = if zero_ok { ">= 0" } else { "> 0" };
                Err(format!("torque scale params: {name} = {v} must be finite and {need}"))
            }
        };
        let model = get("model_resistance", true)?;
        if model != 0.0 && model != 1.0 {
            return Err(format!(
                "torque scale params: model_resistance = {model} must be 0 or 1"
            ));
        }
        Ok(Params {
            window: get("window", false)?,
            min_speed: get("min_speed", false)?,
            max_yaw_rate: get("max_yaw_rate", false)?,
            max_gap: get("max_gap", false)?,
            min_accel: get("min_accel", false)?,
            max_slip: get("max_slip", false)?,
            scale_walk_var: get("scale_walk_var", true)?,
            resistance_walk_var: get("resistance_walk_var", true)?,
            force_var: get("force_var", false)?,
            resistance_var: get("resistance_var", false)?,
            jump_var: get("jump_var", true)?,
            state_sigma: get("state_sigma", false)?,
            state_var: get("state_var", false)?,
            prior_sigma: get("prior_sigma", false)?,
            prior_var: get("prior_var", false)?,
            k_default: get("k_default", false)?,
            slip_floor: get("slip_floor", false)?,
            model_resistance: model == 1.0,
        })
    }

    /// TorqueScaleConfig's defaults with the torque constant's prior 0.05 and the median reference
    /// soil (K 120) for the Rust tests.
    pub fn defaults() -> Params {
        Params {
            window: 1.0,
            min_speed: 0.2,
            max_yaw_rate: 0.1,
            max_gap: 0.25,
            min_accel: 0.35,
            max_slip: 0.15,
            scale_walk_var: 0.002 * 0.002,
            resistance_walk_var: 2.0 * 2.0,
            force_var: 1.0 * 1.0,
            resistance_var: 60.0 * 60.0,
            jump_var: 3.0 * 3.0,
            state_sigma: 0.10,
            state_var: 0.10 * 0.10,
            prior_sigma: 0.05,
            prior_var: 0.05 * 0.05,
            k_default: 120.0,
            slip_floor: 0.05,
            model_resistance: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(p: &Params) -> HashMap<String, f64> {
        let v = [
            p.window,
            p.min_speed,
            p.max_yaw_rate,
            p.max_gap,
            p.min_accel,
            p.max_slip,
            p.scale_walk_var,
            p.resistance_walk_var,
            p.force_var,
            p.resistance_var,
            p.jump_var,
            p.state_sigma,
            p.state_var,
            p.prior_sigma,
            p.prior_var,
            p.k_default,
            p.slip_floor,
            if p.model_resistance { 1.0 } else { 0.0 },
        ];
        Params::NAMES.iter().map(|s| s.to_string()).zip(v).collect()
    }

    #[test]
    fn a_map_round_trips_and_bad_fields_are_named() {
        let p = Params::defaults();
        assert_eq!(Params::from_map(&map(&p)).unwrap(), p);
        let mut m = map(&p);
        m.insert("window".into(), 0.0);
        assert!(Params::from_map(&m).unwrap_err().contains("window"));
        let mut m = map(&p);
        m.insert("scale_walk_var".into(), 0.0);
        assert!(Params::from_map(&m).is_ok());
        m.insert("bogus".into(), 1.0);
        assert!(Params::from_map(&m).unwrap_err().contains("bogus"));
        let mut m = map(&p);
        m.remove("k_default");
        assert!(Params::from_map(&m).unwrap_err().contains("k_default"));
        let mut m = map(&p);
        m.insert("model_resistance".into(), 0.5);
        assert!(Params::from_map(&m).unwrap_err().contains("model_resistance"));
    }
}
