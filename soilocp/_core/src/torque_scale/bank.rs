//! The torque scales of N vehicles (docs/method.md §15): per vehicle the open window
//! ([`Window`]), the (k, b) posterior ([`ScaleState`]) and the soil stage's last K and slips for
//! eq. 4's modelled resistance.  One call per vehicle-sample: [`TorqueScaleBank::step`].
//!
//! A window informs the state where eq. TC holds with a slow F_MR: moving at >= `min_speed`,
//! straight (|yaw rate| <= `max_yaw_rate`), every wheel's slip (eq. 1 from the readings) within
//! `max_slip`, all finite.  Only a window whose mean acceleration (f_x less the gravity reaction of
//! the pitch, eq. 20) reaches `min_accel` informs the state; any other informs nothing.

use crate::constants::Constants;
use crate::normal_force::gravity_from_attitude;
use crate::observer::numeric::nan_max;
use crate::observer::vehicles::Raw;
use crate::slip;
use crate::torque_scale::balance::{longitudinal_balance_split, modelled_resistance, Body};
use crate::torque_scale::kalman::ScaleState;
use crate::torque_scale::params::Params;
use crate::torque_scale::window::{Terms, Window};

/// The torque scales of N vehicles.
#[derive(Clone, Debug)]
pub struct TorqueScaleBank {
    params: Params,
    body: Body,
    constants: Constants,
    state: Vec<ScaleState>,
    window: Vec<Window>,
    /// the soil's K for eq. 4: the soil stage's last report, until then `params.k_default`
    soil_k: Vec<f64>,
    /// the soil stage's slip per wheel (eq. 1 on the observer's filtered speeds); NaN: none yet,
    /// the readings' slip is used
    soil_slip: Vec<[f64; 4]>,
    /// the state before the last fitted window, that window's span and its last stamp (NaN: none)
    before_last: Vec<ScaleState>,
    last_span: Vec<f64>,
    last_end: Vec<f64>,
}

impl TorqueScaleBank {
    /// N vehicles at the prior.  `Err` if N is 0.
    pub fn new(params: Params, body: Body, constants: Constants, n_vehicles: usize) -> Result<Self, String> {
        if n_vehicles == 0 {
            return Err("n_vehicles must be >= 1".into());
        }
        Ok(TorqueScaleBank {
            state: vec![ScaleState::prior(&params); n_vehicles],
            window: vec![Window::default(); n_vehicles],
            soil_k: vec![params.k_default; n_vehicles],
            soil_slip: vec![[f64::NAN; 4]; n_vehicles],
            before_last: vec![ScaleState::prior(&params); n_vehicles],
            last_span: vec![f64::NAN; n_vehicles],
            last_end: vec![f64::NAN; n_vehicles],
            params,
            body,
            constants,
        })
    }

    pub fn len(&self) -> usize {
        self.state.len()
    }

    pub fn is_empty(&self) -> bool {
        self.state.is_empty()
    }

    pub fn params(&self) -> &Params {
        &self.params
    }

    pub fn state(&self, i: usize) -> &ScaleState {
        &self.state[i]
    }

    pub fn soil_k(&self, i: usize) -> f64 {
        self.soil_k[i]
    }

    /// k's posterior mean and 1-sigma of vehicle i.
    pub fn scale(&self, i: usize) -> (f64, f64) {
        self.state[i].scale()
    }

    /// The soil stage's K (ignored unless finite and > 0: the last is kept) and its slips per wheel
    /// (NaN: none, the readings' slip is used) for vehicle i: the next samples' modelled resistance
    /// uses them.
    pub fn feed_soil(&mut self, i: usize, k: f64, slip: [f64; 4]) {
        if k.is_finite() && k > 0.0 {
            self.soil_k[i] = k;
        }
        self.soil_slip[i] = slip;
    }

