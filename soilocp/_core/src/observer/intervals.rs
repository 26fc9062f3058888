//! Gross traction at a slow stream's refresh, from the readings themselves (docs/method.md §13,
//! "Slow wheel speeds or torques"): over a held wheel speed's interval, eq. 13 integrated
//! ([`RefreshIntervals::step`]); at a held torque's refresh while the speed is read at every
//! sample, eq. 13 at that instant ([`RefreshIntervals::torque_refresh`]).
//!
//! Integrated over the interval from the previous refresh t0 to this one t1, eq. 13 needs no
//! prediction: I_w (omega(t1) - omega(t0)) = int T dt - R_w int g Fz dt, so the Fz-weighted mean
//! gross traction over the interval is
//!
//! ```text
//!     g_bar = (int T dt - I_w (omega(t1) - omega(t0))) / (R_w int Fz dt)
//! ```
//!
//! exact but for the readings' own noise; its slip runs from eq. 1 at the previous reading to eq. 1
//! at this one.  The speed is taken as linear over the interval, which it is not near a sweep's
//! kink: the variance states that as the inertia torque of a `jerk` over the interval plus the
//! scatter of T / (R_w Fz) about a straight line in time within it, and the slip path as uncertain
//! by R_w |d omega_dot| tau / 8 (`rim_sigma`).

use super::numeric::nan_max;
use super::settings::ObserverSettings;

/// s: intervals are sums or differences of stamps, so a 10 Hz stream's 0.1 s reads 0.1 - 1e-15 as
/// often as not; the interval bounds are taken this much wider.
pub const STAMP_TOLERANCE: f64 = 1e-6;

/// One vehicle's refresh pairs per wheel; `interval` 0 where the sample closes none.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pairs {
    /// s from the previous refresh to this one (0: none closed here)
    pub interval: [f64; 4],
    /// the interval's Fz-weighted mean gross traction coefficient (eq. 13 integrated) and its variance
    pub gross: [f64; 4],
    pub gross_var: [f64; 4],
    /// the rim speed R_w omega at the interval's start (the previous reading) and end (this one), m/s
    pub rim_start: [f64; 4],
    pub rim_end: [f64; 4],
    /// the ground speed at the wheel (V - psi_dot y_i) at the interval's start and end, m/s
    pub ground_start: [f64; 4],
    pub ground_end: [f64; 4],
    /// 1-sigma of the rim speed's course between the readings against their chord, m/s
    pub rim_sigma: [f64; 4],
    /// one stream refreshes slowly and the other is read at the sample rate: K learns at the refreshes
    pub active: [bool; 4],
}

impl Pairs {
    /// Two sources' pairs in one: `b`'s where it closes an interval, `self`'s elsewhere; active in either.
    pub fn merge(&self, b: &Pairs) -> Pairs {
        let mut out = *self;
        for w in 0..4 {
            if b.interval[w] > 0.0 {
                out.interval[w] = b.interval[w];
                out.gross[w] = b.gross[w];
                out.gross_var[w] = b.gross_var[w];
                out.rim_start[w] = b.rim_start[w];
                out.rim_end[w] = b.rim_end[w];
                out.ground_start[w] = b.ground_start[w];
                out.ground_end[w] = b.ground_end[w];
                out.rim_sigma[w] = b.rim_sigma[w];
            }
            out.active[w] |= b.active[w];
        }
        out
    }
}

/// What one wheel's slow stream needs of the sample, per wheel.
pub struct WheelSample {
    /// the speed reading changed; its stream is read at the sample rate
    pub changed: [bool; 4],
    pub full_rate: [bool; 4],
    /// the previous and the new speed reading (rad/s)
    pub prev_speed: [f64; 4],
    pub speed: [f64; 4],
    /// torque (N m, split per side), a new torque reading, normal force (N, > 0), ground speed at
    /// the wheel now (m/s)
    pub torque: [f64; 4],
    pub torque_fresh: [bool; 4],
    pub fz: [f64; 4],
    pub ground: [f64; 4],
}

/// One wheel's integrals since its speed's last change.
#[derive(Clone, Copy, Debug)]
struct Interval {
    span: f64,
    torque_dt: f64,
    fz_dt: f64,
    /// the ground speed at the wheel when the interval began
    ground_start: f64,
    /// a straight line's least-squares sums through y = T / (R_w Fz) against the time in the
    /// interval: n, t, t^2, y, t y, y^2
    line: [f64; 6],
    /// the integrals began at a change of the speed (not at a restart) and the torque was read at
    /// every sample since
    valid: bool,
    /// the previous closed interval's mean acceleration (rad/s^2; NaN: none since a restart),
    /// whose change to this interval's measures how far the speed strays from the chord
    last_rate: f64,
    /// the last interval ended as a slow refresh; the same for a slow torque stream
    active: bool,
    torque_active: bool,
}

