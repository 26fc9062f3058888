//! N vehicles' traction filters (soilocp.estimation.observer_bank.ObserverBank's filter half):
//! the state x, P and the gate counters of each vehicle, stepped for any subset of them.  One
//! step of a vehicle: restart on a first sample, a stamp going backwards or a time gap (a counted
//! reason); eq. 33's model at the sample; the prediction (dt > 0) and the gated update
//! (`kalman`); the low-speed re-anchoring of wheel speeds (docs/method.md §17); the conditioning;
//! the divergence guard (a non-finite or out-of-physics state restarts that vehicle).

use super::kalman::{condition, gated_update, predict, Workspace};
use super::layout::{Layout, N_MEAS};
use super::model::{build, init, resistance_map, Vehicle};
use super::numeric::{matmul, matvec, nan_max};
use super::settings::ObserverSettings;
use super::walk::{walk_variance_scale, weighted_slip, SlipSpread};

/// Reset reasons, in the order of soilocp.estimation.observer_bank.RESET_REASONS (code = index + 1).
pub const RESET_REASONS: [&str; 5] = [
    "start",
    "time_gap",
    "stamp_backwards",
    "non_finite_state",
    "state_out_of_physics",
];
const START: u8 = 1;
const TIME_GAP: u8 = 2;
const STAMP_BACKWARDS: u8 = 3;
const NON_FINITE: u8 = 4;
const OUT_OF_PHYSICS: u8 = 5;

/// The filter's settings: the observer's as declared, and what follows from them for a layout
/// and a vehicle's drive (ObserverSettings::filter).
#[derive(Clone, Debug)]
pub struct Settings {
    /// the observer's settings (the gate, the gap, the anchoring, the conditioning and gravity are
    /// read here)
    pub s: ObserverSettings,
    /// the traction model's zero-slip bridge
    pub bridge_slip: f64,
    /// measurement variances of the 7 rows (the wheel-speed rows doubled for a per-side drive)
    pub r: [f64; N_MEAS],
    /// Q's diagonal, P_0's diagonal, the state's box (n each)
    pub q: Vec<f64>,
    pub p0: Vec<f64>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// |omega_1..4| and |V| above these are divergence
    pub speed_limits: [f64; 5],
}

impl Settings {
    /// The filter's settings of the declared `s` for `layout`: the measurement variances (a side's shared encoder
    /// `per_side` doubles the wheel rows'), Q's and P_0's diagonals, the state's box and the
    /// divergence limits.  `bridge_slip`: the traction model's zero-slip bridge.
    pub fn of(s: &ObserverSettings, layout: &Layout, per_side: bool, bridge_slip: f64) -> Result<Settings, String> {
        if s.discretization != "series" {
            return Err(format!(
                "discretization {:?}: the observer kernel implements 'series' only",
                s.discretization
            ));
        }
        let sq = |v: Vec<f64>| v.into_iter().map(|x| x * x).collect::<Vec<f64>>();
        let r_speed = s.r_wheel_speed * s.r_wheel_speed * if per_side { 2.0 } else { 1.0 };
        let mut r = [r_speed; N_MEAS];
        r[0] = s.r_specific_force * s.r_specific_force;
        r[1] = s.r_yaw_rate * s.r_yaw_rate;
        r[N_MEAS - 1] = s.r_ground_speed * s.r_ground_speed;
        let inf = f64::INFINITY;
        let upper = layout.per_state(
            s.mu_bound,
            s.resistance_bound,
            s.resistance_slope_bound,
            s.lateral_bound,
            inf,
            inf,
            inf,
            s.speed_bias_bound,
        );
        Ok(Settings {
            s: *s,
            bridge_slip,
            r,
            q: sq(layout.per_state(
                s.q_mu,
                s.q_resistance,
                s.q_resistance_slope,
                s.q_lateral,
                s.q_wheel_speed,
                s.q_ground_speed,
                s.q_yaw_rate,
                s.q_speed_bias,
            )),
            p0: sq(layout.per_state(
                s.p0_mu,
                s.p0_resistance,
                s.p0_resistance_slope,
                s.p0_lateral,
                s.r_wheel_speed,
                s.p0_speed,
                s.r_yaw_rate,
                s.p0_speed_bias,
            )),
            lower: upper.iter().map(|u| -u).collect(),
            upper,
            speed_limits: [
                s.max_wheel_speed,
                s.max_wheel_speed,
                s.max_wheel_speed,
                s.max_wheel_speed,
                s.max_ground_speed,
            ],
        })
    }
}

