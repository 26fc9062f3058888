//! The traction observer's settings, each declared once ([`ObserverSettings`], from which
//! `soilocp.estimation.observer_config` builds `ObserverConfig`), and what the filter, the readings
//! clock and the refresh pairs take from them for a layout and a vehicle's drive.

use super::layout::Layout;
use crate::normal_force::STANDARD_GRAVITY;
use crate::settings::settings_struct;

settings_struct! {
    /// Noise, prior, structure and bounds of the traction observer (paper eqs. 26-35,
    /// docs/method.md §7, §11-13, §17).
    pub struct ObserverSettings("observer") {
        /// How motion resistance enters the state: "slip" (eq. 4's form: a constant part and a
        /// slope in |slip| shared by the wheels), "shared" (one constant coefficient), "per_wheel"
        /// (the paper's eq. 26, determined only by its prior) or "none" (no compensation: each
        /// wheel's traction absorbs its resistance). Keep "slip" unless comparing with the paper.
        structure: Choice = "slip", User, "", [one_of "slip", one_of "shared", one_of "per_wheel", one_of "none"];
        /// Discretisation of the continuous model: "series" (exact, A is nilpotent), which the
        /// kernel runs; "expm" is the tests' reference's cross-check.
        discretization: Choice = "series", Internal, "", [one_of "series", one_of "expm"];
        /// Random-walk intensity of each wheel's net traction coefficient mu_i: a slip sweep moves
        /// mu by about 1 per second.
        q_mu: Float = 1.0, Internal, "1/sqrt(s)", [gt 0.0];
        /// Random-walk intensity of the motion-resistance coefficient (its constant part): soil
        /// changes slower than traction. Slowed while the slips spread widely
        /// (`resistance_walk_spread`).
        q_resistance: Float = 0.1, Internal, "1/sqrt(s)", [gt 0.0];
        /// Random-walk intensity of the resistance's slope in |slip| ("slip" structure). Slowed
        /// with the constant part's (`resistance_walk_spread`).
        q_resistance_slope: Float = 0.1, Internal, "1/sqrt(s)", [gt 0.0];
        /// Where the wheels' load-weighted mean |slip| spreads (its standard deviation sigma over
        /// `resistance_walk_window`) beyond this, the data tell the resistance's constant part from
        /// its slope, and both random walks (`q_resistance`, `q_resistance_slope`) slow: their
        /// intensities are multiplied by min(1, (resistance_walk_spread / sigma)^2) ("slip"
        /// structure, docs/method.md §12). A walk fast enough to follow a soil change would
        /// otherwise take part of a wide sweep's swing as a change of the constant part, read the
        /// slope low and place a flat traction peak late; a drive whose slips stay within a narrow
        /// band (a narrow sweep, a skid steer's short traction test) keeps the full walk. Lower it
        /// (to 0.05) where the OCPs on another tyre matter more than how fast K follows a change of
        /// soil during wide sweeps; raise it for the opposite; 0 keeps the full walk.
        resistance_walk_spread: Float = 0.1, Internal, "", [ge 0.0];
        /// Memory of the slip spread that slows the resistance's walks (`resistance_walk_spread`):
        /// about one traction sweep's cycle.
        resistance_walk_window: Float = 3.0, Internal, "s", [gt 0.0];
        /// Initial 1-sigma of the resistance's slope in |slip| ("slip" structure).
        p0_resistance_slope: Float = 0.5, Internal, "", [gt 0.0];
        /// Random-walk intensity of the lateral resistance coefficient mu_yR.
        q_lateral: Float = 0.3, Internal, "1/sqrt(s)", [gt 0.0];
        /// Unmodelled wheel acceleration (torque ripple) as process noise of the wheel speeds.
        q_wheel_speed: Float = 0.3, Internal, "rad/s^2/sqrt(Hz)", [gt 0.0];
        /// Unmodelled acceleration of the centre of mass as process noise of the ground speed.
        q_ground_speed: Float = 0.1, Internal, "m/s^2/sqrt(Hz)", [gt 0.0];
        /// Random walk of the speed equation's bias (accelerometer bias, pitch error times g).
        q_speed_bias: Float = 0.005, Internal, "m/s^2/sqrt(s)", [gt 0.0];
        /// Initial 1-sigma of the speed equation's bias.
        p0_speed_bias: Float = 0.05, Internal, "m/s^2", [gt 0.0];
        /// Unmodelled yaw acceleration as process noise of the yaw rate.
        q_yaw_rate: Float = 0.2, Internal, "rad/s^2/sqrt(Hz)", [gt 0.0];
        /// 1-sigma noise of the accelerometer's longitudinal specific force f_x, vibration
        /// included. Raise it for a stiff chassis on rough ground (the filter then trusts the
        /// wheel and speed equations more); lower it for an isolated, filtered IMU.
        r_specific_force: Float = 0.08, User, "m/s^2", [gt 0.0];
        /// 1-sigma noise of the gyro's yaw rate. Set it from the IMU's data sheet (rate noise
        /// density times the square root of its bandwidth) or its standstill spread.
        r_yaw_rate: Float = 0.01, User, "rad/s", [gt 0.0];
        /// 1-sigma noise of an encoder's wheel speed, quantisation included (doubled in variance
        /// where one encoder reads a side). Raise it for a coarse encoder (its speed step at the
        /// sample rate) or a noisy speed estimate from the motor driver.
        r_wheel_speed: Float = 0.03, User, "rad/s", [gt 0.0];
        /// 1-sigma noise of the ground speed (GNSS, visual odometry). Set it from the source's
        /// standstill spread; raise it for odometry that slips with the wheels.
        r_ground_speed: Float = 0.02, User, "m/s", [gt 0.0];
        /// Initial 1-sigma of each wheel's net traction coefficient mu_i.
        p0_mu: Float = 0.5, Internal, "", [gt 0.0];
        /// Initial 1-sigma of the motion-resistance coefficient (its constant part).
        p0_resistance: Float = 0.2, Internal, "", [gt 0.0];
        /// Initial 1-sigma of the lateral resistance coefficient mu_yR.
        p0_lateral: Float = 0.5, Internal, "", [gt 0.0];
        /// Initial 1-sigma of the ground-speed state (the wheel speeds and the yaw rate start
        /// from their sensors' noise).
        p0_speed: Float = 0.1, Internal, "m/s", [gt 0.0];
        /// A measurement row whose innovation exceeds this many sigma is rejected (a glitch, not
        /// the robot's motion).
        gate_sigma: Float = 5.0, Internal, "", [gt 0.0];
        /// After this many consecutive rejections a row is accepted again: the model, not the
        /// sensor, is off.
        gate_patience: Int = 10.0, Internal, "", [ge 1.0];
        /// A step between samples longer than this restarts the filter from the readings (what
        /// happened in the gap is unknown). Raise it for a log recorded at a low or irregular
        /// rate; it must exceed the longest normal sample interval.
        max_gap: Float = 0.5, User, "s", [gt 0.0];
        /// Below this rim and ground speed, a wheel-speed reading the gate rejects re-anchors that
        /// wheel's speed state to it: at a stall under torque the wheel equation is stiff, and a
        /// wrong traction state drives the filtered speed off the encoder's (0: off).
        anchor_speed: Float = 0.3, Internal, "m/s", [ge 0.0];
        /// A reading stream whose value changes come at consecutive samples more often than this
        /// share is read at the sample rate: a repeated value is a new, quantised reading of the
        /// same value, not a held one.
        full_rate_share: Float = 0.5, Internal, "", [gt 0.0, lt 1.0];
        /// The longest a full-rate stream's unchanged value still counts as a new reading (a
        /// frozen driver repeats forever).
        repeat_window: Float = 0.5, Internal, "s", [ge 0.0];
        /// The longest ground-speed latency the observer measures against the accelerometer and
        /// leads the reading by (0: none). Raise it for a ground-speed source known to lag more
        /// (a visual odometry pipeline); 0 when the source is stamped at its measurement.
        ground_speed_latency_max: Float = 0.3, User, "s", [ge 0.0];
        /// Memory of the ground-speed latency fit.
        latency_window: Float = 30.0, Internal, "s", [gt 0.0];
        /// The wheel's unmeasured jerk between a slow wheel-speed stream's refreshes, which sets
        /// the variance of the interval's gross traction taken from the readings.
        refresh_jerk: Float = 50.0, Internal, "rad/s^3", [gt 0.0];
        /// A wheel-speed stream held at least this long between its readings refreshes slowly,
        /// and its intervals' gross traction is taken from the readings (a quantised encoder's
        /// few repeats are not).
        refresh_min_interval: Float = 0.1, Internal, "s", [gt 0.0];
        /// The longest refresh interval of a slow wheel-speed stream whose gross traction is taken
        /// from the readings (a longer one says little of the speed's course between them).
        refresh_max_interval: Float = 1.0, Internal, "s", [gt 0.0];
        /// Smallest variance a state keeps after each step (in its unit squared): the covariance
        /// stays positive definite.
        variance_floor: Float = 1e-10, Internal, "", [gt 0.0];
        /// Largest variance a state keeps after each step (in its unit squared).
        variance_ceiling: Float = 1e4, Internal, "", [gt 0.0];
        /// Gravity: the speed equation's slope term g sin(pitch) and the static wheel load m g / 4.
        /// Change it only off Earth's standard gravity (another planet, a test rig).
        gravity: Float = STANDARD_GRAVITY, User, "m/s^2", [gt 0.0];
        /// |mu_i| (net traction coefficient) is kept within this: no soil gives more.
        mu_bound: Float = 1.5, Internal, "", [gt 0.0];
        /// |motion-resistance coefficient| (its constant part) is kept within this.
        resistance_bound: Float = 1.0, Internal, "", [gt 0.0];
        /// |resistance slope in |slip|| is kept within this.
        resistance_slope_bound: Float = 5.0, Internal, "", [gt 0.0];
        /// |mu_yR| is kept within this.
        lateral_bound: Float = 2.0, Internal, "", [gt 0.0];
        /// |speed equation's bias| is kept within this.
        speed_bias_bound: Float = 3.0, Internal, "m/s^2", [gt 0.0];
        /// mu_i counts as determined by the data while its posterior 1-sigma is within this.
        mu_std_determined: Float = 0.15, Internal, "", [gt 0.0];
        /// Speed over which a wheel's travel direction is smoothed (the resistance's sign at rest).
        travel_speed: Float = 0.05, Internal, "m/s", [gt 0.0];
        /// A filtered wheel speed above this is divergence: the filter restarts.
        max_wheel_speed: Float = 1000.0, Internal, "rad/s", [gt 0.0];
        /// A filtered ground speed above this is divergence: the filter restarts.
        max_ground_speed: Float = 100.0, Internal, "m/s", [gt 0.0];
    }
}

impl ObserverSettings {
    /// The state layout of `structure`.
    pub fn layout(&self) -> Layout {
        Layout::of(self.structure).expect("structure is one of its declared choices")
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    #[test]
    fn defaults_and_an_empty_map_agree() {
        let s = ObserverSettings::default();
        assert_eq!(
            (s.structure, s.discretization, s.gate_patience),
            ("slip", "series", 10.0)
        );
        assert_eq!(ObserverSettings::from_map(&HashMap::<String, f64>::new()).unwrap(), s);
        assert_eq!(s.layout().n_res, 2);
    }
}