impl Default for Interval {
    fn default() -> Interval {
        Interval {
            span: 0.0,
            torque_dt: 0.0,
            fz_dt: 0.0,
            ground_start: 0.0,
            line: [0.0; 6],
            valid: false,
            last_rate: f64::NAN,
            active: false,
            torque_active: false,
        }
    }
}

/// The constants of the refresh pairs (soilocp.estimation.observer.ObserverConfig's refresh_*).
#[derive(Clone, Copy, Debug)]
pub struct IntervalSettings {
    pub inertia: f64,
    pub radius: f64,
    pub jerk: f64,
    pub min_interval: f64,
    pub max_interval: f64,
    pub variance_floor: f64,
    /// rad/s: the encoder's noise
    pub speed_sigma: f64,
}

impl IntervalSettings {
    /// The refresh pairs' settings of the declared `s` for a wheel of `inertia` (kg m^2) and `radius` (m).
    pub fn of(s: &ObserverSettings, inertia: f64, radius: f64) -> IntervalSettings {
        IntervalSettings {
            inertia,
            radius,
            jerk: s.refresh_jerk,
            min_interval: s.refresh_min_interval,
            max_interval: s.refresh_max_interval,
            variance_floor: s.variance_floor,
            speed_sigma: s.r_wheel_speed,
        }
    }
}

pub struct RefreshIntervals {
    pub settings: IntervalSettings,
    wheels: Vec<[Interval; 4]>,
}

impl RefreshIntervals {
    pub fn new(n_vehicles: usize, settings: IntervalSettings) -> RefreshIntervals {
        RefreshIntervals {
            settings,
            wheels: vec![[Interval::default(); 4]; n_vehicles],
        }
    }

    /// Integrate one sample of vehicle `g` (its values stand for the `dt` s before it) and close
    /// the intervals whose speed reading changed now: eq. 13 integrated over each,
    /// g_bar = (int T dt - I_w (omega(t1) - omega(t0))) / (R_w int Fz dt) (docs/method.md §13; the
    /// print's eq. 13 holds per instant, and a held speed leaves no instant between the readings to
    /// apply it at).  `restart`: a first sample, a gap or a stamp that went backwards (every
    /// interval restarts invalid).  A vehicle whose four speeds are read at the sample rate keeps
    /// no interval.
    pub fn step(&mut self, g: usize, dt: f64, restart: bool, s: &WheelSample) -> Pairs {
        let st = self.settings;
        let wheels = &mut self.wheels[g];
        let mut out = Pairs::default();
        if s.full_rate.iter().all(|&f| f) {
            for iv in wheels.iter_mut() {
                iv.valid = false;
                iv.active = false;
                iv.last_rate = f64::NAN;
            }
            return out;
        }
        // a restart, a repeated stamp or NaN: nothing to integrate
        let step = if restart || dt.is_nan() || dt <= 0.0 { 0.0 } else { dt };
        let counted = if step > 0.0 { 1.0 } else { 0.0 };
        for (w, iv) in wheels.iter_mut().enumerate() {
            let mut valid = iv.valid && !restart;
            iv.span += step;
            iv.torque_dt += s.torque[w] * step;
            iv.fz_dt += s.fz[w] * step;
            valid &= s.torque_fresh[w];
            let y = s.torque[w] / (st.radius * s.fz[w]);
            let t = iv.span;
            for (sum, term) in iv.line.iter_mut().zip([1.0, t, t * t, y, t * y, y * y]) {
                *sum += counted * term;
            }
            // a slow stream's refresh: the interval is longer than the sample interval and
            // min_interval (a quantised encoder's change after a few repeats is a full-rate
            // stream's, and the observer follows it), and not so long that the speed's linear
            // course between the readings says nothing
            let changed = s.changed[w];
            let ended = changed
                && valid
                && !s.full_rate[w]
                && iv.span > 1.5 * step
                && iv.span >= st.min_interval - STAMP_TOLERANCE
                && iv.span <= st.max_interval + STAMP_TOLERANCE
                && s.prev_speed[w].is_finite()
                && iv.fz_dt > 0.0;
            let last_rate = iv.last_rate;
            let active = ended || (iv.active && !restart && !changed && s.torque_fresh[w]);
            out.active[w] = active;
            if ended {
                iv.last_rate = close(&st, iv, s, w, &mut out);
            } else if restart || changed {
                iv.last_rate = f64::NAN;
            } else {
                iv.last_rate = last_rate;
            }
            // a change starts the next interval; a restart starts an invalid one (its start is unknown)
            if changed || restart {
                iv.span = 0.0;
                iv.torque_dt = 0.0;
                iv.fz_dt = 0.0;
                iv.line = [0.0; 6];
                iv.ground_start = s.ground[w];
                valid = !restart && changed;
            }
            iv.valid = valid;
            iv.active = active;
        }
        out
    }

