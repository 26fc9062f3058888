//! The (k, F_MR) filter of the torque scale (docs/method.md §15): state theta = (k, b, c),
//! k the common scale of the logged torques (prior N(1, state_sigma)), b the motion resistance the
//! model does not give (prior N(0, resistance_sigma)) and c its growth with the window's |a|
//! (prior N(0, resistance_slope_sigma)); one update per closed window that accelerates or brakes,
//! with the window's eq. TC: y = k x - b - c |a|, H = (x, -1, -|a|).

use crate::torque_scale::params::Params;

/// The state's size: k, b and c.
pub const N: usize = 3;

type Vector = [f64; N];
type Matrix = [[f64; N]; N];

/// One vehicle's posterior of (k, b, c): mean and covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleState {
    pub theta: Vector,
    pub p: Matrix,
    /// the acceleration signs of the windows fitted since b was last reset (the prior or a
    /// jump): bit 1 accelerating, bit 2 braking
    pub signs: u8,
    /// the posterior as if every accelerating or braking window since that reset had informed k
    /// (the state itself once both signs have been fitted)
    pub shadow_theta: Vector,
    pub shadow_p: Matrix,
}

impl ScaleState {
    /// The prior: k = 1 +- state_sigma, b = 0 +- resistance_sigma, c = 0 +- resistance_slope_sigma.
    pub fn prior(p: &Params) -> ScaleState {
        let p0 = [
            [p.state_var, 0.0, 0.0],
            [0.0, p.resistance_var, 0.0],
            [0.0, 0.0, p.slope_var],
        ];
        ScaleState {
            theta: [1.0, 0.0, 0.0],
            p: p0,
            signs: 0,
            shadow_theta: [1.0, 0.0, 0.0],
            shadow_p: p0,
        }
    }

    /// k's mean and 1-sigma.
    #[inline]
    pub fn scale(&self) -> (f64, f64) {
        (self.theta[0], self.p[0][0].sqrt())
    }

    /// One window's step of eq. TC's state (k, F_MR) (docs/method.md §15): predict by its span
    /// (random walks; k's only where the window can see it again: its mean acceleration `accel`,
    /// f_x less eq. 20's g_x, reaches `min_accel`), then, for a window that accelerates or brakes,
    /// the update with y = k x - b - c |a|.
    ///
    /// A window without acceleration informs nothing: its balance holds the resistance at the
    /// slip of a steady drive, and the resistance grows with the slip that accelerating or braking
    /// takes (eq. 4, even in the slip: c |a|); fitted into b, the one would be carried into the
    /// contrast of the others and read as k, most where the swing is gentle and its windows' x
    /// differ little.  So at constant speed k stays at its prior however long the drive.  The
    /// update is in Joseph form, which stays a covariance with a gain that is not the optimal one
    /// (k's gain 0 below); the operation order is the reference's (tests/reference_torque_scale.py).
    ///
    /// Both signs: the state's k moves only once windows of both acceleration signs have been
    /// fitted since b was last reset (the prior or a jump); until then the windows inform b and c
    /// alone (k's gain 0), while a shadow posterior lets them inform k as well, and the first
    /// window of the other sign makes the shadow the state (no window's information is lost).  A
    /// force that does not flip sign with the acceleration (a draft that grows with the speed of a
    /// start from rest, the resistance at a sweep's slips) shifts the windows of one sign alike,
    /// and only the contrast of the two signs tells it from k.
    ///
    /// A jump of F_MR (the soil under the wheels changed, a draft was hooked on): a window whose
    /// innovation is beyond `jump_var` times its variance is not explained by the slow random
    /// walk, and would otherwise be read as a change of k (a soil change of 25 N in F_MR, against
    /// the 30 N that 0.5 m/s^2 takes on 60 kg).  The variances of b and c return to their priors,
    /// uncorrelated with k, and the window informs them alone.  A jump shifts every window's
    /// balance alike, a wrong k shifts it with the acceleration's sign; so a jump is taken only
    /// once windows of both signs have been fitted since b was last reset (their contrast fits k):
    /// a k far from its prior is learnt from that contrast, not taken for jump after jump.  Returns
    /// whether it was one.
    pub fn update(&mut self, span: f64, x: f64, y: f64, accel: f64, p: &Params) -> bool {
        // a NaN acceleration is none (the reference's |a| >= min_accel is False for it)
        let sign = accel_sign(accel, p);
        let informs = sign != 0;
        predict(&mut self.p, span, informs, p);
        predict(&mut self.shadow_p, span, informs, p);
        if !informs {
            return false;
        }
        let h = design(x, accel);
        let innov = y - dot(&h, &self.theta);
        let s = gain_terms(&self.p, &h, p).1;
        let jump = p.jump_var > 0.0 && self.signs == 3 && innov * innov > p.jump_var * s;
        if jump {
            self.jump(&h, y, sign, p);
            return true;
        }
        self.signs |= sign;
        let innov_shadow = y - dot(&h, &self.shadow_theta);
        correct(&mut self.shadow_theta, &mut self.shadow_p, &h, innov_shadow, true, p);
        if self.signs == 3 {
            // both signs fitted: the shadow, which every accelerating or braking window informed
            (self.theta, self.p) = (self.shadow_theta, self.shadow_p);
        } else {
            correct(&mut self.theta, &mut self.p, &h, innov, false, p);
        }
        false
    }
}

