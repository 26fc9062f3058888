//! The latency of the ground-speed sensor, measured against the accelerometer, and the reading led
//! by it (docs/method.md §13).  A reading tau late is V(t - tau) = V(t) - tau a.  Between two new
//! readings at t1 and t2 the speed changes by the integral of a = f_x + g sin(pitch) (the specific
//! force of eq. 29 plus the gravity term of the speed equation); the readings change by the same
//! integral taken tau earlier, so to first order
//!
//! ```text
//!     y = integral of a over [t1, t2] - (V_read(t2) - V_read(t1))  =  tau (a(t2) - a(t1)) = tau x
//! ```
//!
//! A least-squares line through the origin over the recent pairs (forgetting `window` s) gives tau,
//! used while the fit determines it ([`MIN_T`], [`MIN_SPREAD`], [`MIN_PAIRS`]), clipped to
//! [0, `max_latency`]; the observer then fuses the reading led by the accelerometer's integral over
//! the last tau seconds, V(t) = V_read + integral of a over [t - tau, t], which holds however the
//! acceleration changes within tau (tau a(t), its first order, misses the speed a brake or a
//! launch that began or ended less than tau ago changed).  The integrals are trapezoids (the
//! rectangle at each sample's end reads dt / 2 of latency: 25 ms at 20 Hz).

use std::collections::VecDeque;

use super::numeric::{clip, nan_max};

/// t-statistic of the fitted latency above which it is used.
pub const MIN_T: f64 = 3.0;
/// m/s^2: the root sum of squares of the acceleration changes the fit needs (its lever).
pub const MIN_SPREAD: f64 = 0.5;
/// Pairs of readings (decayed count) the fit needs.
pub const MIN_PAIRS: f64 = 10.0;
/// s: low-pass of the accelerometer (its noise would otherwise enter x and the lead).
pub const SMOOTHING: f64 = 0.05;

/// One vehicle's fit: the accelerometer's integral since the last new reading (NaN: no pair
/// open), that reading, the low-passed acceleration then and now, the previous sample's
/// acceleration (the trapezoid), the decaying sums of x y, x x, y y and the pair count, the
/// latency (s; 0 while not determined), and the recent accelerations the lead integrates: (s since
/// the last restart, m/s^2), spanning at least the largest latency.
#[derive(Clone, Debug)]
pub struct Fit {
    pub integral: f64,
    pub read: f64,
    pub a_then: f64,
    pub a_lp: f64,
    pub a_prev: f64,
    pub sums: [f64; 4],
    pub latency: f64,
    pub clock: f64,
    pub recent: VecDeque<(f64, f64)>,
}

/// The most accelerations a vehicle's lead keeps, whatever the span (repeated stamps add samples
/// without time): 0.3 s at 10 kHz.
const MAX_RECENT: usize = 3000;

impl Default for Fit {
    fn default() -> Fit {
        Fit {
            integral: f64::NAN,
            read: f64::NAN,
            a_then: 0.0,
            a_lp: f64::NAN,
            a_prev: f64::NAN,
            sums: [0.0; 4],
            latency: 0.0,
            clock: 0.0,
            recent: VecDeque::new(),
        }
    }
}

/// The integral of the acceleration over the last `tau` s before `now`: trapezoids between the
/// `recent` samples (time, acceleration), the first one cut at now - tau by interpolation; before
/// the oldest sample its acceleration is held.
pub fn trailing_integral(recent: &VecDeque<(f64, f64)>, now: f64, tau: f64) -> f64 {
    let start = now - tau;
    let mut rev = recent.iter().rev();
    let Some(&(mut t1, mut a1)) = rev.next() else {
        return 0.0;
    };
    let mut sum = 0.0;
    for &(t0, a0) in rev {
        if t1 <= start {
            break;
        }
        if t0 >= start {
            sum += 0.5 * (a0 + a1) * (t1 - t0);
            (t1, a1) = (t0, a0);
        } else {
            let a_start = a0 + (a1 - a0) * (start - t0) / (t1 - t0);
            sum += 0.5 * (a_start + a1) * (t1 - start);
            t1 = start;
            break;
        }
    }
    if t1 > start {
        sum += a1 * (t1 - start);
    }
    sum
}

pub struct GroundSpeedLatency {
    pub window: f64,
    pub max_latency: f64,
    pub fits: Vec<Fit>,
}

/// expm1(-dt / SMOOTHING) and exp(-dt / window), by libm: the fit's low-pass and memory over a step.
pub fn exp_terms(dt: f64, window: f64) -> (f64, f64) {
    ((-dt / SMOOTHING).exp_m1(), (-dt / window).exp())
}

impl GroundSpeedLatency {
    pub fn new(n_vehicles: usize, window: f64, max_latency: f64) -> GroundSpeedLatency {
        GroundSpeedLatency {
            window,
            max_latency,
            fits: vec![Fit::default(); n_vehicles],
        }
    }