/// One vehicle's sample, as the bank takes it (the Python side has run the readings clock, the
/// torque split, the encoder lead and the ground-speed latency).
pub struct Sample {
    /// s since the vehicle's last sample (NaN: its first), and dt^3
    pub dt: f64,
    pub dt_cubed: f64,
    pub specific_force_x: f64,
    pub yaw_rate: f64,
    pub pitch: f64,
    /// the raw readings (a restart takes them as its state)
    pub wheel_speed: [f64; 4],
    pub ground_speed: f64,
    /// wheel speeds as measured now (reading + encoder lead), the led ground speed (NaN: none)
    pub wheel_speed_z: [f64; 4],
    pub ground_speed_z: f64,
    /// torque per wheel (N m, split per side), normal force (N, >= the lift-off force)
    pub torque: [f64; 4],
    pub normal_force: [f64; 4],
    /// wheel speeds and ground speed that are new readings now (a held one is no measurement)
    pub fresh: [bool; 5],
}

/// What a step gives for one vehicle (beside its state, read from the bank).
#[derive(Clone, Copy, Debug, Default)]
pub struct Step {
    pub mu_var: [f64; 4],
    pub resistance: [f64; 4],
    pub gross: [f64; 4],
    pub gross_var: [f64; 4],
    pub rejected: i64,
    /// per wheel: a new speed reading that the innovation gate rejected (Huber-weighted), or a held one
    /// the filtered speed has left ([`left_its_reading`]), and that did not re-anchor the wheel: its
    /// filtered speed is then the prediction, not the measurement
    pub speed_rejected: [bool; 4],
    /// 0: no reset, else RESET_REASONS[code - 1]
    pub reset: u8,
}

/// docs/method.md §18, "A repeated reading the prediction has left": per wheel, a reading that is no
/// measurement now (a repeat the reading clock judged held, `available` false) that the filtered speed
/// has left by more than `gate_sigma` of the encoder's own noise (|z − ω| > gate_sigma sqrt(R), R the
/// wheel's row of the measurement noise: r_wheel_speed², twice that for a side's shared encoder). The
/// prediction's variance is not in the test: a free-running wheel equation on a poorly known traction
/// state has a P_ωω that excuses any departure, while the slip made of it informs K as a measured one.
/// Between a quantised encoder's changes at a steady speed its flicker drives the traction state, and
/// the prediction runs off the reading (the stall-draft drive of §18). A missing reading (NaN) says nothing.
pub fn left_its_reading(
    l: &Layout,
    x: &[f64],
    z: &[f64; N_MEAS],
    available: &[bool; N_MEAS],
    r: &[f64; N_MEAS],
    gate_sigma: f64,
) -> [bool; 4] {
    std::array::from_fn(|w| {
        let nu = z[2 + w] - x[l.omega() + w];
        !available[2 + w] && nu * nu > gate_sigma * gate_sigma * r[2 + w]
    })
}

pub struct FilterBank {
    pub layout: Layout,
    pub vehicle: Vehicle,
    pub settings: Settings,
    pub n_vehicles: usize,
    /// (N, n), (N, n, n), (N, 7), row-major
    pub x: Vec<f64>,
    pub p: Vec<f64>,
    pub rejections: Vec<i64>,
    pub resets: [u64; 5],
    pub anchored: u64,
    /// per vehicle: the spread of its slips that slows the resistance's walk (`walk`)
    spread: Vec<SlipSpread>,
    /// Q's diagonal at this step (the resistance's walk scaled)
    q: Vec<f64>,
    a: Vec<f64>,
    b: Vec<f64>,
    h: Vec<f64>,
    m: Vec<f64>,
    ws: Workspace,
}