    /// docs/method.md §13: a slow torque stream's refresh (a motor current held 0.1-1 s between readings) while the
    /// wheel speed is read at every sample, for vehicle `g`: eq. 13 at this instant from the
    /// readings, g = (T - I_w omega_dot) / (R_w Fz), with omega_dot the last two speed readings'
    /// difference (1-sigma I_w sqrt(2) speed_sigma / dt / (R_w Fz): 0.008 at 100 Hz), at the slip
    /// of this speed reading.  The pair stands for the torque's interval `since` s.  Per wheel:
    /// `changed` / `full_rate` the torque reading's; the speed is not held when its stream is read
    /// at the sample rate (`s.full_rate`) or its value last changed less than min_interval before
    /// (`speed_since`, s).  A vehicle whose four torques are read at the sample rate has none.
    #[allow(clippy::too_many_arguments)]
    pub fn torque_refresh(
        &mut self,
        g: usize,
        dt: f64,
        restart: bool,
        changed: &[bool; 4],
        full_rate: &[bool; 4],
        since: &[f64; 4],
        speed_since: &[f64; 4],
        s: &WheelSample,
    ) -> Pairs {
        let st = self.settings;
        let wheels = &mut self.wheels[g];
        let mut out = Pairs::default();
        if full_rate.iter().all(|&f| f) {
            for iv in wheels.iter_mut() {
                iv.torque_active = false;
            }
            return out;
        }
        let ok_dt = !restart && dt > 0.0;
        let step = if ok_dt { dt } else { 1.0 };
        for (w, iv) in wheels.iter_mut().enumerate() {
            let slow = !full_rate[w] && (s.full_rate[w] || speed_since[w] < st.min_interval - STAMP_TOLERANCE) && ok_dt;
            let close = changed[w]
                && slow
                && since[w] >= st.min_interval - STAMP_TOLERANCE
                && since[w] <= st.max_interval + STAMP_TOLERANCE
                && s.prev_speed[w].is_finite()
                && s.fz[w] > 0.0;
            iv.torque_active = close || (iv.torque_active && slow);
            out.active[w] = iv.torque_active;
            if close {
                let fz = s.fz[w];
                let gross = (s.torque[w] - st.inertia * (s.speed[w] - s.prev_speed[w]) / step) / (st.radius * fz);
                let scale = st.inertia / (st.radius * fz);
                let a = scale * std::f64::consts::SQRT_2 * st.speed_sigma / step;
                let b = scale * st.jerk * step;
                // the pair's slip is this reading's
                let rim = st.radius * s.speed[w];
                out.interval[w] = since[w];
                out.gross[w] = gross;
                out.gross_var[w] = a * a + b * b + st.variance_floor;
                out.rim_start[w] = rim;
                out.rim_end[w] = rim;
                out.ground_start[w] = s.ground[w];
                out.ground_end[w] = s.ground[w];
            }
        }
        out
    }
}

/// The pair of wheel `w`'s interval that ended now, into `out`; returns the interval's mean
/// acceleration (rad/s^2).  The first interval after a restart has no neighbour to tell its
/// curvature: it only starts the chain (no pair).
fn close(st: &IntervalSettings, iv: &Interval, s: &WheelSample, w: usize, out: &mut Pairs) -> f64 {
    let tau = iv.span;
    let (speed, prev) = (s.speed[w], s.prev_speed[w]);
    let rate = (speed - prev) / tau;
    if !iv.last_rate.is_finite() {
        return rate;
    }
    let fz_mean = iv.fz_dt / tau;
    let gross = (iv.torque_dt - st.inertia * (speed - prev)) / (st.radius * iv.fz_dt);
    let jerk = st.inertia * st.jerk * tau / (st.radius * fz_mean);
    let mut var = jerk * jerk + st.variance_floor;
    // the gross traction's course within the interval off a straight line in time: the slip path's
    // average (Simpson's rule on a straight path) does not see it, so it is that much less certain
    let [n, t, tt, y, ty, yy] = iv.line;
    let n1 = nan_max(n, 1.0);
    let sxx = tt - t * t / n1;
    let sxy = ty - t * y / n1;
    let syy = yy - y * y / n1;
    let fitted = if sxx > 0.0 { sxy * sxy / sxx } else { 0.0 };
    var += nan_max(syy - fitted, 0.0) / n1;
    out.interval[w] = iv.span;
    out.gross[w] = gross;
    out.gross_var[w] = var;
    out.rim_start[w] = st.radius * prev;
    out.rim_end[w] = st.radius * speed;
    out.ground_start[w] = iv.ground_start;
    out.ground_end[w] = s.ground[w];
    // the mean speed over the interval against the readings' mean: a course bent by an
    // acceleration change d_a within the interval strays from the chord by up to d_a tau / 8
    out.rim_sigma[w] = st.radius * (rate - iv.last_rate).abs() * tau / 8.0;
    rate
}