    /// One sample of vehicle `g`: `dt` s since its previous sample (NaN or negative: a restart,
    /// which closes the open pair; 0: a repeated stamp), `acc` m/s^2, the ground-speed `reading`
    /// (NaN: none, which neither closes a pair nor enters the fit) and whether it is a new one.
    /// Returns the reading led by the latency, V_read plus the integral of the acceleration over
    /// the last tau seconds.
    ///
    /// `expm1_smoothing` and `exp_window` are [`exp_terms`] of `dt`; they are not used at a restart.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        g: usize,
        dt: f64,
        acc: f64,
        reading: f64,
        new: bool,
        expm1_smoothing: f64,
        exp_window: f64,
    ) -> f64 {
        let max_latency = self.max_latency;
        let f = &mut self.fits[g];
        let restart = dt.is_nan() || dt < 0.0;
        let step = if restart {
            f.a_lp = f64::NAN;
            f.a_prev = f64::NAN;
            f.integral = f64::NAN;
            f.recent.clear();
            f.clock = 0.0;
            0.0
        } else {
            dt
        };
        f.clock += step;
        f.recent.push_back((f.clock, acc));
        // keep one sample at or before now - max_latency, the integral's longest reach
        while f.recent.len() > MAX_RECENT || (f.recent.len() > 2 && f.recent[1].0 <= f.clock - max_latency) {
            f.recent.pop_front();
        }
        if f.a_lp.is_nan() {
            f.a_lp = acc;
            if f.a_prev.is_nan() {
                f.a_prev = acc;
            }
        } else {
            f.a_lp += -expm1_smoothing * (acc - f.a_lp);
        }
        f.integral += 0.5 * (f.a_prev + acc) * step;
        // exp(-0 / window) = 1 at a restart
        let decay = if restart { 1.0 } else { exp_window };
        for s in f.sums.iter_mut() {
            *s *= decay;
        }
        if new && reading.is_finite() {
            // a new reading with one before it (and no restart since)
            let pair = f.integral.is_finite();
            let x = f.a_lp - f.a_then;
            let y = f.integral - (reading - f.read);
            // a term is added either way (0 without a pair): one branch-free update
            f.sums[0] += if pair { x * y } else { 0.0 };
            f.sums[1] += if pair { x * x } else { 0.0 };
            f.sums[2] += if pair { y * y } else { 0.0 };
            f.sums[3] += if pair { 1.0 } else { 0.0 };
            if pair {
                let [sxy, sxx, syy, n] = f.sums;
                let tau = sxy / sxx;
                let t_stat = tau * (sxx * nan_max(n - 1.0, 1.0) / nan_max(syy - tau * sxy, 1e-30)).sqrt();
                let determined = sxx > MIN_SPREAD * MIN_SPREAD && n > MIN_PAIRS && t_stat > MIN_T;
                f.latency = if determined { clip(tau, 0.0, max_latency) } else { 0.0 };
            }
            f.read = reading;
            f.a_then = f.a_lp;
            f.integral = 0.0;
        }
        f.a_prev = acc;
        if f.latency > 0.0 {
            reading + trailing_integral(&f.recent, f.clock, f.latency)
        } else {
            reading
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A brake that begins and ends within the latency: the reading led by the acceleration's
    /// integral over the last tau seconds is the speed now, where tau a(t) is off by up to
    /// tau x the change of a (0.25 m/s here).
    #[test]
    fn a_lead_over_a_changing_acceleration_is_the_speed_now() {
        let (lag, dt) = (0.15, 0.01);
        // a brake of -2 m/s^2 from 1 s to 1.2 s, ramped over 0.05 s at each end
        let acc = |t: f64| -2.0 * ((t - 0.95) / 0.05).clamp(0.0, 1.0) * ((1.25 - t) / 0.05).clamp(0.0, 1.0);
        let mut speed = vec![2.0];
        for i in 1..300 {
            let (t0, t1) = ((i - 1) as f64 * dt, i as f64 * dt);
            speed.push(speed[i - 1] + 0.5 * (acc(t0) + acc(t1)) * dt);
        }
        let late = |i: usize| speed[i - (lag / dt).round() as usize];
        let mut est = GroundSpeedLatency::new(1, 30.0, 0.3);
        est.fits[0].latency = lag; // as the fit finds it (a_late_speed_is_measured...)
        let mut worst: f64 = 0.0;
        for i in 20..300 {
            let t = i as f64 * dt;
            let (e1, e2) = exp_terms(dt, 30.0);
            let led = est.step(0, if i == 20 { f64::NAN } else { dt }, acc(t), late(i), false, e1, e2);
            est.fits[0].latency = lag;
            if i > 40 {
                worst = worst.max((led - speed[i]).abs());
            }
        }
        assert!(worst < 1e-9, "led reading off the speed now by {worst}");
        // the first order misses a brake that ended less than tau ago by tau x its deceleration
        let i = 125; // the brake's end
        assert!((late(i) + lag * acc(1.25) - speed[i]).abs() > 0.2);
    }

    #[test]
    fn a_late_speed_is_measured_and_none_reads_zero() {
        // sines of acceleration, the reading refreshed at 10 Hz, `lag` s late (exact, noise-free)
        for (lag, expect) in [(0.05, 0.05), (0.0, 0.0)] {
            let mut est = GroundSpeedLatency::new(1, 30.0, 0.3);
            let speed = |t: f64| 1.0 - (2.0 * t).cos() / 2.0;
            let mut last = f64::NAN;
            for i in 0..4000 {
                let t = i as f64 * 0.01;
                let acc = (2.0 * t).sin();
                let new = i % 10 == 0;
                let (e1, e2) = exp_terms(t - last, 30.0);
                est.step(0, t - last, acc, speed(t - lag), new, e1, e2);
                last = t;
            }
            assert!(
                (est.fits[0].latency - expect).abs() < 0.01,
                "{lag}: {}",
                est.fits[0].latency
            );
        }
    }
}