impl FilterBank {
    pub fn new(layout: Layout, vehicle: Vehicle, settings: Settings, n_vehicles: usize) -> Result<FilterBank, String> {
        let n = layout.n();
        for (name, v) in [
            ("q", &settings.q),
            ("p0", &settings.p0),
            ("lower", &settings.lower),
            ("upper", &settings.upper),
        ] {
            if v.len() != n {
                return Err(format!(
                    "settings.{name} must have {n} entries (the state size), got {}",
                    v.len()
                ));
            }
        }
        let (mut a, mut b, mut h) = (vec![0.0; n * n], vec![0.0; n], vec![0.0; N_MEAS * n]);
        init(&layout, &mut a, &mut b, &mut h);
        Ok(FilterBank {
            layout,
            vehicle,
            q: settings.q.clone(),
            settings,
            n_vehicles,
            x: vec![0.0; n_vehicles * n],
            p: vec![0.0; n_vehicles * n * n],
            rejections: vec![0; n_vehicles * N_MEAS],
            resets: [0; 5],
            anchored: 0,
            spread: vec![SlipSpread::default(); n_vehicles],
            a,
            b,
            h,
            m: vec![0.0; 16],
            ws: Workspace::new(n),
        })
    }

    /// Restart vehicle `g`'s filter at the sample's readings (state clipped into its box, P_0,
    /// no rejections), counting the reason.
    fn reset(&mut self, g: usize, s: &Sample, why: u8) {
        let (l, n) = (self.layout, self.layout.n());
        let x = &mut self.x[g * n..(g + 1) * n];
        x.fill(0.0);
        x[l.omega()..l.v()].copy_from_slice(&s.wheel_speed);
        x[l.v()] = if s.ground_speed.is_nan() {
            s.wheel_speed.iter().sum::<f64>() / 4.0 * self.vehicle.wheel_radius
        } else {
            s.ground_speed
        };
        x[l.psi()] = s.yaw_rate;
        for i in 0..n {
            x[i] = super::numeric::clip(x[i], self.settings.lower[i], self.settings.upper[i]);
        }
        let p = &mut self.p[g * n * n..(g + 1) * n * n];
        p.fill(0.0);
        for i in 0..n {
            p[i * n + i] = self.settings.p0[i];
        }
        self.rejections[g * N_MEAS..(g + 1) * N_MEAS].fill(0);
        self.spread[g].reset();
        self.resets[(why - 1) as usize] += 1;
    }

    /// At low speed, a rejected wheel-speed reading re-anchors its wheel's state (docs/method.md
    /// §17, ObserverBank's anchor_wheel_speeds): the state takes the reading, its variance R, its
    /// correlations none; so does a repeated reading the state has left by more than
    /// anchor_speed / 3 in rim speed.  Below anchor_speed (rim and ground) the wheel equation is
    /// stiff and the traction state poorly known: the encoder is the speed's one measurement.
    /// Returns the wheels it re-anchored.
    fn anchor(&mut self, g: usize, z: &[f64; N_MEAS], keep: &[bool; N_MEAS], available: &[bool; N_MEAS]) -> [bool; 4] {
        let (l, n) = (self.layout, self.layout.n());
        let (radius, speed, r) = (
            self.vehicle.wheel_radius,
            self.settings.s.anchor_speed,
            self.settings.r[2],
        );
        let x = &mut self.x[g * n..(g + 1) * n];
        let p = &mut self.p[g * n * n..(g + 1) * n * n];
        let slow_ground = x[l.v()].abs() < speed;
        let mut wheels = [false; 4];
        for (w, on) in wheels.iter_mut().enumerate() {
            let row = 2 + w;
            let away = (x[l.omega() + w] - z[row]).abs() * radius > speed / 3.0;
            let rejected = available[row] && !keep[row];
            *on = (rejected || (!available[row] && away)) && (z[row].abs() * radius < speed) && slow_ground;
        }
        for (w, &on) in wheels.iter().enumerate() {
            if on {
                let c = l.omega() + w;
                x[c] = z[2 + w];
                for j in 0..n {
                    p[c * n + j] = 0.0;
                    p[j * n + c] = 0.0;
                }
                p[c * n + c] = r;
                self.anchored += 1;
            }
        }
        wheels
    }

