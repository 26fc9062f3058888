//! The online torque scale's settings, each declared once ([`Settings`], from which
//! `soilocp.estimation.torque_scale_config` builds `TorqueScaleConfig`), and what the kernel reads
//! ([`Params`]): the settings, their squares, and what the caller derives from other settings
//! (the priors, the default soil, eq. 1's floor and gravity, each from its one definition).

use crate::normal_force::STANDARD_GRAVITY;
use crate::settings::settings_struct;

settings_struct! {
    /// The online torque scale's settings (docs/method.md §10).
    pub struct Settings("torque_scale") {
        /// The force balance is taken over window means.
        window: Float = 1.0, Internal, "s", [gt 0.0];
        /// Windows with a slower sample are left out (static friction, stall).
        min_speed: Float = 0.2, Internal, "m/s", [gt 0.0];
        /// Windows turning faster are left out: a skid turn spends torque on scrubbing the wheels
        /// sideways.
        max_yaw_rate: Float = 0.1, Internal, "rad/s", [gt 0.0];
        /// A larger step between stamps restarts the window.
        max_gap: Float = 0.25, Internal, "s", [gt 0.0];
        /// A window whose mean |acceleration| (f_x less the pitch's gravity reaction) is below this
        /// informs nothing: at a steady speed the balance holds the resistance, not the torque's
        /// scale, and that resistance is not the one at the slips of accelerating or braking.  Low
        /// enough for a gentle swing (±30 % of 1 m/s every 6 s: 0.25-0.27 on 1-s windows), well
        /// above the noise of a 1-s mean of f_x.
        min_accel: Float = 0.2, Internal, "m/s^2", [gt 0.0];
        /// |slip| (eq. 1, from the readings) above which a window informs nothing: motion resistance
        /// grows with slip (eq. 4), and the slip grows with the acceleration that makes a window
        /// informative, so above this the resistance's change within the balance is read as torque
        /// (a skid steer's speed swings at slips 0.1-0.15 learn k a few per cent high, and K on a
        /// firm soil, where the curve is flat, moves many times that).
        max_slip: Float = 0.1, Internal, "", [gt 0.0];
        /// Random walk of k: how fast the torque scale may drift (temperature, battery).
        scale_walk: Float = 0.002, Internal, "1/sqrt(s)", [ge 0.0];
        /// Random walk of the motion resistance F_MR (its part b that does not grow with |a|): it
        /// ties the windows of a swing together, whose contrast of the two signs is what informs k.
        /// Slow enough that a gentle swing's windows, 2-3 s apart, share one b; fast enough that a
        /// resistance that grows with the speed (a draft on a start from rest) is taken as a jump
        /// rather than read as k.
        resistance_walk: Float = 0.7, Internal, "N/sqrt(s)", [ge 0.0];
        /// Prior 1-sigma of F_MR (prior mean 0).
        resistance_sigma: Float = 60.0, Internal, "N", [gt 0.0];
        /// Prior 1-sigma (mean 0) of c, the growth of the motion resistance with the window's mean
        /// |acceleration|: the balance's F_MR is b + c |a|.  Eq. 4's resistance grows with |slip|,
        /// and accelerating and braking alike take slip, so windows at different |a| hold
        /// different resistances; one b for all of them reads the difference as k (a start ramp
        /// against a gentle swing's brake).  c is even in a, k x odd: the contrast of the two
        /// signs still fits k.  0: one b at every |a|.
        resistance_slope_sigma: Float = 20.0, Internal, "N s^2/m", [ge 0.0];
        /// 1-sigma of a window's force balance once F_MR's changes are the random walk's and
        /// resistance_jump's.
        force_sigma: Float = 1.0, Internal, "N", [gt 0.0];
        /// A window whose innovation is beyond this many of its own sigmas is a jump of F_MR (the
        /// soil changed, a draft was hooked on), not a change of k: F_MR's variance returns to
        /// resistance_sigma and the window informs F_MR alone (0: never).
        resistance_jump: Float = 3.0, Internal, "", [ge 0.0];
    }
}