    /// Add vehicle i's sample as logged (the observer's input: its torques before the scale; NaN
    /// ground speed: none, the rims' mean is used) by eq. 1 with the §10 floor for the window's slip
    /// test, eq. 20's gravity reaction and eq. 4's resistance where modelled, close its window if full
    /// and update its state by eq. TC (docs/method.md §15).  Returns k's mean and 1-sigma after this
    /// sample.
    pub fn step(&mut self, i: usize, s: &Raw) -> (f64, f64) {
        let (p, r) = (&self.params, self.body.wheel_radius);
        let w_sum: f64 = s.wheel_speed.iter().sum();
        let t_sum: f64 = s.wheel_torque.iter().sum();
        let g_x = gravity_from_attitude(0.0, s.pitch, p.gravity)[0];
        let speed = if s.ground_speed.is_nan() {
            w_sum / 4.0 * r
        } else {
            s.ground_speed
        };
        let slips: [f64; 4] = std::array::from_fn(|j| slip::slip(s.wheel_speed[j] * r, speed, p.slip_floor));
        let f_mr = if p.model_resistance {
            // eq. 4 is even in S: the body-frame slip's magnitude is the travel frame's
            let fed = &self.soil_slip[i];
            let at: [f64; 4] = std::array::from_fn(|j| {
                let sj = if fed[j].is_finite() { fed[j] } else { slips[j] };
                if sj.is_finite() {
                    sj
                } else {
                    0.0
                }
            });
            let direction = if speed < 0.0 { -1.0 } else { 1.0 };
            modelled_resistance(&at, self.soil_k[i], &s.normal_force, direction, &self.constants)
        } else {
            0.0
        };
        let cur: Terms = [s.specific_force_x, g_x, t_sum, f_mr];
        let straight = s.yaw_rate.abs() <= p.s.max_yaw_rate; // false for NaN
        let unusable = !cur.iter().all(|v| v.is_finite())
            || !w_sum.is_finite()
            || speed.abs() < p.s.min_speed
            || !straight
            || !slips.iter().all(|v| v.abs() <= p.s.max_slip);
        if let Some(c) = self.window[i].add(s.stamp, &cur, w_sum, unusable, p) {
            if c.usable {
                let alpha = self.inertia_scale(i);
                let (x, y) = longitudinal_balance_split(
                    c.means[0],
                    c.omega_dot_sum,
                    c.means[2],
                    Some(c.means[3]),
                    alpha,
                    &self.body,
                );
                let before = self.state[i];
                let accel = c.means[0] - c.means[1];
                // a jump whose window adjoins the previous fitted one takes that one back (ScaleState::jump_after);
                // x and y keep the inertia factor of the shadow k that the taken-back window had moved (as the reference)
                if self.state[i].update(c.span, x, y, accel, p) && c.start == self.last_end[i] {
                    let mut st = self.before_last[i];
                    st.jump_after(self.last_span[i] + c.span, x, y, accel, p);
                    self.state[i] = st;
                }
                self.before_last[i] = before;
                self.last_span[i] = c.span;
                self.last_end[i] = s.stamp;
            } else {
                self.last_end[i] = f64::NAN;
            }
        }
        self.scale(i)
    }

    /// 1 / rho, the payload's share of the scale that eq. TC's wheel-inertia term carries
    /// ([`longitudinal_balance_split`]): k = c / rho is learnt whole, and which of the torque
    /// constant c and the mass ratio rho made it is not in the balance (f_x and the wheels' omega_dot
    /// move together).  Their priors split it: ln c ~ N(0, prior_sigma^2) (the torque constant's)
    /// and ln rho with the rest of k's prior variance, state_var - prior_var, so that
    /// E[ln(1 / rho) | ln k] = w ln k with w = 1 - prior_var / state_var, at k's estimate from
    /// every accelerating window before this one (the shadow's; the state's, which waits for both
    /// signs, read payload+25-accel-brake's K 11.2 % off for 8.7 %, seed 0).  w = 0 where k's prior
    /// is the torque constant's alone (the balance as the offline fit reads it).  docs/method.md §15.
    pub fn inertia_scale(&self, i: usize) -> f64 {
        let p = &self.params;
        let w = if p.state_var > p.prior_var {
            1.0 - p.prior_var / p.state_var
        } else {
            0.0
        };
        let k = self.state[i].shadow_theta[0];
        if w == 0.0 || !(k.is_finite() && k > 0.0) {
            return 1.0;
        }
        k.powf(w)
    }