    /// One step of vehicle `g` (see the module doc).
    pub fn step(&mut self, g: usize, s: &Sample) -> Step {
        let (l, n) = (self.layout, self.layout.n());
        let mut out = Step::default();
        let why = if s.dt.is_nan() {
            START
        } else if s.dt < 0.0 {
            STAMP_BACKWARDS
        } else if s.dt > self.settings.s.max_gap {
            TIME_GAP
        } else {
            0
        };
        if why != 0 {
            self.reset(g, s, why);
            out.reset = why;
        }
        let st = &self.settings;
        resistance_map(
            &l,
            &self.vehicle,
            &self.x[g * n..(g + 1) * n],
            st.s.travel_speed,
            st.bridge_slip,
            &mut self.m,
        );
        let g_sin_pitch = st.s.gravity * s.pitch.sin();
        build(
            &l,
            &self.vehicle,
            &s.normal_force,
            &s.torque,
            g_sin_pitch,
            &self.m,
            &mut self.a,
            &mut self.b,
            &mut self.h,
        );
        if why == 0 {
            let x = &mut self.x[g * n..(g + 1) * n];
            let p = &mut self.p[g * n * n..(g + 1) * n * n];
            if s.dt > 0.0 {
                if l.n_res == 2 {
                    let spread = &mut self.spread[g];
                    spread.update(
                        weighted_slip(&self.m, &s.normal_force),
                        s.dt,
                        st.s.resistance_walk_window,
                    );
                    let f = walk_variance_scale(spread.std(), st.s.resistance_walk_spread);
                    for i in l.res()..l.lat() {
                        self.q[i] = st.q[i] * f;
                    }
                }
                predict(x, p, &self.a, &self.b, &self.q, s.dt, s.dt_cubed, &mut self.ws);
            }
            let no_gs = s.ground_speed_z.is_nan();
            let mut z = [0.0; N_MEAS];
            z[0] = s.specific_force_x;
            z[1] = s.yaw_rate;
            z[2..6].copy_from_slice(&s.wheel_speed_z);
            z[6] = if no_gs { 0.0 } else { s.ground_speed_z };
            let mut available = [true; N_MEAS];
            available[2..7].copy_from_slice(&s.fresh);
            available[6] &= !no_gs;
            let counts = &mut self.rejections[g * N_MEAS..(g + 1) * N_MEAS];
            let gated = gated_update(
                x,
                p,
                &z,
                &st.r,
                &self.h,
                st.s.gate_sigma,
                counts,
                st.s.gate_patience as i64,
                &available,
                &mut self.ws,
            );
            out.rejected = (0..N_MEAS).filter(|&i| available[i] && !gated.keep[i]).count() as i64;
            let anchored = if st.s.anchor_speed > 0.0 {
                self.anchor(g, &z, &gated.keep, &available)
            } else {
                [false; 4]
            };
            let st = &self.settings;
            let x = &mut self.x[g * n..(g + 1) * n];
            let p = &mut self.p[g * n * n..(g + 1) * n * n];
            let left = left_its_reading(&l, x, &z, &available, &st.r, st.s.gate_sigma);
            out.speed_rejected =
                std::array::from_fn(|w| !anchored[w] && ((available[2 + w] && !gated.keep[2 + w]) || left[w]));
            condition(
                x,
                p,
                &st.lower,
                &st.upper,
                st.s.variance_floor,
                st.s.variance_ceiling,
                n,
            );
        }
        // divergence guard
        let x = &self.x[g * n..(g + 1) * n];
        let p = &self.p[g * n * n..(g + 1) * n * n];
        let finite = x.iter().all(|v| v.is_finite()) && p.iter().all(|v| v.is_finite());
        let sane = (0..5).all(|i| x[l.omega() + i].abs() <= self.settings.speed_limits[i]);
        if !finite {
            self.reset(g, s, NON_FINITE);
            out.reset = NON_FINITE;
        } else if !sane {
            self.reset(g, s, OUT_OF_PHYSICS);
            out.reset = OUT_OF_PHYSICS;
        }
        self.output(g, &mut out);
        out
    }

