//! The whole observer step of N vehicles (soilocp.estimation.observer_bank.ObserverBank), one call
//! per step for any subset of them: the readings clock (`readings`), the per-side torque split and
//! the encoder lead (`wheel_inputs`), the ground-speed latency (`latency`), the filter (`bank`)
//! and the refresh pairs (`intervals`), with every vehicle's state of each.

use super::bank::{FilterBank, Sample};
use super::intervals::{IntervalSettings, Pairs, RefreshIntervals, WheelSample};
use super::latency::{exp_terms, GroundSpeedLatency};
use super::layout::N_MEAS;
use super::numeric::nan_max;
use super::readings::{ReadingClock, CHANNELS};
use super::settings::ObserverSettings;
use super::wheel_inputs::{encoder_lead, split_side_torque, wheel_acceleration};

/// Normal force (N) below which a wheel is treated as lifted off: no traction information.
pub const LIFT_OFF_FORCE: f64 = 1.0;

/// How the vehicle's readings are to be read, and the observer's thresholds around the filter.
#[derive(Clone, Copy, Debug)]
pub struct Reading {
    /// skid-steer: one motor per side, its torque logged as half on each wheel (docs/method.md §14)
    pub per_side: bool,
    /// encoder speeds are count differences, the mean over their interval (docs/method.md §14)
    pub interval_mean: bool,
    /// mu_i counts as determined while its posterior variance is <= this
    pub mu_var_determined: f64,
}

impl Reading {
    /// What the vehicles' step reads of a vehicle's drive, from the declared `s` (`per_side`: a side's encoder) and
    /// encoder (`interval_mean`: its reading is the interval's mean speed).
    pub fn of(s: &ObserverSettings, per_side: bool, interval_mean: bool) -> Reading {
        Reading {
            per_side,
            interval_mean,
            mu_var_determined: s.mu_std_determined * s.mu_std_determined,
        }
    }
}

/// One vehicle's sample as logged.
#[derive(Clone, Copy, Debug)]
pub struct Raw {
    pub stamp: f64,
    pub specific_force_x: f64,
    pub yaw_rate: f64,
    pub pitch: f64,
    pub wheel_speed: [f64; 4],
    pub wheel_torque: [f64; 4],
    /// NaN: no independent ground-speed sensor
    pub ground_speed: f64,
    pub normal_force: [f64; 4],
}

/// s: memory of the ground speed's disagreement with the accelerometer ([`Estimate::ground_speed_excess`])
pub const EXCESS_WINDOW: f64 = 1.0;

/// One vehicle's estimate at a step.
#[derive(Clone, Copy, Debug, Default)]
pub struct Estimate {
    pub mu: [f64; 4],
    pub mu_var: [f64; 4],
    pub mu_determined: [bool; 4],
    pub resistance: [f64; 4],
    pub gross: [f64; 4],
    pub gross_var: [f64; 4],
    pub wheel_speed: [f64; 4],
    pub ground_speed: f64,
    pub yaw_rate: f64,
    pub rejected: i64,
    /// per wheel: its filtered speed is the prediction, not the reading (bank::Step::speed_rejected)
    pub speed_rejected: [bool; 4],
    /// 0: no reset, else bank::RESET_REASONS[code - 1]
    pub reset: u8,
    /// clamped to the lift-off force
    pub normal_force: [f64; 4],
    /// s since each channel's last new reading (wheel speeds, ground speed, torques)
    pub age: [f64; CHANNELS],
    pub ground_speed_measured: bool,
    /// s the ground speed was led by (0: none)
    pub ground_speed_latency: f64,
    /// m/s: how far the ground speed's new readings stray from the filtered speed carried forward by the
    /// accelerometer, beyond the noise the observer assumes (r_ground_speed): the rms over the last
    /// [`EXCESS_WINDOW`] s, less r_ground_speed in quadrature (0 when within it).  A GNSS-grade speed (noisy,
    /// late, held between fixes) strays; the slip made of it is that much less certain (docs/method.md §20)
    pub ground_speed_excess: f64,
    pub pairs: Pairs,
}