    /// k's 1-sigma for K's band from its posterior 1-sigma `sd`: the windows' information about k
    /// (the state's posterior precision less its prior's, `state_sigma`) combined with the torque
    /// constant's prior `prior_sigma`.  With `state_sigma` = `prior_sigma` this is `sd` itself.  A
    /// wider state prior lets the balance move k as far as the data say (a payload the vehicle file
    /// does not know: 0.80), while a start ramp's one window, which hardly informs k, leaves K's
    /// band at the torque constant's prior instead of widening it to the state's.
    pub fn band_sigma(&self, sd: f64) -> f64 {
        let p = &self.params;
        if p.state_sigma == p.prior_sigma {
            return sd;
        }
        let m = nan_max(sd, 1e-12);
        let info = nan_max(1.0 / (m * m) - 1.0 / p.state_var, 0.0);
        1.0 / (1.0 / p.prior_var + info).sqrt()
    }

    /// What the observer and the soil update take from a step's (mean, 1-sigma) of k, one pair per
    /// vehicle stepped: the factor of each vehicle's logged torques (k's mean) and k's relative
    /// 1-sigma for K's band; None while every one is exactly its prior (never learnt: the torques and
    /// the soil's scale prior stay as configured).
    pub fn scaled(&self, stepped: &[(f64, f64)]) -> Option<Vec<(f64, f64)>> {
        if stepped.iter().all(|&(m, sd)| self.at_prior(m, sd)) {
            return None;
        }
        Some(stepped.iter().map(|&(m, sd)| (m, self.band_sigma(sd) / m)).collect())
    }

    /// Whether (mean, 1-sigma) is exactly the state's prior: k never learnt.
    #[inline]
    pub fn at_prior(&self, m: f64, sd: f64) -> bool {
        m == 1.0 && sd == self.params.state_sigma
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BODY: Body = Body {
        mass: 60.0,
        wheel_inertia: 0.05,
        wheel_radius: 0.2,
    };

    /// A drive that satisfies eq. TC exactly with k_true (true torque = k_true x logged), F_MR
    /// 25 N, wheels rolling without slip at 1 m/s plus a swing of `accel` m/s^2 (period 4 s).
    /// A sample of a robot driving straight on level ground: all four wheels at `omega`, the
    /// measured total torque `torque` shared equally.
    /// The normal forces are the static load's (read only where the resistance is modelled).
    fn straight(t: f64, f_x: f64, omega: f64, torque: f64, v: f64) -> Raw {
        Raw {
            stamp: t,
            specific_force_x: f_x,
            yaw_rate: 0.0,
            pitch: 0.0,
            wheel_speed: [omega; 4],
            wheel_torque: [torque / 4.0; 4],
            ground_speed: v,
            normal_force: [BODY.mass * crate::normal_force::STANDARD_GRAVITY / 4.0; 4],
        }
    }

    fn drive(bank: &mut TorqueScaleBank, k_true: f64, accel: f64, seconds: f64) -> (f64, f64) {
        drive_of(bank, k_true, 1.0, accel, seconds, |_| 25.0)
    }

    /// The drive above with a torque constant c (true torque = c x logged), a true mass rho x the
    /// vehicle's (the wheels' inertia unchanged) and F_MR(t): k = c / rho.
    fn drive_of(
        bank: &mut TorqueScaleBank,
        c: f64,
        rho: f64,
        accel: f64,
        seconds: f64,
        f_mr: impl Fn(f64) -> f64,
    ) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI / 4.0;
        let mut out = (f64::NAN, f64::NAN);
        for i in 0..(seconds * 100.0) as usize {
            let t = i as f64 * 0.01;
            let a = accel * (w * t).sin();
            let v = 1.0 + accel / w * (1.0 - (w * t).cos());
            let omega = v / BODY.wheel_radius;
            let od = 4.0 * a / BODY.wheel_radius;
            let torque = (rho * BODY.mass * a + f_mr(t)) * BODY.wheel_radius + BODY.wheel_inertia * od;
            out = bank.step(0, &straight(t, a, omega, torque / c, v));
        }
        out
    }

    fn bank(state_sigma: f64) -> TorqueScaleBank {
        let p = Params {
            state_sigma,
            state_var: state_sigma * state_sigma,
            ..Params::defaults()
        };
        TorqueScaleBank::new(p, BODY, Constants::PAPER, 1).unwrap()
    }