    /// The estimate of vehicle `g` at its state: mu's variances, the resistance M x_res, the gross
    /// traction mu + M x_res and its variance J P J^T with J = [I | M] (determined by the wheel
    /// torque balance even where the net / resistance split is not, docs/method.md §12), floored
    /// since the clamped correlations keep P only nearly positive semi-definite.
    fn output(&mut self, g: usize, out: &mut Step) {
        let (l, n) = (self.layout, self.layout.n());
        let st = &self.settings;
        let x = &self.x[g * n..(g + 1) * n];
        let p = &self.p[g * n * n..(g + 1) * n * n];
        resistance_map(&l, &self.vehicle, x, st.s.travel_speed, st.bridge_slip, &mut self.m);
        if l.n_res > 0 {
            matvec(&self.m, &x[l.res()..l.lat()], &mut out.resistance, 4, l.n_res);
        }
        let mut j = [0.0; 4 * 19];
        for i in 0..4 {
            j[i * n + i] = 1.0;
            for r in 0..l.n_res {
                j[i * n + l.res() + r] = self.m[i * l.n_res + r];
            }
        }
        let mut jp = [0.0; 4 * 19];
        matmul(&j[..4 * n], p, &mut jp[..4 * n], 4, n, n);
        let mut row = [0.0; 19];
        for i in 0..4 {
            for c in 0..n {
                row[c] = jp[i * n + c] * j[i * n + c];
            }
            out.gross_var[i] = nan_max(row[..n].iter().sum(), st.s.variance_floor);
            out.mu_var[i] = p[i * n + i];
            out.gross[i] = x[i] + out.resistance[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_resolve_per_layout() {
        let s = ObserverSettings::default();
        let l = s.layout();
        let f = Settings::of(&s, &l, true, 0.005).unwrap();
        assert_eq!((f.q.len(), f.p0.len(), f.upper.len()), (l.n(), l.n(), l.n()));
        assert_eq!(f.r[2], 2.0 * 0.03 * 0.03);
        assert_eq!((f.upper[0], f.lower[0], f.upper[l.v()]), (1.5, -1.5, f64::INFINITY));
        assert_eq!(f.q[0], 1.0);
    }

    #[test]
    fn expm_is_refused_by_the_kernel() {
        let s = ObserverSettings {
            discretization: "expm",
            ..Default::default()
        };
        assert!(Settings::of(&s, &s.layout(), false, 0.005)
            .unwrap_err()
            .contains("'series' only"));
    }

    #[test]
    fn a_held_reading_the_speed_left_by_more_than_the_gate_of_its_noise_is_flagged() {
        let l = Layout::of("slip").unwrap();
        let mut x = vec![0.0; l.n()];
        x[l.omega()..l.v()].copy_from_slice(&[3.336, 3.50, 3.70, f64::NAN]);
        let mut z = [0.0; N_MEAS];
        z[2..6].copy_from_slice(&[3.336, 3.336, 3.336, 3.336]);
        let (r, gate) = ([0.03f64 * 0.03; N_MEAS], 5.0);
        let mut available = [false; N_MEAS];
        // held readings: on the reading; 0.164 rad/s off (5.5 sigma of R); 0.364 off; a NaN state says nothing
        assert_eq!(
            left_its_reading(&l, &x, &z, &available, &r, gate),
            [false, true, true, false]
        );
        // a new reading is the innovation gate's to judge, not this rule's
        available[2..6].fill(true);
        assert_eq!(left_its_reading(&l, &x, &z, &available, &r, gate), [false; 4]);
        // a missing reading says nothing
        available[2..6].fill(false);
        z[3] = f64::NAN;
        assert!(!left_its_reading(&l, &x, &z, &available, &r, gate)[1]);
    }
}
