//! The slip gate of N vehicles (docs/method.md §6, §9, §10, §13, §17): from the observer's output,
//! each wheel's slip (eq. 1 in its direction of travel), the traction it is compared with, their
//! uncertainties, the low-pass slip the soil gate decides on, the refresh pairs of a slow stream,
//! and whether the wheel may inform K now; the soil bank's [`Sample`] of each vehicle.
//!
//! The observer's output comes packed, one row of [`COLUMNS`] numbers per vehicle (the fields of
//! soilocp.estimation.observer_bank.ObserverBankOutput that the gate reads, in the order of
//! soilocp.estimation.slip_gate.GATE_FIELDS), so that a step is one array across the boundary.

use crate::observer::numeric::{nan_max, nan_min};
use crate::observer::vehicles::{Estimate, QUAD_NAMES as OBSERVER_QUADS};
use crate::slip;
use crate::soil::bank::{likelihood_exponent, Sample};
use crate::soil::params::Params;
use crate::soil::usability::{self, Limits, SLIP_BEYOND_EQ1};

/// The per-wheel fields of a packed row, four columns each from `4 * index`: the observer's rows
/// ([`OBSERVER_QUADS`], in their order, each found by its name when compiled), then the gate's two flags.
pub mod quad {
    use super::OBSERVER_QUADS;

    /// The index of the observer's row `name` (a name that is no row does not compile).
    const fn row(name: &str) -> usize {
        let mut i = 0;
        while i < OBSERVER_QUADS.len() {
            if same(OBSERVER_QUADS[i].as_bytes(), name.as_bytes()) {
                return i;
            }
            i += 1;
        }
        panic!("not a row of the observer's output");
    }

    const fn same(a: &[u8], b: &[u8]) -> bool {
        if a.len() != b.len() {
            return false;
        }
        let mut i = 0;
        while i < a.len() {
            if a[i] != b[i] {
                return false;
            }
            i += 1;
        }
        true
    }

    pub const MU: usize = row("mu");
    pub const MU_VAR: usize = row("mu_var");
    pub const GROSS: usize = row("gross");
    pub const GROSS_VAR: usize = row("gross_var");
    pub const WHEEL_SPEED: usize = row("wheel_speed");
    pub const NORMAL_FORCE: usize = row("normal_force");
    pub const SPEED_AGE: usize = row("speed_age");
    pub const TORQUE_AGE: usize = row("torque_age");
    pub const INTERVAL: usize = row("interval");
    pub const INTERVAL_GROSS: usize = row("interval_gross");
    pub const INTERVAL_GROSS_VAR: usize = row("interval_gross_var");
    pub const INTERVAL_RIM_START: usize = row("interval_rim_start");
    pub const INTERVAL_RIM_END: usize = row("interval_rim_end");
    pub const INTERVAL_GROUND_START: usize = row("interval_ground_start");
    pub const INTERVAL_GROUND_END: usize = row("interval_ground_end");
    pub const INTERVAL_RIM_SIGMA: usize = row("interval_rim_sigma");
    /// bool (0 / 1)
    pub const INTERVAL_LEARNING: usize = OBSERVER_QUADS.len();
    /// bool (0 / 1)
    pub const SPEED_REJECTED: usize = OBSERVER_QUADS.len() + 1;
    pub const COUNT: usize = OBSERVER_QUADS.len() + 2;
}

/// The per-vehicle fields of a packed row, one column each after the quads.
pub mod scalar {
    use super::quad;
    pub const GROUND_SPEED: usize = 4 * quad::COUNT;
    pub const YAW_RATE: usize = GROUND_SPEED + 1;
    /// bool (0 / 1)
    pub const RESET: usize = GROUND_SPEED + 2;
    pub const GROUND_SPEED_AGE: usize = GROUND_SPEED + 3;
    /// bool (0 / 1)
    pub const GROUND_SPEED_MEASURED: usize = GROUND_SPEED + 4;
    /// m/s: the ground speed's stray beyond its assumed noise (observer::vehicles::Estimate::ground_speed_excess)
    pub const GROUND_SPEED_EXCESS: usize = GROUND_SPEED + 5;
    pub const COUNT: usize = 6;
}