/// What the kernel reads: the settings, their variances squared once, and the numbers the caller
/// derives from other settings.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// the settings (window, speed, yaw-rate, gap, acceleration and slip limits are read here)
    pub s: Settings,
    /// scale_walk^2: k's random walk, 1/s
    pub scale_walk_var: f64,
    /// resistance_walk^2: F_MR's random walk, N^2/s
    pub resistance_walk_var: f64,
    /// force_sigma^2: one window's balance, N^2
    pub force_var: f64,
    /// resistance_sigma^2: F_MR's prior, N^2
    pub resistance_var: f64,
    /// resistance_slope_sigma^2: the prior of F_MR's growth with |a|, (N s^2/m)^2
    pub slope_var: f64,
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
    /// eq. 1's floor of the denominator, m/s (the pipeline's slip_floor, docs/method.md §10)
    pub slip_floor: f64,
    /// m/s^2: gravity in the balance's slope term (the observer's gravity)
    pub gravity: f64,
    /// subtract eq. 4's motion resistance from the balance
    pub model_resistance: bool,
}

/// The numbers the caller derives from settings other than [`Settings`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Derived {
    /// k's prior 1-sigma of the state
    pub state_sigma: f64,
    /// the torque constant's prior 1-sigma (soil.gross_scale_sigma)
    pub prior_sigma: f64,
    /// the soil's K for eq. 4 until the soil stage reports one
    pub k_default: f64,
    /// eq. 1's floor of the denominator, m/s
    pub slip_floor: f64,
    /// m/s^2
    pub gravity: f64,
    /// subtract eq. 4's motion resistance from the balance
    pub model_resistance: bool,
}

impl Derived {
    /// The defaults: the state's prior 0.10, the torque constant's 0.05, the median reference soil
    /// (K 120), eq. 1's floor 0.05 m/s, standard gravity, no modelled resistance.
    pub const DEFAULT: Derived = Derived {
        state_sigma: 0.10,
        prior_sigma: 0.05,
        k_default: 120.0,
        slip_floor: 0.05,
        gravity: STANDARD_GRAVITY,
        model_resistance: false,
    };
}

impl Params {
    /// The kernel's numbers from the settings `s` and the derived numbers `d`, which must be
    /// finite and > 0; the error names the one that is not.
    pub fn new(s: &Settings, d: Derived) -> Result<Params, String> {
        for (name, v) in [
            ("state_sigma", d.state_sigma),
            ("prior_sigma", d.prior_sigma),
            ("k_default", d.k_default),
            ("slip_floor", d.slip_floor),
            ("gravity", d.gravity),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("torque scale: {name} = {v} must be finite and > 0"));
            }
        }
        Ok(Params {
            s: *s,
            scale_walk_var: s.scale_walk * s.scale_walk,
            resistance_walk_var: s.resistance_walk * s.resistance_walk,
            force_var: s.force_sigma * s.force_sigma,
            resistance_var: s.resistance_sigma * s.resistance_sigma,
            slope_var: s.resistance_slope_sigma * s.resistance_slope_sigma,
            jump_var: s.resistance_jump * s.resistance_jump,
            state_sigma: d.state_sigma,
            state_var: d.state_sigma * d.state_sigma,
            prior_sigma: d.prior_sigma,
            prior_var: d.prior_sigma * d.prior_sigma,
            k_default: d.k_default,
            slip_floor: d.slip_floor,
            gravity: d.gravity,
            model_resistance: d.model_resistance,
        })
    }

    /// The default settings with [`Derived::DEFAULT`] (for the Rust tests).
    pub fn defaults() -> Params {
        Params::new(&Settings::default(), Derived::DEFAULT).expect("the defaults are valid")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn settings_are_checked_by_name_and_derived_numbers_too() {
        let m: HashMap<String, f64> = [("window".to_string(), 0.0)].into();
        assert!(Settings::from_map(&m).unwrap_err().contains("window = 0 must be > 0"));
        let m: HashMap<String, f64> = [("scale_walk".to_string(), 0.0)].into();
        assert!(Settings::from_map(&m).is_ok());
        let m: HashMap<String, f64> = [("bogus".to_string(), 1.0)].into();
        assert!(Settings::from_map(&m).unwrap_err().contains("bogus"));
        let bad = Derived {
            k_default: f64::NAN,
            ..Derived::DEFAULT
        };
        assert!(Params::new(&Settings::default(), bad)
            .unwrap_err()
            .contains("k_default"));
        let p = Params::defaults();
        assert_eq!(
            (p.jump_var, p.state_var, p.gravity),
            (9.0, 0.10 * 0.10, STANDARD_GRAVITY)
        );
    }
}