impl ScaleState {
    /// A jump of F_MR at a window of eq. TC's H = h and balance y, its span predicted
    /// (docs/method.md §15, "A jump is a mixed window"): the variances of b and c return to their
    /// priors, uncorrelated with k and with each other, and the window informs them alone.  The
    /// window is a mixed one: the soil under the wheels changed within it, one axle after the
    /// other, so its mean F_MR is neither the old soil's nor the new one's.  Its sign still counts
    /// (the jump test stays on), but the shadow restarts from the reset state, without the window's
    /// b: carried into the contrast with the next window of the other sign, that b would be read as
    /// a change of k.
    pub fn jump(&mut self, h: &Vector, y: f64, sign: u8, p: &Params) {
        for j in 1..N {
            for l in 0..N {
                if l != j {
                    self.p[j][l] = 0.0;
                    self.p[l][j] = 0.0;
                }
            }
        }
        self.p[1][1] = p.resistance_var;
        self.p[2][2] = p.slope_var;
        (self.signs, self.shadow_theta, self.shadow_p) = (sign, self.theta, self.p);
        let innov = y - dot(h, &self.theta);
        correct(&mut self.theta, &mut self.p, h, innov, false, p);
    }

    /// A jump of F_MR whose window adjoins the previous one (fitted or not), from the state before
    /// that one (self) over both windows' `span`: the previous window is taken back.  The wheels
    /// cross a soil change one axle after the other ((a + b) / V, 0.5 s at 1 m/s), so the change's
    /// first part, below the jump test, fell into the window before the jump and was read as k
    /// (docs/method.md §15, "A jump is a mixed window").  `accel`: this window's mean acceleration.
    pub fn jump_after(&mut self, span: f64, x: f64, y: f64, accel: f64, p: &Params) {
        let sign = accel_sign(accel, p);
        predict(&mut self.p, span, sign != 0, p);
        predict(&mut self.shadow_p, span, sign != 0, p);
        self.jump(&design(x, accel), y, sign, p);
    }
}

/// The sign of a window's mean acceleration: 1 accelerating, 2 braking, 0 below `min_accel` (or NaN).
fn accel_sign(accel: f64, p: &Params) -> u8 {
    if accel.abs() >= p.s.min_accel {
        if accel > 0.0 {
            1
        } else {
            2
        }
    } else {
        0
    }
}

/// Eq. TC's row for a window of x = sum T_log / R and mean acceleration `accel`: (x, -1, -|a|).
#[inline]
fn design(x: f64, accel: f64) -> Vector {
    [x, -1.0, -accel.abs()]
}