    #[test]
    fn it_converges_where_the_robot_accelerates_and_brakes() {
        // 0.05: a payload of +25 % is 4 sigma of the prior, and its innovations must not be taken for
        // jumps of b one after another.  (c, rho, prior): a torque constant 8 % high, a payload of
        // +25 %, a torque constant 20 % low; with the prior 0.05 k is the torque constant's alone
        for (c, rho, prior) in [(1.08, 1.0, 0.10), (1.0, 1.25, 0.10), (0.8, 1.0, 0.05)] {
            let k_true = c / rho;
            let mut b = bank(prior);
            let (m, sd) = drive_of(&mut b, c, rho, 0.8, 40.0, |_| 25.0);
            assert!((m - k_true).abs() < 0.006 * k_true, "k {m} for {k_true}");
            assert!(sd < 0.02 && !b.at_prior(m, sd));
        }
    }

    /// The wheels' inertia under a payload (docs/method.md §15): with the split of the priors
    /// (w = 0.75 at 0.10 / 0.05) the payload's k is read 0.8041 for 0.80 (+0.5 %) and the torque
    /// constant's 1.0843 for 1.08 (+0.4 %); read as the torque constant's alone (w = 0, the prior
    /// 0.05), 0.8146 (+1.8 %: the inertia term, 5 N per m/s^2 here, scaled by k instead of 1 / rho)
    /// and 1.0781 (-0.2 %).
    #[test]
    fn the_inertia_term_carries_the_payloads_share_of_the_scale() {
        let mut b = bank(0.10);
        assert_eq!(b.inertia_scale(0), 1.0);
        b.state[0].shadow_theta[0] = 0.8;
        assert!((b.inertia_scale(0) - 0.8f64.powf(0.75)).abs() < 1e-15);
        assert_eq!(bank(0.05).inertia_scale(0), 1.0);
        let mut b = bank(0.10);
        let (m, _) = drive_of(&mut b, 1.0, 1.25, 0.8, 40.0, |_| 25.0);
        assert!((m / 0.8 - 1.0).abs() < 0.006, "payload: k {m} for 0.8");
        let mut b = bank(0.10);
        let (m, _) = drive_of(&mut b, 1.08, 1.0, 0.8, 40.0, |_| 25.0);
        assert!((m / 1.08 - 1.0).abs() < 0.006, "torque constant: k {m} for 1.08");
    }

    /// A soil change whose resistance ramps over 0.5 s (the axles one after the other) across a
    /// window boundary, on the drive of `soilocp accuracy --robustness`'s accelerate/brake rows: 4 s
    /// of speed swing, then 4 s of a traction test (slip 0.3: no window fits).  The window with the
    /// change's first part adjoins the jump's and is taken back, and the jump window's b does not
    /// enter the next swing's contrast, so k stays the truth's (0.9998 on the first; the kernel before
    /// read 1.0047, and 1.0055 with the shadow's restart alone) (docs/method.md §15, "A jump is a
    /// mixed window").
    #[test]
    fn a_soil_change_across_two_windows_does_not_move_k() {
        for (t_change, step) in [(10.6, 20.0), (10.6, -20.0), (26.6, 15.0)] {
            let mut b = bank(0.10);
            let w = 2.0 * std::f64::consts::PI / 4.0;
            let mut m = f64::NAN;
            for i in 0..4000 {
                let t = i as f64 * 0.01;
                let phase = t % 8.0;
                let swing = phase < 4.0;
                let a = if swing { 0.8 * (w * phase).sin() } else { 0.0 };
                let v = if swing {
                    1.0 + 0.8 / w * (1.0 - (w * phase).cos())
                } else {
                    1.0
                };
                let slip = if swing { 0.0 } else { (0.6 * (phase - 4.0)).min(0.3) };
                let omega = v / (1.0 - slip) / BODY.wheel_radius;
                let od = 4.0 * a / BODY.wheel_radius;
                let f_mr = 25.0 + step * ((t - t_change) / 0.5).clamp(0.0, 1.0);
                let torque = (BODY.mass * a + f_mr) * BODY.wheel_radius + BODY.wheel_inertia * od;
                m = b.step(0, &straight(t, a, omega, torque, v)).0;
            }
            assert!(
                (m - 1.0).abs() < 0.002,
                "k {m} for 1.00 (change at {t_change} s by {step} N)"
            );
        }
    }