/// The names of the gate's own per-wheel flags, after the observer's rows ([`quad`]).
pub const FLAG_NAMES: [&str; 2] = ["interval_learning", "speed_rejected"];

/// The names of the per-wheel fields, in [`quad`]'s order (soilocp.estimation.slip_gate.GATE_QUADS).
pub fn quad_names() -> Vec<&'static str> {
    OBSERVER_QUADS.iter().chain(&FLAG_NAMES).copied().collect()
}

/// The names of the per-vehicle fields, in [`scalar`]'s order (soilocp.estimation.slip_gate.GATE_SCALARS).
pub const SCALAR_NAMES: [&str; scalar::COUNT] = [
    "ground_speed",
    "yaw_rate",
    "reset",
    "ground_speed_age",
    "ground_speed_measured",
    "ground_speed_excess",
];

/// Numbers per vehicle in a packed row.
pub const COLUMNS: usize = scalar::GROUND_SPEED + scalar::COUNT;

/// The packed row of one vehicle's observer estimate (bools as 0 / 1): what
/// soilocp.estimation.slip_gate.pack_output makes of the core's output blocks, for the chain's
/// step, which hands the estimate over without leaving Rust.
pub fn row_of(e: &Estimate) -> [f64; COLUMNS] {
    let p = &e.pairs;
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    let quads = e
        .quads()
        .into_iter()
        .chain([p.active.map(flag), e.speed_rejected.map(flag)]);
    let mut row = [0.0; COLUMNS];
    for (f, q) in quads.enumerate() {
        row[4 * f..4 * f + 4].copy_from_slice(&q);
    }
    row[scalar::GROUND_SPEED] = e.ground_speed;
    row[scalar::YAW_RATE] = e.yaw_rate;
    row[scalar::RESET] = flag(e.reset > 0);
    row[scalar::GROUND_SPEED_AGE] = e.ground_speed_age();
    row[scalar::GROUND_SPEED_MEASURED] = flag(e.ground_speed_measured);
    row[scalar::GROUND_SPEED_EXCESS] = e.ground_speed_excess;
    row
}

/// The gate's settings: the vehicle's and eq. 1's numbers, the soil settings and the usability
/// limits.
#[derive(Clone, Debug, PartialEq)]
pub struct GateParams {
    /// m
    pub wheel_radius: f64,
    /// m, each wheel's lateral position (left > 0)
    pub wheel_y: [f64; 4],
    /// m, (c + d) / 2
    pub half_track: f64,
    /// m g / 4, N
    pub static_load: f64,
    /// 2 for a skid-steer (one torque measurement per side), else 1
    pub shared: f64,
    /// compare gross traction (eq. 3) rather than the net (eq. 6): refresh pairs only then
    pub gross: bool,
    /// N: a wheel at or below this normal force is lifted off
    pub lift_off_force: f64,
    /// m/s: eq. 1's deadband (the pipeline's slip_deadband)
    pub slip_deadband: f64,
    /// m/s: eq. 1's floor (the pipeline's slip_floor)
    pub slip_floor: f64,
    /// the soil settings (the gate reads slip_sigma, speed_sigma, gate_smoothing, fresh_age,
    /// max_input_age and min_load_fraction)
    pub soil: Params,
    pub limits: Limits,
}

/// N vehicles' gate state: each one's [`Memory`] and the stamp it was last stepped at (NaN: never).
#[derive(Clone, Debug)]
pub struct SlipGateBank {
    pub cfg: GateParams,
    pub memory: Vec<Memory>,
    pub lp_stamp: Vec<f64>,
}

/// What one vehicle's gate carries to its next sample: the low-pass slip, the ground speed's age
/// and its last refresh interval (s; NaN: not yet seen).
#[derive(Clone, Copy, Debug)]
pub struct Memory {
    pub lp: [f64; 4],
    pub ground_speed_age: f64,
    pub ground_speed_interval: f64,
}

