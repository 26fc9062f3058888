//! The window means of eq. TC's terms (docs/method.md §15): the balance is linear, so it holds for
//! means over a window; trapezoid means, as the offline fit's, over `window` s of samples, cut at
//! stamp gaps.  The means bring a slow current stream and a fast IMU onto one clock and make the
//! windows nearly independent.

use crate::torque_scale::params::Params;

/// The terms averaged over a window, per sample: specific force f_x (m/s^2), the gravity reaction
/// of the pitch g_x (eq. 20, m/s^2), the sum of the logged torques (N m) and the modelled motion
/// resistance F_MR,model (N, eq. 4 summed; 0 when not modelled).
pub type Terms = [f64; 4];

/// A window closed on a sample: its span (s), the terms' means, the sum of the wheels' speed
/// changes per second (rad/s^2) and whether every sample of it was usable.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closed {
    /// the window's first stamp (s)
    pub start: f64,
    pub span: f64,
    pub means: Terms,
    pub omega_dot_sum: f64,
    pub usable: bool,
}

/// One vehicle's open window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    /// the window's first stamp (NaN: none yet)
    t0: f64,
    /// the previous sample's stamp (NaN: none yet) and terms
    t_prev: f64,
    prev: Terms,
    /// the terms' integrals over the open window
    area: Terms,
    /// the sum of wheel speeds at the window's start
    w0: f64,
    /// the window holds a sample that is slow, turning, slipping or not finite
    spoilt: bool,
}

impl Default for Window {
    fn default() -> Self {
        Window {
            t0: f64::NAN,
            t_prev: f64::NAN,
            prev: [0.0; 4],
            area: [0.0; 4],
            w0: 0.0,
            spoilt: false,
        }
    }
}

impl Window {
    /// Add one sample (stamp s, its terms, the sum of its wheel speeds rad/s, and whether it is
    /// unusable for the balance).  A window that reaches `window` s closes on this sample, which
    /// also starts the next; a gap (or a stamp that does not advance) restarts it here.
    pub fn add(&mut self, stamp: f64, cur: &Terms, w_sum: f64, unusable: bool, p: &Params) -> Option<Closed> {
        let dt = stamp - self.t_prev;
        let cont = dt.is_finite() && dt > 0.0 && dt <= p.s.max_gap;
        let area: Terms = std::array::from_fn(|j| {
            let step = if cont { 0.5 * (self.prev[j] + cur[j]) * dt } else { 0.0 };
            self.area[j] + step
        });
        let spoilt = self.spoilt || unusable;
        let span = stamp - self.t0;
        let full = cont && span >= p.s.window - 1e-9;
        let closed = full.then(|| Closed {
            start: self.t0,
            span,
            means: std::array::from_fn(|j| area[j] / span),
            omega_dot_sum: (w_sum - self.w0) / span,
            usable: !spoilt,
        });
        if !cont || full {
            self.t0 = stamp;
            self.w0 = w_sum;
            self.area = [0.0; 4];
            self.spoilt = unusable;
        } else {
            self.area = area;
            self.spoilt = spoilt;
        }
        self.prev = *cur;
        self.t_prev = stamp;
        closed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> Params {
        Params::defaults()
    }

    /// A linear ramp's trapezoid mean is exact: f_x = t over [0, 1] means 0.5.
    #[test]
    fn a_window_closes_after_its_span_with_trapezoid_means() {
        let mut w = Window::default();
        let mut out = None;
        for i in 0..=100 {
            let t = i as f64 * 0.01;
            let got = w.add(t, &[t, 0.0, 2.0, 0.0], 4.0 * t, false, &p());
            if got.is_some() {
                assert!(out.is_none());
                out = got;
                assert_eq!(i, 100);
            }
        }
        let c = out.expect("closed at 1 s");
        assert!((c.span - 1.0).abs() < 1e-12);
        assert!((c.means[0] - 0.5).abs() < 1e-12 && (c.means[2] - 2.0).abs() < 1e-12);
        assert!((c.omega_dot_sum - 4.0).abs() < 1e-9);
        assert!(c.usable);
    }

    #[test]
    fn a_gap_restarts_and_a_bad_sample_spoils_the_window() {
        let mut w = Window::default();
        for i in 0..50 {
            assert!(w.add(i as f64 * 0.01, &[0.0; 4], 0.0, i == 10, &p()).is_none());
        }
        // a 0.3 s gap: the window restarts at 0.79, so nothing closes before 1.79
        for i in 0..=100 {
            let t = 0.79 + i as f64 * 0.01;
            let got = w.add(t, &[0.0; 4], 0.0, false, &p());
            assert_eq!(got.is_some(), i == 100, "sample {i}");
            if let Some(c) = got {
                assert!(c.usable, "the spoilt sample was before the gap");
            }
        }
        // within one window a bad sample spoils it
        let mut w = Window::default();
        let closed: Vec<Closed> = (0..=100)
            .filter_map(|i| w.add(i as f64 * 0.01, &[0.0; 4], 0.0, i == 40, &p()))
            .collect();
        assert_eq!(closed.len(), 1);
        assert!(!closed[0].usable);
    }
}