impl Estimate {
    /// s since each wheel's speed reading was last new.
    pub fn speed_age(&self) -> [f64; 4] {
        [self.age[0], self.age[1], self.age[2], self.age[3]]
    }

    /// s since the ground speed reading was last new.
    pub fn ground_speed_age(&self) -> f64 {
        self.age[4]
    }

    /// s since each wheel's torque reading was last new.
    pub fn torque_age(&self) -> [f64; 4] {
        [self.age[5], self.age[6], self.age[7], self.age[8]]
    }

    /// The first number that is not finite, by its output name (soilocp's ObserverOutput message,
    /// whose fields must be finite), or None.
    pub fn first_non_finite(&self) -> Option<&'static str> {
        let quads = QUAD_NAMES.iter().zip(self.quads());
        let bad_quad = quads.into_iter().find(|(_, q)| !q.iter().all(|v| v.is_finite()));
        bad_quad.map(|(n, _)| *n).or_else(|| {
            FLAT_NAMES
                .iter()
                .zip(self.flats())
                .find(|(_, v)| !v.is_finite())
                .map(|(n, _)| *n)
        })
    }
}

/// An [`Estimate`]'s numbers (and flags), each named once: the const array of their names (the ObserverOutput
/// message's fields: ObserverCore.block_fields, the slip gate's packed row) and the method giving
/// their values in that order.
macro_rules! named_numbers {
    ($(#[$doc:meta])* $names:ident, fn $values:ident(&$e:ident) -> [$t:ty; $n:literal] {
        $($name:literal: $value:expr,)+
    }) => {
        $(#[$doc])*
        pub const $names: [&str; $n] = [$($name),+];

        impl Estimate {
            $(#[$doc])*
            pub fn $values(&$e) -> [$t; $n] {
                [$($value),+]
            }
        }
    };
}

named_numbers! {
    /// The per-wheel numbers.
    QUAD_NAMES, fn quads(&self) -> [[f64; 4]; 17] {
        "mu": self.mu,
        "mu_var": self.mu_var,
        "resistance": self.resistance,
        "gross": self.gross,
        "gross_var": self.gross_var,
        "wheel_speed": self.wheel_speed,
        "normal_force": self.normal_force,
        "speed_age": self.speed_age(),
        "torque_age": self.torque_age(),
        "interval": self.pairs.interval,
        "interval_gross": self.pairs.gross,
        "interval_gross_var": self.pairs.gross_var,
        "interval_rim_start": self.pairs.rim_start,
        "interval_rim_end": self.pairs.rim_end,
        "interval_ground_start": self.pairs.ground_start,
        "interval_ground_end": self.pairs.ground_end,
        "interval_rim_sigma": self.pairs.rim_sigma,
    }
}

named_numbers! {
    /// The per-vehicle numbers.
    FLAT_NAMES, fn flats(&self) -> [f64; 5] {
        "ground_speed": self.ground_speed,
        "yaw_rate": self.yaw_rate,
        "ground_speed_age": self.ground_speed_age(),
        "ground_speed_latency": self.ground_speed_latency,
        "ground_speed_excess": self.ground_speed_excess,
    }
}

named_numbers! {
    /// The per-wheel flags.
    BOOL_QUAD_NAMES, fn bool_quads(&self) -> [[bool; 4]; 3] {
        "mu_determined": self.mu_determined,
        "interval_learning": self.pairs.active,
        "speed_rejected": self.speed_rejected,
    }
}

named_numbers! {
    /// The per-vehicle flags.
    BOOL_FLAT_NAMES, fn bool_flats(&self) -> [bool; 2] {
        "reset": self.reset > 0,
        "ground_speed_measured": self.ground_speed_measured,
    }
}

pub struct ObserverBank {
    pub filter: FilterBank,
    pub reading: Reading,
    pub readings: ReadingClock,
    pub latency: Option<GroundSpeedLatency>,
    pub intervals: RefreshIntervals,
    pub last_stamp: Vec<f64>,
    /// per vehicle: the mean square of the ground speed's new readings against the filtered speed carried
    /// forward by the accelerometer, and the stamp of the last new reading
    pub stray: Vec<(f64, f64)>,
}

impl ObserverBank {
    pub fn new(filter: FilterBank, reading: Reading, refresh: IntervalSettings) -> ObserverBank {
        let (n, s) = (filter.n_vehicles, &filter.settings.s);
        let latency_max = s.ground_speed_latency_max;
        ObserverBank {
            readings: ReadingClock::new(n, s.full_rate_share, s.repeat_window),
            latency: (latency_max > 0.0).then(|| GroundSpeedLatency::new(n, s.latency_window, latency_max)),
            intervals: RefreshIntervals::new(n, refresh),
            last_stamp: vec![f64::NAN; n],
            stray: vec![(0.0, f64::NAN); n],
            filter,
            reading,
        }
    }

    /// One observer step of vehicle `g` (see the module doc).
    pub fn step(&mut self, g: usize, r: &Raw) -> Estimate {
        let rd_cfg = self.reading;
        let max_gap = self.filter.settings.s.max_gap;
        let last = self.last_stamp[g];
        // NaN at a vehicle's first sample
        let dt = r.stamp - last;
        let first = last.is_nan();
        let fz: [f64; 4] = std::array::from_fn(|w| nan_max(r.normal_force[w], LIFT_OFF_FORCE));
        let mut raw = [0.0; CHANNELS];
        raw[..4].copy_from_slice(&r.wheel_speed);
        raw[4] = r.ground_speed;
        raw[5..].copy_from_slice(&r.wheel_torque);
        let rd = self.readings.step(g, r.stamp, last, &raw, first || dt < 0.0);
        let mut torque = r.wheel_torque;
        let mut wheel_z = r.wheel_speed;
        if rd_cfg.per_side || rd_cfg.interval_mean {
            // a changed encoder speed is a count difference: the mean over the interval since the
            // last change (a quantised repeat in between is the same count rate, and adds no
            // acceleration)
            let mut inertia_torque = [0.0; 4];
            for w in 0..4 {
                let since = if rd.changed[w] {
                    r.stamp - rd.changed_before[w]
                } else {
                    0.0
                };
                let interval = if since <= max_gap { since } else { 0.0 };
                let rate = wheel_acceleration(rd.prev[w], r.wheel_speed[w], interval, rd.changed[w], max_gap);
                inertia_torque[w] = self.filter.vehicle.wheel_inertia * rate;
                if rd_cfg.interval_mean {
                    wheel_z[w] = r.wheel_speed[w] + encoder_lead(interval, rate);
                }
            }
            if rd_cfg.per_side {
                torque = split_side_torque(&r.wheel_torque, &fz, &inertia_torque);
            }
        }
        // dt == 0 (a repeated stamp) is no restart: only the update runs
        let restart = first || dt < 0.0 || dt > max_gap;
        let g_sin_pitch = self.filter.settings.s.gravity * r.pitch.sin();
        let mut ground_speed_z = r.ground_speed;
        let mut latency = 0.0;
        if let Some(fit) = self.latency.as_mut() {
            // a late ground speed, led by its measured latency (eq. 29's f_x plus g sin(pitch))
            let acc = r.specific_force_x + g_sin_pitch;
            // the fit's low-pass and memory over this step, by libm (unused at a restart)
            let (dt_fit, (expm1_smoothing, exp_window)) = if restart {
                (f64::NAN, (f64::NAN, f64::NAN))
            } else {
                (dt, exp_terms(dt, fit.window))
            };
            ground_speed_z = fit.step(g, dt_fit, acc, r.ground_speed, rd.fresh[4], expm1_smoothing, exp_window);
            latency = fit.fits[g].latency;
        }
        let sample = Sample {
            dt,
            dt_cubed: dt * dt * dt,
            specific_force_x: r.specific_force_x,
            yaw_rate: r.yaw_rate,
            pitch: r.pitch,
            wheel_speed: r.wheel_speed,
            ground_speed: r.ground_speed,
            wheel_speed_z: wheel_z,
            ground_speed_z,
            torque,
            normal_force: fz,
            fresh: std::array::from_fn(|c| rd.fresh[c]),
        };
        // the filtered speed before this step, carried forward to it by the accelerometer
        let l = self.filter.layout;
        let n = l.n();
        let carried = if restart {
            f64::NAN
        } else {
            self.filter.x[g * n + l.v()] + (r.specific_force_x + g_sin_pitch) * dt
        };
        let f = self.filter.step(g, &sample);
        self.last_stamp[g] = r.stamp;
        let excess = self.ground_speed_excess(g, r.stamp, restart, rd.fresh[4], ground_speed_z, carried);
        let x = &self.filter.x[g * n..(g + 1) * n];
        let wheel_y = self.filter.vehicle.wheel_y;
        let ground: [f64; 4] = std::array::from_fn(|w| x[l.v()] - x[l.psi()] * wheel_y[w]);
        let ws = WheelSample {
            changed: std::array::from_fn(|w| rd.changed[w]),
            full_rate: std::array::from_fn(|w| rd.full_rate[w]),
            prev_speed: std::array::from_fn(|w| rd.prev[w]),
            speed: r.wheel_speed,
            torque,
            torque_fresh: std::array::from_fn(|w| rd.fresh[5 + w]),
            fz,
            ground,
        };
        let speed_pairs = self.intervals.step(g, dt, restart, &ws);
        let torque_pairs = self.intervals.torque_refresh(
            g,
            dt,
            restart,
            &std::array::from_fn(|w| rd.changed[5 + w]),
            &std::array::from_fn(|w| rd.full_rate[5 + w]),
            &std::array::from_fn(|w| r.stamp - rd.changed_before[5 + w]),
            &std::array::from_fn(|w| r.stamp - rd.changed_before[w]),
            &ws,
        );
        Estimate {
            mu: std::array::from_fn(|w| x[w]),
            mu_var: f.mu_var,
            mu_determined: std::array::from_fn(|w| f.mu_var[w] <= rd_cfg.mu_var_determined),
            resistance: f.resistance,
            gross: f.gross,
            gross_var: f.gross_var,
            wheel_speed: std::array::from_fn(|w| x[l.omega() + w]),
            ground_speed: x[l.v()],
            yaw_rate: x[l.psi()],
            rejected: f.rejected,
            speed_rejected: f.speed_rejected,
            reset: f.reset,
            normal_force: fz,
            age: rd.age,
            ground_speed_measured: !r.ground_speed.is_nan(),
            ground_speed_latency: latency,
            ground_speed_excess: excess,
            pairs: speed_pairs.merge(&torque_pairs),
        }
    }

    /// [`Estimate::ground_speed_excess`] of vehicle `g` after a step: a new reading `z` (led by its latency)
    /// against `carried`, the filtered speed before the step carried forward by the accelerometer, enters an
    /// exponentially weighted mean square of memory [`EXCESS_WINDOW`]; a restart forgets it.
    fn ground_speed_excess(&mut self, g: usize, stamp: f64, restart: bool, fresh: bool, z: f64, carried: f64) -> f64 {
        let r_v = self.filter.settings.r[N_MEAS - 1];
        let (ms, last) = &mut self.stray[g];
        if restart {
            (*ms, *last) = (0.0, f64::NAN);
        }
        if fresh && z.is_finite() && carried.is_finite() {
            let nu = z - carried;
            let w = if last.is_nan() {
                1.0
            } else {
                -(-(stamp - *last) / EXCESS_WINDOW).exp_m1()
            };
            *ms += w * (nu * nu - *ms);
            *last = stamp;
        }
        (*ms - r_v).max(0.0).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_non_finite_output_is_named() {
        let mut e = Estimate::default();
        assert_eq!(e.first_non_finite(), None);
        e.pairs.ground_end[2] = f64::NAN;
        assert_eq!(e.first_non_finite(), Some("interval_ground_end"));
        e.gross[0] = f64::INFINITY;
        assert_eq!(e.first_non_finite(), Some("gross"));
        let mut e = Estimate::default();
        e.age[4] = f64::NAN;
        assert_eq!(e.first_non_finite(), Some("ground_speed_age"));
    }
}