#[inline]
fn row4(row: &[f64], q: usize) -> [f64; 4] {
    let o = 4 * q;
    [row[o], row[o + 1], row[o + 2], row[o + 3]]
}

/// Eq. 1 in each wheel's direction of travel (§17) and the deadband's measure max(|R_w omega|, |V|),
/// for a refresh interval's end: (body-frame slip, scale, direction).
#[inline]
fn ends(rim: f64, ground: f64, floor: f64) -> (f64, f64, f64) {
    (
        slip::slip(rim, ground, floor),
        slip::scale(rim, ground),
        slip::travel_direction(rim, ground),
    )
}

impl SlipGateBank {
    pub fn new(cfg: GateParams, n: usize) -> Result<Self, String> {
        if n == 0 {
            return Err("slip gate: n_vehicles must be >= 1".into());
        }
        Ok(SlipGateBank {
            cfg,
            memory: vec![
                Memory {
                    lp: [0.0; 4],
                    ground_speed_age: f64::NAN,
                    ground_speed_interval: f64::NAN,
                };
                n
            ],
            lp_stamp: vec![f64::NAN; n],
        })
    }

    /// One sample per vehicle `idx[j]` (distinct, in range): its stamp (s) and its packed observer
    /// output (`rows[j]`, [`COLUMNS`] numbers).  Every sample carries its wheels' refresh spans and
    /// slip ends when any of the k vehicles refreshes a wheel (arrays of the whole
    /// step, as the gate's callers read them), none otherwise.  The [`Sample`]s carry no scale sigma.
    pub fn step(&mut self, idx: &[usize], stamp: &[f64], rows: &[&[f64]]) -> Result<Vec<Sample>, String> {
        let (samples, lps) = self.samples(idx, stamp, rows)?;
        self.commit(idx, stamp, &lps);
        Ok(samples)
    }

    /// [`Self::step`] without touching the state: the samples and each vehicle's new [`Memory`], for
    /// [`Self::commit`] once the caller has accepted them (a refused step leaves the gate as it was).
    pub fn samples(&self, idx: &[usize], stamp: &[f64], rows: &[&[f64]]) -> Result<(Vec<Sample>, Vec<Memory>), String> {
        crate::index::vehicles(idx, self.memory.len())?;
        let cfg = &self.cfg;
        let refreshes = |row: &[f64]| cfg.gross && row4(row, quad::INTERVAL).iter().any(|&v| v > 0.0);
        let any_refresh = rows.iter().any(|r| refreshes(r));
        Ok(idx
            .iter()
            .zip(stamp)
            .zip(rows)
            .map(|((&i, &t), row)| self.one(i, t, row, any_refresh))
            .unzip())
    }

    /// Keep the [`Memory`]s `lps` of [`Self::samples`] as the vehicles' state at `stamp`.
    pub fn commit(&mut self, idx: &[usize], stamp: &[f64], lps: &[Memory]) {
        for ((&i, &t), m) in idx.iter().zip(stamp).zip(lps) {
            self.memory[i] = *m;
            self.lp_stamp[i] = t;
        }
    }

