//! The resistance's random walk slowed while the slips spread (docs/method.md §12, `slip`
//! structure).
//!
//! The accelerometer sees the wheels' resistance only as one sum at each instant,
//! sum_i Fz_i (r0 + r1 |S_i|): the constant part r0 and the slope r1 are told apart by how that sum
//! changes as the load-weighted mean |slip| u = sum_i Fz_i |S_i| / sum_i Fz_i swings over time.  A
//! random walk of r0 fast enough to follow a soil change within a second also follows a good part
//! of a sweep's swing r1 du as a change of r0, and the slope reads low (a flat traction peak is then
//! placed late).  Where u spreads, the data determine both parts and the walks can be slow; where
//! it stays within a narrow band (a narrow sweep, a skid steer's short traction test, cruise), the
//! split rests on the walk, which is kept.  [`SlipSpread`] follows u's standard deviation sigma over
//! a window; [`walk_variance_scale`] gives the factor on the two walks' variances,
//! min(1, (spread / sigma)^4): their intensities fall as 1 / sigma^2 above `spread`.

/// Exponentially weighted mean and mean square of u over `window` s, from the vehicle's (re)start.
#[derive(Clone, Copy, Debug, Default)]
pub struct SlipSpread {
    mean: f64,
    mean_sq: f64,
    started: bool,
}

impl SlipSpread {
    /// Forget the drive so far (a filter restart).
    pub fn reset(&mut self) {
        *self = SlipSpread::default();
    }

    /// Take u after `dt` s (weight dt / window, at most 1); the first u after a restart is taken
    /// whole.  A non-finite u or dt leaves the spread as it was.
    pub fn update(&mut self, u: f64, dt: f64, window: f64) {
        if !u.is_finite() || !dt.is_finite() {
            return;
        }
        let a = if self.started {
            (dt / window).clamp(0.0, 1.0)
        } else {
            1.0
        };
        self.mean += a * (u - self.mean);
        self.mean_sq += a * (u * u - self.mean_sq);
        self.started = true;
    }

    /// u's standard deviation over the window (0 before any u).
    pub fn std(&self) -> f64 {
        (self.mean_sq - self.mean * self.mean).max(0.0).sqrt()
    }
}

/// The load-weighted mean |slip| of the wheels, u = sum_i Fz_i |m_i1| / sum_i Fz_i, from the
/// resistance map's slope column (`m`: 4 x 2, row-major; |m_i1| is |S_i| times the smoothed travel
/// direction's magnitude).
pub fn weighted_slip(m: &[f64], fz: &[f64; 4]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..4 {
        num += fz[i] * m[2 * i + 1].abs();
        den += fz[i];
    }
    num / den
}

/// The factor on the resistance walks' variances at u's spread `sigma`: min(1, (spread / sigma)^4);
/// 1 where `spread` is 0 (off) or sigma is not above it.
pub fn walk_variance_scale(sigma: f64, spread: f64) -> f64 {
    if spread <= 0.0 || sigma.is_nan() || sigma <= spread {
        return 1.0;
    }
    let r = spread / sigma;
    (r * r) * (r * r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_constant_slip_has_no_spread_and_a_square_wave_its_half_amplitude() {
        let mut s = SlipSpread::default();
        for _ in 0..1000 {
            s.update(0.3, 0.01, 3.0);
        }
        assert!(s.std() < 1e-12);
        // u alternating 0.1 / 0.5 every step: mean 0.3, std 0.2 (up to the weighting's ripple)
        for k in 0..5000 {
            s.update(if k % 2 == 0 { 0.1 } else { 0.5 }, 0.01, 3.0);
        }
        assert!((s.std() - 0.2).abs() < 1e-3, "{}", s.std());
        s.reset();
        assert_eq!(s.std(), 0.0);
        s.update(f64::NAN, 0.01, 3.0);
        s.update(0.7, 0.01, 3.0);
        assert_eq!(s.std(), 0.0, "the first u after a restart is taken whole");
    }

    #[test]
    fn the_walk_slows_above_the_spread_only() {
        assert_eq!(walk_variance_scale(0.03, 0.05), 1.0);
        assert_eq!(walk_variance_scale(0.05, 0.05), 1.0);
        assert!((walk_variance_scale(0.1, 0.05) - 0.0625).abs() < 1e-15);
        assert_eq!(walk_variance_scale(0.2, 0.0), 1.0, "0: off");
        assert_eq!(walk_variance_scale(f64::NAN, 0.05), 1.0);
    }

    #[test]
    fn weighted_slip_weighs_by_load() {
        let m = [1.0, 0.5, 1.0, -0.1, 1.0, 0.1, 1.0, 0.5];
        let u = weighted_slip(&m, &[100.0, 300.0, 300.0, 100.0]);
        assert!((u - (0.5 * 200.0 + 0.1 * 600.0) / 800.0).abs() < 1e-15);
    }
}