/// h . v, summed in index order.
#[inline]
fn dot(h: &Vector, v: &Vector) -> f64 {
    (h[0] * v[0] + h[1] * v[1]) + h[2] * v[2]
}

/// The random walks over a window's span: b's always, k's where the window can see it again.
fn predict(pm: &mut Matrix, span: f64, accel: bool, p: &Params) {
    pm[0][0] += p.scale_walk_var * span * if accel { 1.0 } else { 0.0 };
    pm[1][1] += p.resistance_walk_var * span;
}

/// P H^T and the innovation's variance H P H^T + force_var.
fn gain_terms(pm: &Matrix, h: &Vector, p: &Params) -> (Vector, f64) {
    let ph: Vector = std::array::from_fn(|i| dot(&pm[i], h));
    let s = dot(h, &ph) + p.force_var;
    (ph, s)
}

/// The update with the innovation `innov` of H = h; k's gain 0 unless `informs` (the Schmidt
/// update); Joseph form.
fn correct(th: &mut Vector, pm: &mut Matrix, h: &Vector, innov: f64, informs: bool, p: &Params) {
    let (ph, s) = gain_terms(pm, h, p);
    let mut k: Vector = std::array::from_fn(|i| ph[i] / s);
    if !informs {
        k[0] = 0.0;
    }
    *th = std::array::from_fn(|i| th[i] + k[i] * innov);
    let eye = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
    let a: Matrix = std::array::from_fn(|i| std::array::from_fn(|j| eye(i, j) - k[i] * h[j]));
    let old = *pm;
    // A P A^T: per entry, the terms of each j summed over m first, then the j's in order
    let apa = |i: usize, l: usize| {
        let t = |j: usize, m: usize| (a[i][j] * old[j][m]) * a[l][m];
        let row = |j: usize| (t(j, 0) + t(j, 1)) + t(j, 2);
        (row(0) + row(1)) + row(2)
    };
    *pm = std::array::from_fn(|i| std::array::from_fn(|l| apa(i, l) + p.force_var * k[i] * k[l]));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Windows of an exact balance y = 0.8 x - 25 with x swinging (accelerating where x is above its
    /// mean, braking below): k and b are found.
    #[test]
    fn exact_windows_give_k_and_the_resistance() {
        let p = Params::defaults();
        let mut st = ScaleState::prior(&p);
        for i in 0..400 {
            let swing = ((i as f64) * 0.7).sin();
            let x = 300.0 + 200.0 * swing;
            st.update(1.0, x, 0.8 * x - 25.0, 0.8 * swing, &p);
        }
        let (k, sd) = st.scale();
        assert!((k - 0.8).abs() < 1e-3, "k {k}");
        assert!((st.theta[1] - 25.0).abs() < 0.5, "b {}", st.theta[1]);
        assert!(st.theta[2].abs() < 1.0, "c {}", st.theta[2]);
        assert!(sd < 0.01 && (st.p[0][1] - st.p[1][0]).abs() <= 1e-12 * st.p[1][1]);
    }

    /// A resistance that grows with |a| (eq. 4 at the slips that accelerating and braking take):
    /// a start ramp's window at 0.64 m/s^2 and a gentle swing's at +-0.26, on 75 kg read with the
    /// vehicle file's 60 kg (k = 0.8), F_MR = -1.5 - 12 |a| N, exact.  With c the windows find k; with one b
    /// for every |a| (resistance_slope_sigma 0) the start ramp's contrast with the first brake reads
    /// k several per cent high, and the swing's windows undo it only slowly.
    #[test]
    fn a_resistance_that_grows_with_the_acceleration_is_not_read_as_k() {
        let run = |slope_sigma: f64, swings: usize| {
            let p = Params {
                slope_var: slope_sigma * slope_sigma,
                resistance_walk_var: 0.0,
                ..Params::defaults()
            };
            let mut st = ScaleState::prior(&p);
            let mut accels = vec![0.64];
            for _ in 0..swings {
                accels.extend([-0.26, -0.26, 0.0, 0.26, 0.0]);
            }
            for a in accels {
                let f_mr = -1.5 - 12.0 * f64::abs(a);
                let x = 75.0 * a + f_mr;
                st.update(1.0, x, 60.0 * a, a, &p);
            }
            st.theta[0]
        };
        // b constant (no random walk): after two swings 0.8105 (k's prior still pulls) against 0.8407;
        // after twelve 0.8015 and 0.8103
        let (with, without) = (run(20.0, 2), run(0.0, 2));
        assert!((with - 0.8).abs() < 0.015, "k {with}");
        assert!(without - 0.8 > 0.035, "one b: k {without}");
        assert!((run(20.0, 12) - 0.8).abs() < 0.003);
    }

    /// A step of b (a soil change: +12 N to -15 N) between windows of a swing: the window where it shows
    /// is taken as a jump (b's variance back to its prior, k's gain 0), so k stays where the windows
    /// before put it and ends at the truth; without the jump test the step is read as a change of k.
    #[test]
    fn a_step_of_the_resistance_is_a_jump_not_a_change_of_k() {
        let run = |jump_var: f64| {
            let p = Params {
                jump_var,
                ..Params::defaults()
            };
            let mut st = ScaleState::prior(&p);
            let (mut jumps, mut k) = (0, [f64::NAN; 2]);
            for i in 0..40 {
                let a = if i % 2 == 0 { 0.5 } else { -0.5 };
                let x = 60.0 * a + 8.0;
                let b = if i < 20 { 12.0 } else { -15.0 };
                if i == 20 {
                    k[0] = st.theta[0];
                }
                jumps += st.update(1.0, x, 1.08 * x - b, a, &p) as i32;
                if i == 20 {
                    k[1] = st.theta[0];
                }
            }
            (k, st.theta[0], jumps)
        };
        let (k, end, jumps) = run(9.0);
        assert_eq!(jumps, 1);
        assert!((k[0] - 1.08).abs() < 0.01 && k[1] == k[0], "k {k:?}");
        assert!((end - 1.08).abs() < 0.005, "k {end}");
        let (k, _, jumps) = run(0.0);
        assert_eq!(jumps, 0);
        assert!(
            (k[1] - 1.08).abs() > 0.02,
            "without the jump test the step moves k: {k:?}"
        );
    }

    /// Windows of one acceleration sign only (a start from rest under a draft that grows with the
    /// speed, y = x - (10 + 0.1 x)) leave k at its prior: they inform b; the first window of the other
    /// sign informs k.
    #[test]
    fn windows_of_one_sign_inform_the_resistance_alone() {
        let p = Params::defaults();
        let mut st = ScaleState::prior(&p);
        for i in 0..5 {
            let x = 40.0 + 10.0 * i as f64;
            st.update(1.0, x, x - (10.0 + 0.1 * x), 0.5, &p);
            let want = p.state_var + p.scale_walk_var * (i + 1) as f64;
            assert!(st.theta[0] == 1.0 && (st.p[0][0] - want).abs() < 1e-15, "{:?}", st);
        }
        st.update(1.0, -20.0, -20.0 - 8.0, -0.5, &p);
        assert!(st.theta[0] != 1.0 && st.signs == 3);
    }

    /// A window without acceleration informs nothing: the state is the prior, b's variance grows by
    /// its random walk.
    #[test]
    fn a_window_without_acceleration_informs_nothing() {
        let p = Params::defaults();
        let mut st = ScaleState::prior(&p);
        for _ in 0..50 {
            assert!(!st.update(1.0, 400.0, 0.8 * 400.0 - 25.0, 0.1, &p));
        }
        assert_eq!(
            (st.theta, st.shadow_theta, st.signs),
            ([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0)
        );
        assert_eq!(st.p[0][0], p.state_var);
        assert!((st.p[1][1] - (p.resistance_var + 50.0 * p.resistance_walk_var)).abs() < 1e-9);
    }
}