#[cfg(test)]
mod tests {
    use super::*;

    const I_W: f64 = 0.04;
    const R_W: f64 = 0.15;
    const FZ: f64 = 150.0;
    const G: f64 = 0.4;
    const DT: f64 = 0.01;

    fn settings() -> IntervalSettings {
        IntervalSettings {
            inertia: I_W,
            radius: R_W,
            jerk: 50.0,
            min_interval: 0.1,
            max_interval: 1.0,
            variance_floor: 1e-10,
            speed_sigma: 0.03,
        }
    }

    /// A wheel spun up at 3 rad/s^2 on a gross traction G (eq. 13: T = R_w Fz G + I_w 3).
    fn sample(changed: bool, full_rate: bool, prev: f64, speed: f64) -> WheelSample {
        WheelSample {
            changed: [changed; 4],
            full_rate: [full_rate; 4],
            prev_speed: [prev; 4],
            speed: [speed; 4],
            torque: [R_W * FZ * G + I_W * 3.0; 4],
            torque_fresh: [true; 4],
            fz: [FZ; 4],
            ground: [0.7; 4],
        }
    }

    #[test]
    fn a_held_speeds_interval_serves_eq_13_integrated() {
        // the speed read every 21 samples (4.76 Hz): from the second closed interval on, each serves G
        let mut ri = RefreshIntervals::new(1, settings());
        let (mut served, mut prev, mut held) = (vec![], f64::NAN, 5.0);
        for k in 0..200 {
            let t = k as f64 * DT;
            let changed = k % 21 == 0;
            if changed {
                prev = held;
                held = 5.0 + 3.0 * t;
            }
            let dt = if k == 0 { f64::NAN } else { DT };
            let p = ri.step(0, dt, k == 0, &sample(changed, false, prev, held));
            if p.interval[0] > 0.0 {
                served.push(p);
            }
        }
        // changes at 0, 21, ..., 189: the first interval starts at a restart (invalid), the next only starts the chain
        assert_eq!(served.len(), 7);
        for p in &served {
            assert!((p.interval[0] - 0.21).abs() < 1e-9 && p.active[0]);
            assert!((p.gross[0] - G).abs() < 1e-9, "{}", p.gross[0]);
            // a constant acceleration: the chord is the course, no curvature
            assert!(p.rim_sigma[0].abs() < 1e-9 && p.gross_var[0] > 0.0);
        }
        // read at the sample rate: nothing kept, nothing served
        let mut ri = RefreshIntervals::new(1, settings());
        for k in 1..100 {
            let p = ri.step(0, DT, false, &sample(true, true, 5.0, 5.03));
            assert_eq!(p, Pairs::default(), "{k}");
        }
    }

    #[test]
    fn a_held_torques_refresh_serves_eq_13_at_that_instant() {
        // speed read at every sample, the torque every 50: a pair at each torque refresh, exact
        let mut ri = RefreshIntervals::new(1, settings());
        let mut pairs = 0;
        for k in 1..300 {
            let t = k as f64 * DT;
            let ws = sample(true, true, 5.0 + 3.0 * (t - DT), 5.0 + 3.0 * t);
            let changed = k % 50 == 0;
            let p = ri.torque_refresh(0, DT, false, &[changed; 4], &[false; 4], &[0.5; 4], &[DT; 4], &ws);
            if changed {
                assert!((p.gross[0] - G).abs() < 1e-9 && p.interval[0] == 0.5, "{p:?}");
                pairs += 1;
            } else {
                assert_eq!(p.interval[0], 0.0);
            }
        }
        assert_eq!(pairs, 5);
        let a = Pairs {
            interval: [0.2, 0.0, 0.0, 0.0],
            gross: [1.0; 4],
            active: [true, false, false, false],
            ..Pairs::default()
        };
        let b = Pairs {
            interval: [0.0, 0.5, 0.0, 0.0],
            gross: [2.0, 2.0, 0.0, 0.0],
            active: [false, true, false, true],
            ..Pairs::default()
        };
        let m = a.merge(&b);
        assert_eq!(
            (m.interval, m.gross, m.active),
            ([0.2, 0.5, 0.0, 0.0], [1.0, 2.0, 1.0, 1.0], [true, true, false, true])
        );
    }
}