    #[test]
    fn at_constant_speed_it_stays_the_prior() {
        let mut b = bank(0.10);
        let (m, sd) = drive(&mut b, 1.08, 0.0, 20.0);
        assert!(b.at_prior(m, sd), "{m} {sd}");
        assert_eq!(
            b.band_sigma(sd),
            0.05,
            "no window's information: the torque constant's prior"
        );
    }

    #[test]
    fn the_band_combines_the_windows_information_with_the_torque_constant_prior() {
        let b = bank(0.10);
        for sd in [0.10f64, 0.05, 0.02] {
            let want = 1.0 / (1.0 / 0.0025 + (1.0 / (sd * sd) - 1.0 / 0.01)).sqrt();
            assert!((b.band_sigma(sd) - want).abs() < 1e-15);
            assert!(b.band_sigma(sd) <= sd.min(0.05) + 1e-12);
        }
        assert_eq!(bank(0.05).band_sigma(0.033), 0.033);
    }

    /// Eq. TC with F_MR = eq. 4 at slip 0.04-0.09 (within max_slip) on a soil that alternates K 200 / 50 every 10 s, the K fed
    /// back as the soil stage does: with the modelled resistance k is read within 1.5 %, with b a random walk
    /// alone it lags each soil change (tests/test_torque_scale.py has the same drive with noise), unless the
    /// soil change is taken as a jump of b (`jump_var`): then within 1.5 % too.
    #[test]
    fn the_modelled_resistance_follows_a_soil_change() {
        let run = |model: bool, jump_var: f64| {
            let p = Params {
                model_resistance: model,
                jump_var,
                state_sigma: 0.05,
                state_var: 0.05 * 0.05,
                ..Params::defaults()
            };
            let mut b = TorqueScaleBank::new(p, BODY, Constants::PAPER, 1).unwrap();
            let (k_true, w) = (1.08, 2.0 * std::f64::consts::PI / 4.0);
            let fz = [BODY.mass * crate::normal_force::STANDARD_GRAVITY / 4.0; 4];
            let mut out = 0.0;
            let mut prev_w = f64::NAN;
            for i in 0..4000 {
                let t = i as f64 * 0.01;
                let a = 0.8 * (w * t).sin();
                let v = 1.0 + 0.8 / w * (1.0 - (w * t).cos());
                let s = 0.04 + 0.05 * (w * t).sin().abs();
                let k_soil = if ((t / 10.0).floor() as i64) % 2 == 0 {
                    200.0
                } else {
                    50.0
                };
                let f_mr = modelled_resistance(&[s; 4], k_soil, &fz, 1.0, &Constants::PAPER);
                let omega = v / (1.0 - s) / BODY.wheel_radius;
                let od = if prev_w.is_nan() {
                    0.0
                } else {
                    4.0 * (omega - prev_w) / 0.01
                };
                prev_w = omega;
                let torque = (BODY.mass * a + f_mr) * BODY.wheel_radius + BODY.wheel_inertia * od;
                b.feed_soil(0, k_soil, [f64::NAN; 4]);
                out = b.step(0, &straight(t, a, omega, torque / k_true, v)).0;
            }
            out
        };
        assert!(
            (run(true, 0.0) / 1.08 - 1.0).abs() < 0.015,
            "modelled: {}",
            run(true, 0.0)
        );
        assert!(
            (run(false, 0.0) / 1.08 - 1.0).abs() > 0.02,
            "random walk: {}",
            run(false, 0.0)
        );
        assert!(
            (run(false, 9.0) / 1.08 - 1.0).abs() < 0.015,
            "jumps: {}",
            run(false, 9.0)
        );
    }

    #[test]
    fn the_soil_feed_keeps_the_last_good_k() {
        let mut b = bank(0.10);
        b.feed_soil(0, f64::NAN, [f64::NAN; 4]);
        assert_eq!(b.soil_k(0), 120.0);
        b.feed_soil(0, 50.0, [f64::NAN; 4]);
        assert_eq!(b.soil_k(0), 50.0);
        b.feed_soil(0, 200.0, [0.1; 4]);
        b.feed_soil(0, -3.0, [f64::NAN; 4]);
        assert_eq!(b.soil_k(0), 200.0);
    }
}