    /// Vehicle `i`'s sample and its new low-pass slip: eq. 1 in the wheel's direction of travel with the
    /// floor and deadband (docs/method.md §6, §10, §17), and the gate's low-pass slip and its
    /// stationary 1-sigma (§9).
    fn one(&self, i: usize, stamp: f64, row: &[f64], any_refresh: bool) -> (Sample, Memory) {
        let cfg = &self.cfg;
        let q = |f: usize| row4(row, f);
        let flag = |f: usize| q(f).map(|v| v != 0.0);
        let (v_body, yaw) = (row[scalar::GROUND_SPEED], row[scalar::YAW_RATE]);
        let reset = row[scalar::RESET] != 0.0;
        let measured = row[scalar::GROUND_SPEED_MEASURED] != 0.0;
        let (wheel_speed, gross, normal_force) = (q(quad::WHEEL_SPEED), q(quad::GROSS), q(quad::NORMAL_FORCE));
        let v_wheel: [f64; 4] = std::array::from_fn(|w| v_body - yaw * cfg.wheel_y[w]);
        let rim = wheel_speed.map(|s| s * cfg.wheel_radius);
        // eq. 1 and the traction law in each wheel's direction of travel (§17): a wheel travelling
        // backwards is the mirror image of one travelling forwards, its slip and its traction both negated
        let direction: [f64; 4] = std::array::from_fn(|w| slip::travel_direction(rim[w], v_wheel[w]));
        let mut slip: [f64; 4] = std::array::from_fn(|w| direction[w] * slip::slip(rim[w], v_wheel[w], cfg.slip_floor));
        let mut scale: [f64; 4] = std::array::from_fn(|w| slip::scale(rim[w], v_wheel[w]));
        let (measure, measure_var) = if cfg.gross {
            (gross, q(quad::GROSS_VAR))
        } else {
            (q(quad::MU), q(quad::MU_VAR))
        };
        let mut observed: [f64; 4] = std::array::from_fn(|w| direction[w] * measure[w]);
        let mut variance = measure_var.map(|v| v * cfg.shared);
        let mut unusable = usability::codes(
            &slip,
            &rim,
            &v_wheel,
            v_body,
            yaw,
            &gross,
            cfg.half_track,
            &cfg.limits,
            cfg.slip_deadband,
        );
        // a slow stream's refresh: the pair from the readings (eq. 13 integrated over a held speed's
        // interval, or at a held torque's refresh) instead of the observer's prediction through the
        // held value; gross only
        let interval = q(quad::INTERVAL);
        let refresh = interval.map(|v| cfg.gross && v > 0.0);
        let filtered_slip = slip; // the low-pass runs on the filtered speeds' slip
        let mut slip_ends = [[0.0; 2]; 4];
        if any_refresh {
            let (r0, r1, g0, g1) = (
                q(quad::INTERVAL_RIM_START),
                q(quad::INTERVAL_RIM_END),
                q(quad::INTERVAL_GROUND_START),
                q(quad::INTERVAL_GROUND_END),
            );
            let (i_gross, i_var) = (q(quad::INTERVAL_GROSS), q(quad::INTERVAL_GROSS_VAR));
            for w in 0..4 {
                let (s0, scale0, d0) = ends(r0[w], g0[w], cfg.slip_floor);
                let (s1, scale1, d1) = ends(r1[w], g1[w], cfg.slip_floor);
                let (s0, s1) = (d1 * s0, d1 * s1);
                // a pair whose interval reverses the travel is no one slip path of one law: not informative
                let scale0 = if d0 == d1 { scale0 } else { 0.0 };
                slip_ends[w] = [s0, s1];
                if refresh[w] {
                    // the slip path's middle; informative only where the wheel moved at both ends
                    slip[w] = 0.5 * (s0 + s1);
                    scale[w] = nan_min(scale0, scale1);
                    observed[w] = d1 * i_gross[w];
                    if s0.abs() > 1.0 || s1.abs() > 1.0 {
                        unusable[w] = SLIP_BEYOND_EQ1;
                    }
                    variance[w] = i_var[w] * cfg.shared;
                }
            }
        }
        // between the refreshes of a slow stream the filtered speed is a prediction and the samples
        // repeat one measurement: K learns from samples within fresh_age of a new reading, and where
        // the interval's own pair is served (interval_learning) at the refresh only
        let (learning, speed_age, torque_age) =
            (flag(quad::INTERVAL_LEARNING), q(quad::SPEED_AGE), q(quad::TORQUE_AGE));
        let held: [bool; 4] = std::array::from_fn(|w| {
            if learning[w] {
                !refresh[w]
            } else {
                speed_age[w] > cfg.soil.fresh_age || torque_age[w] > cfg.soil.fresh_age
            }
        });
        // a wheel whose new speed reading the observer's innovation gate rejected, or whose held reading its
        // prediction left, has a predicted slip, not a measured one (docs/method.md §18): at a torque step the
        // prediction leads the reading and the traction state lags the slip (slip 0.56 for 0.19, gross 0.50
        // for 0.96), and one such pair decided a change of soil after a hold.  A refresh pair is made from the
        // readings and keeps its say; a held wheel informs no K anyway, and keeps its own reason (the readings
        // are held), which the flag would hide
        let rejected = flag(quad::SPEED_REJECTED);
        let informative: [bool; 4] = std::array::from_fn(|w| {
            scale[w] >= cfg.slip_deadband
                && normal_force[w] > cfg.lift_off_force
                && !reset
                && unusable[w] == 0
                && (!rejected[w] || (any_refresh && refresh[w]) || held[w])
        });
        // slip error of eq. 1 at this speed: a speed error dV gives dS ~ dV / V (§6, §9), and a ground speed
        // that strays from the accelerometer's course beyond its assumed noise (a GNSS-grade speed: noisy, late,
        // held between fixes; §20) is that much less certain; a refresh interval's mean rim speed is known only
        // to interval_rim_sigma
        let rim_sigma = q(quad::INTERVAL_RIM_SIGMA);
        // the stray is one error per reading: every sample until the next reading repeats it, and K
        // would count it as many times as those samples' likelihood exponents add up to (§20)
        let last = self.lp_stamp[i];
        let dt = stamp - last;
        let age = row[scalar::GROUND_SPEED_AGE];
        let mem = &self.memory[i];
        let since = mem.ground_speed_age + dt; // the previous reading's age now
        let gs_interval = if since.is_finite() && age < since - 1e-9 {
            since - age // a new reading: the time since the one before it
        } else {
            mem.ground_speed_interval
        };
        let repeats = if dt > 0.0 && gs_interval > dt {
            (gs_interval / dt * likelihood_exponent(&cfg.soil, dt)).max(1.0)
        } else {
            1.0
        };
        let speed_sigma = cfg
            .soil
            .speed_sigma
            .hypot(row[scalar::GROUND_SPEED_EXCESS] * repeats.sqrt());
        let slip_sigma: [f64; 4] = std::array::from_fn(|w| {
            let s = cfg.soil.slip_sigma.hypot(speed_sigma / nan_max(scale[w], 1e-3));
            if any_refresh && refresh[w] {
                s.hypot(rim_sigma[w] / nan_max(scale[w], 1e-3))
            } else {
                s
            }
        });
        // the low-pass slip the gate decides on (§9): gating on the raw, noisy slip keeps the samples
        // whose noise pushed |S| up and biases K
        let tau = cfg.soil.gate_smoothing;
        let mut restart = last.is_nan() || reset || dt <= 0.0 || dt > 1.0;
        let alpha = if tau > 0.0 {
            if restart {
                1.0
            } else {
                -((-dt) / tau).exp_m1()
            }
        } else {
            restart = true;
            1.0
        };
        let prev = self.memory[i].lp;
        let lp: [f64; 4] = std::array::from_fn(|w| {
            if restart {
                filtered_slip[w]
            } else {
                prev[w] + alpha * (filtered_slip[w] - prev[w])
            }
        });
        let shrink = (alpha / (2.0 - alpha)).sqrt(); // stationary std of low-passed white noise
        let mut gate_slip = lp;
        let mut gate_sigma = slip_sigma.map(|s| s * shrink);
        // between refreshes the low-pass follows a prediction: the gate takes the interval's slip
        for w in 0..4 {
            if any_refresh && refresh[w] {
                gate_slip[w] = slip[w];
                gate_sigma[w] = slip_sigma[w];
            }
        }
        let min_load = cfg.soil.min_load_fraction * cfg.static_load;
        // the codes judge measured speeds and torques: between a slow stream's refreshes the filtered
        // speed is a prediction, and a held wheel informs no K anyway
        let unusable: [i64; 4] = std::array::from_fn(|w| if held[w] || !measured { 0 } else { unusable[w] as i64 });
        let sample = Sample {
            vehicle: i,
            stamp,
            slip,
            observed,
            variance,
            slip_sigma,
            gate_slip,
            gate_sigma,
            informative: std::array::from_fn(|w| informative[w] && measured && normal_force[w] >= min_load),
            held,
            ground_stale: row[scalar::GROUND_SPEED_AGE] > cfg.soil.max_input_age,
            identifiable: measured,
            speed: v_body,
            span: any_refresh.then(|| std::array::from_fn(|w| if refresh[w] { interval[w] } else { 0.0 })),
            slip_ends: any_refresh.then_some(slip_ends),
            unusable,
            scale_sigma: None,
        };
        let memory = Memory {
            lp,
            ground_speed_age: age,
            ground_speed_interval: gs_interval,
        };
        (sample, memory)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_estimate_packs_into_its_named_columns() {
        let mut e = Estimate {
            mu: [0.1, 0.2, 0.3, 0.4],
            gross_var: [1.0, 2.0, 3.0, 4.0],
            age: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0],
            ground_speed: 1.5,
            reset: 3,
            ground_speed_measured: true,
            ..Default::default()
        };
        e.pairs.active = [true, false, false, true];
        e.pairs.rim_sigma = [0.5; 4];
        e.speed_rejected = [false, true, false, false];
        let row = row_of(&e);
        let at = |f: usize| &row[4 * f..4 * f + 4];
        assert_eq!(at(quad::MU), &e.mu);
        assert_eq!(at(quad::GROSS_VAR), &e.gross_var);
        assert_eq!(at(quad::SPEED_AGE), &[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(at(quad::TORQUE_AGE), &[6.0, 7.0, 8.0, 9.0]);
        assert_eq!(at(quad::INTERVAL_RIM_SIGMA), &[0.5; 4]);
        assert_eq!(at(quad::INTERVAL_LEARNING), &[1.0, 0.0, 0.0, 1.0]);
        assert_eq!(at(quad::SPEED_REJECTED), &[0.0, 1.0, 0.0, 0.0]);
        assert_eq!(row[scalar::GROUND_SPEED], 1.5);
        assert_eq!(row[scalar::RESET], 1.0);
        assert_eq!(row[scalar::GROUND_SPEED_AGE], 5.0);
        assert_eq!(row[scalar::GROUND_SPEED_MEASURED], 1.0);
    }

    #[test]
    fn names_follow_the_column_indices() {
        let names = quad_names();
        assert_eq!(names.len(), quad::COUNT);
        for (i, name) in [
            (quad::MU, "mu"),
            (quad::GROSS, "gross"),
            (quad::INTERVAL_RIM_SIGMA, "interval_rim_sigma"),
            (quad::INTERVAL_LEARNING, "interval_learning"),
            (quad::SPEED_REJECTED, "speed_rejected"),
        ] {
            assert_eq!(names[i], name);
        }
        let scalars = [
            (scalar::GROUND_SPEED, "ground_speed"),
            (scalar::YAW_RATE, "yaw_rate"),
            (scalar::RESET, "reset"),
            (scalar::GROUND_SPEED_AGE, "ground_speed_age"),
            (scalar::GROUND_SPEED_MEASURED, "ground_speed_measured"),
            (scalar::GROUND_SPEED_EXCESS, "ground_speed_excess"),
        ];
        for (i, name) in scalars {
            assert_eq!(SCALAR_NAMES[i - scalar::GROUND_SPEED], name);
        }
        assert_eq!(COLUMNS, 4 * quad::COUNT + SCALAR_NAMES.len());
    }

    fn params() -> GateParams {
        GateParams {
            wheel_radius: 0.15,
            wheel_y: [0.25, 0.25, -0.25, -0.25],
            half_track: 0.25,
            static_load: 100.0,
            shared: 1.0,
            gross: true,
            lift_off_force: 1.0,
            slip_deadband: 0.15,
            slip_floor: 0.05,
            soil: Params::default(),
            limits: Limits::default(),
        }
    }

    fn row(omega: f64, v: f64) -> Vec<f64> {
        let mut r = vec![0.0; COLUMNS];
        for w in 0..4 {
            r[4 * quad::WHEEL_SPEED + w] = omega;
            r[4 * quad::GROSS + w] = 0.3;
            r[4 * quad::GROSS_VAR + w] = 1e-4;
            r[4 * quad::NORMAL_FORCE + w] = 100.0;
        }
        r[scalar::GROUND_SPEED] = v;
        r[scalar::GROUND_SPEED_MEASURED] = 1.0;
        r
    }

    #[test]
    fn slip_of_eq1_and_the_low_pass() {
        let mut g = SlipGateBank::new(params(), 2).unwrap();
        // 1.25 m/s rim over 1 m/s ground: S = 0.2 (§6), informative, and the low-pass starts at it
        let r = row(1.25 / 0.15, 1.0);
        let s = g.step(&[1], &[0.0], &[&r]).unwrap();
        assert!((s[0].slip[0] - 0.2).abs() < 1e-12);
        assert_eq!(s[0].informative, [true; 4]);
        assert_eq!(s[0].gate_slip, s[0].slip);
        assert!(s[0].span.is_none());
        // 10 ms later at S = 0: the low-pass moves by 1 - exp(-0.01 / 0.15) of the way
        let r = row(1.0 / 0.15, 1.0);
        let s = g.step(&[1], &[0.01], &[&r]).unwrap();
        let alpha = 1.0 - (-0.01f64 / 0.15).exp();
        assert!((s[0].gate_slip[0] - 0.2 * (1.0 - alpha)).abs() < 1e-12);
        assert!(g.lp_stamp[0].is_nan());
        assert!(g.step(&[2], &[0.0], &[&r]).is_err());
    }

    #[test]
    fn reversing_wheel_drives_in_its_direction_of_travel() {
        let mut g = SlipGateBank::new(params(), 1).unwrap();
        let r = row(-0.45 / 0.15, -0.04 - 1e-12);
        let s = g.step(&[0], &[0.0], &[&r]).unwrap();
        assert!((s[0].slip[0] - 0.41 / 0.45).abs() < 1e-9);
        assert!((s[0].observed[0] + 0.3).abs() < 1e-15);
    }

    /// A ground speed read at 5 Hz by 100 Hz samples, straying 0.05 m/s beyond its noise: each
    /// reading's error is repeated by the 20 samples until the next, whose likelihood exponents
    /// add up to 20 x 0.15 = 3, so the stray enters the slip's 1-sigma sqrt(3) times; a reading
    /// at every sample, once.
    #[test]
    fn a_held_reading_s_stray_counts_once_per_reading() {
        let sigma_at = |refresh: usize| {
            let p = params();
            let mut g = SlipGateBank::new(p.clone(), 1).unwrap();
            let mut last = [0.0; 4];
            for i in 0..100 {
                let mut r = row(1.25 / 0.15, 1.0);
                r[scalar::GROUND_SPEED_AGE] = 0.01 * (i % refresh) as f64;
                r[scalar::GROUND_SPEED_EXCESS] = 0.05;
                last = g.step(&[0], &[0.01 * i as f64], &[&r]).unwrap()[0].slip_sigma;
            }
            let s = p.soil;
            let want = |repeats: f64| s.slip_sigma.hypot(s.speed_sigma.hypot(0.05 * repeats.sqrt()) / 1.25);
            (last[0], want(1.0), want(20.0 * likelihood_exponent(&s, 0.01)))
        };
        let (got, once, _) = sigma_at(1);
        assert!((got - once).abs() < 1e-12, "{got} {once}");
        let (got, once, repeated) = sigma_at(20);
        assert!(
            (got - repeated).abs() < 1e-12 && repeated > 1.3 * once,
            "{got} {repeated} {once}"
        );
    }
}
