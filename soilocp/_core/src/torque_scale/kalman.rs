//! The (k, F_MR) filter of the torque scale (docs/method.md §15; issue 27): state theta = (k, b),
//! k the common scale of the logged torques (prior N(1, state_sigma)), b the motion resistance the
//! model does not give (prior N(0, resistance_sigma)); one update per closed window with the
//! window's eq. TC: y = k x - b, H = (x, -1).

use crate::torque_scale::params::Params;

/// One vehicle's posterior of (k, b): mean and covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleState {
    pub theta: [f64; 2],
    pub p: [[f64; 2]; 2],
}

impl ScaleState {
    /// The prior: k = 1 +- state_sigma, b = 0 +- resistance_sigma.
    pub fn prior(p: &Params) -> ScaleState {
        ScaleState {
            theta: [1.0, 0.0],
            p: [[p.state_var, 0.0], [0.0, p.resistance_var]],
        }
    }

    /// k's mean and 1-sigma.
    #[inline]
    pub fn scale(&self) -> (f64, f64) {
        (self.theta[0], self.p[0][0].sqrt())
    }

    /// One window's step of eq. TC's state (k, F_MR) (docs/method.md §15): predict by its span (random walks; k's only where the window can see
    /// it again, `accel`), then the update with y = k x - b.  A window without acceleration
    /// informs b alone: a Schmidt update (k's gain 0), so that at constant speed k stays at its
    /// prior however long the drive; Joseph form, which stays a covariance with a gain that is not
    /// the optimal one.  Operation order of the numpy kernel it replaced (its einsums).
    pub fn update(&mut self, span: f64, x: f64, y: f64, accel: bool, p: &Params) {
        let (th, pm) = (self.theta, &mut self.p);
        pm[0][0] += p.scale_walk_var * span * if accel { 1.0 } else { 0.0 };
        pm[1][1] += p.resistance_walk_var * span;
        let h = [x, -1.0];
        let ph = [pm[0][0] * h[0] + pm[0][1] * h[1], pm[1][0] * h[0] + pm[1][1] * h[1]];
        let s = (h[0] * ph[0] + h[1] * ph[1]) + p.force_var;
        let mut k = [ph[0] / s, ph[1] / s];
        if !accel {
            k[0] = 0.0;
        }
        let innov = y - (h[0] * th[0] + h[1] * th[1]);
        self.theta = [th[0] + k[0] * innov, th[1] + k[1] * innov];
        let eye = [[1.0, 0.0], [0.0, 1.0]];
        let a: [[f64; 2]; 2] = std::array::from_fn(|i| std::array::from_fn(|j| eye[i][j] - k[i] * h[j]));
        let old = *pm;
        // A P A^T: per entry, the terms of each j summed over k first, then the two j's
        let apa = |i: usize, l: usize| {
            let t = |j: usize, m: usize| (a[i][j] * old[j][m]) * a[l][m];
            (t(0, 0) + t(0, 1)) + (t(1, 0) + t(1, 1))
        };
        *pm = std::array::from_fn(|i| std::array::from_fn(|l| apa(i, l) + p.force_var * k[i] * k[l]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Windows of an exact balance y = 0.8 x - 25 with x swinging: k and b are found.
    #[test]
    fn exact_windows_give_k_and_the_resistance() {
        let p = Params::defaults();
        let mut st = ScaleState::prior(&p);
        for i in 0..400 {
            let x = 300.0 + 200.0 * ((i as f64) * 0.7).sin();
            st.update(1.0, x, 0.8 * x - 25.0, true, &p);
        }
        let (k, sd) = st.scale();
        assert!((k - 0.8).abs() < 1e-3, "k {k}");
        assert!((st.theta[1] - 25.0).abs() < 0.5, "b {}", st.theta[1]);
        assert!(sd < 0.01 && (st.p[0][1] - st.p[1][0]).abs() <= 1e-12 * st.p[1][1]);
    }

    /// Without acceleration k keeps its prior exactly (the Schmidt update), b moves.
    #[test]
    fn a_window_without_acceleration_informs_the_resistance_alone() {
        let p = Params::defaults();
        let mut st = ScaleState::prior(&p);
        for _ in 0..50 {
            st.update(1.0, 400.0, 0.8 * 400.0 - 25.0, false, &p);
        }
        assert_eq!(st.theta[0], 1.0);
        assert_eq!(st.p[0][0], p.state_var);
        // b moves towards the misfit at k = 1 (105 N); k's prior variance, which the Schmidt update
        // keeps, counts as the windows' noise, so it gets there slowly
        assert!(st.theta[1] > 50.0 && st.theta[1] < 105.0, "b {}", st.theta[1]);
    }
}
