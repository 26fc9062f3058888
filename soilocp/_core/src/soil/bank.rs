//! N vehicles' grid Bayes filters over ln K (docs/method.md §9), stepped together: one call per
//! step for k selected vehicles.  Per vehicle: the pooled belief p, the no-change belief p_stay
//! with its posterior probability and the recent evidence for a change, the window statistics
//! (evidence, NIS, the systematic budget's sums), the scale profile, the scale's systematic term
//! and the axle check.

use crate::observer::numeric::sign;
use crate::soil::axles::{AxleCheck, AxleVerdict};
use crate::soil::grid::Grid;
use crate::soil::numeric::{grid_sum, row_top};
use crate::soil::params::Params;
use crate::soil::scale::{scale_shift_with, ScaleNodes, ScaleScratch};

/// Per-wheel flags of a step's result (`Step::wheel`).
pub const USED: u8 = 1;
/// gated by slip but the torque balance does not determine the gross traction (§12)
pub const UNDETERMINED: u8 = 2;
/// gated by slip but the wheel's readings (or the ground speed) are held / stale
pub const HELD: u8 = 4;

/// One vehicle's sample.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    pub vehicle: usize,
    pub stamp: f64,
    pub slip: [f64; 4],
    pub observed: [f64; 4],
    pub variance: [f64; 4],
    pub slip_sigma: [f64; 4],
    pub gate_slip: [f64; 4],
    pub gate_sigma: [f64; 4],
    pub informative: [bool; 4],
    pub held: [bool; 4],
    pub ground_stale: bool,
    pub identifiable: bool,
    /// m/s (NaN: unknown)
    pub speed: f64,
    /// s a wheel's pair stands for (a refresh interval; 0: the sample's own), if any is given
    pub span: Option<[f64; 4]>,
    /// a refresh pair's slip at its interval's start and end, if given
    pub slip_ends: Option<[[f64; 2]; 4]>,
    /// wheel_usability's code per wheel (0: the longitudinal model describes it)
    pub unusable: [i64; 4],
    /// the torque scale's relative 1-sigma now (the online state), if given
    pub scale_sigma: Option<f64>,
}

/// What one vehicle's update gives the Python side (its status logic and band).
#[derive(Clone, Copy, Debug)]
pub struct Step {
    pub wheel: [u8; 4],
    pub dt: f64,
    /// the belief was updated by data
    pub informed: bool,
    /// a change was taken (the no-change belief restarted)
    pub taken: bool,
    pub k_report: f64,
    /// half the 16-84 % interval of the pooled belief in ln K
    pub log_stat: f64,
    /// evidence (s), NIS sum, sum w h_K^2, sum w h_K h, sum w h_K h_S dS
    pub stats: [f64; 5],
    /// systematic 1-sigma of ln K from the scale, c's mean and 1-sigma
    pub scale: [f64; 3],
    pub axle: AxleVerdict,
    /// the pooled belief's mid-point CDF at the weakest fitted soil (> 1/2: mostly below it)
    pub floor_cdf: f64,
}

/// One vehicle's state.
#[derive(Clone, Debug)]
pub struct Belief {
    pub p: Vec<f64>,
    pub p_stay: Vec<f64>,
    pub w_stay: f64,
    pub stay_llr: f64,
    pub last_stamp: f64,
    pub stats: [f64; 5],
    /// the window's per-node sums of the scale profile: sum w obs h(theta), sum w h(theta)^2
    pub profile: [Vec<f64>; 2],
    pub scale_sys: [f64; 3],
    pub scale_prior: f64,
    pub axles: AxleCheck,
}

impl Belief {
    fn new(g: usize, scale_sigma: f64) -> Belief {
        let u = vec![1.0 / g as f64; g];
        Belief {
            p: u.clone(),
            p_stay: u,
            w_stay: 1.0,
            stay_llr: 0.0,
            last_stamp: f64::NAN,
            stats: [0.0; 5],
            profile: [vec![0.0; g], vec![0.0; g]],
            scale_sys: [0.0, 1.0, scale_sigma],
            scale_prior: scale_sigma,
            axles: AxleCheck::new(g),
        }
    }
}

/// The bank: the grid, the settings and N vehicles' beliefs.
#[derive(Clone, Debug)]
pub struct SoilGridBank {
    pub grid: Grid,
    pub cfg: Params,
    pub nodes: ScaleNodes,
    /// the first node at or above the weakest fitted soil's K / 2
    pub floor_idx: usize,
    pub vehicles: Vec<Belief>,
    /// the rows a step works in, kept between steps (a step allocates nothing)
    scratch: Scratch,
}

/// A used wheel's pair within one step: its likelihood's pieces; its rows (the curve h, dh/dS,
/// r^2 and the tempered log-likelihood on the grid) are row `j` of [`Scratch`]'s, j its index
/// among the step's pairs.
#[derive(Clone, Copy, Debug, Default)]
struct Pair {
    wheel: usize,
    slip: f64,
    observed: f64,
    sig2: f64,
    exponent: f64,
    span: Option<f64>,
}

/// The grid rows of one step (G each): up to four pairs' rows, the refresh interval's end
/// curves, the beliefs' products and the window's sums.  Sized on the first step.
#[derive(Clone, Debug, Default)]
struct Scratch {
    h: [Vec<f64>; 4],
    d: [Vec<f64>; 4],
    r2: [Vec<f64>; 4],
    loglike: [Vec<f64>; 4],
    ends: [Vec<f64>; 4],
    /// the pairs' summed log-likelihood, then the likelihood relative to its top
    like: Vec<f64>,
    post: Vec<f64>,
    post_stay: Vec<f64>,
    cdf: Vec<f64>,
    /// the prediction's kernel row, the no-change belief's forgetting
    q: Vec<f64>,
    axle_acc: Vec<f64>,
    axle_post: Vec<f64>,
    oh: Vec<f64>,
    hh: Vec<f64>,
    scale: ScaleScratch,
}

impl Scratch {
    fn size(&mut self, g: usize) {
        if self.like.len() == g {
            return;
        }
        let rows = self.h.iter_mut().chain(&mut self.d).chain(&mut self.r2);
        let rows = rows.chain(&mut self.loglike).chain(&mut self.ends);
        let more = [
            &mut self.like,
            &mut self.post,
            &mut self.post_stay,
            &mut self.cdf,
            &mut self.q,
            &mut self.axle_acc,
            &mut self.axle_post,
            &mut self.oh,
            &mut self.hh,
        ];
        for v in rows.chain(more) {
            v.clear();
            v.resize(g, 0.0);
        }
    }
}

impl SoilGridBank {
    pub fn new(grid: Grid, cfg: Params, nodes: ScaleNodes, k_floor: f64, n: usize) -> Result<Self, String> {
        if nodes.z.len() != nodes.log_prior.len() || nodes.z.len() < 3 {
            return Err("soil bank: the scale nodes need z and log prior of one length >= 3".into());
        }
        let floor_idx = grid.k.partition_point(|&k| k < k_floor);
        let g = grid.len();
        let vehicles = (0..n).map(|_| Belief::new(g, cfg.gross_scale_sigma)).collect();
        Ok(SoilGridBank {
            grid,
            cfg,
            nodes,
            floor_idx,
            vehicles,
            scratch: Scratch::default(),
        })
    }

    /// Start vehicle `i`'s beliefs over from `p` (G, a normalised belief, e.g. a map cell's):
    /// the evidence window restarts, as when a change is taken.
    pub fn start_belief(&mut self, i: usize, p: &[f64]) -> Result<(), String> {
        let g = self.grid.len();
        let b = self
            .vehicles
            .get_mut(i)
            .ok_or_else(|| format!("vehicle {i} out of range"))?;
        if p.len() != g || !p.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(format!("belief must be {g} finite values >= 0"));
        }
        b.p = p.to_vec();
        b.p_stay = p.to_vec();
        b.w_stay = 1.0;
        b.stay_llr = 0.0;
        b.stats = [0.0; 5];
        b.profile = [vec![0.0; g], vec![0.0; g]];
        Ok(())
    }

    /// The wheels of a sample that inform K (`USED`), and why a gated wheel does not.  The gate
    /// decides on the smoothed slip, which must agree in sign with the slip the curve is
    /// evaluated at, itself away from zero (a fast reversal leaves the smoothed slip behind).
    fn wheel_flags(&self, s: &Sample) -> [u8; 4] {
        let c = &self.cfg;
        std::array::from_fn(|w| {
            let a = s.gate_slip[w].abs();
            let gated = s.informative[w]
                && a >= c.slip_min
                && a <= c.slip_max
                && a >= c.slip_snr * s.gate_sigma[w]
                && sign(s.gate_slip[w]) == sign(s.slip[w])
                && s.slip[w].abs() >= 0.5 * c.slip_min;
            let determined = s.variance[w] <= c.observable_max_gross_sigma * c.observable_max_gross_sigma;
            let held = s.held[w] || s.ground_stale;
            let used = gated && determined && !held && s.identifiable && s.unusable[w] == 0;
            u8::from(used) * USED + u8::from(gated && !determined) * UNDETERMINED + u8::from(gated && held) * HELD
        })
    }

    /// One step for k distinct vehicles: the update of each and what its status needs.
    pub fn step(&mut self, samples: &[Sample]) -> Result<Vec<Step>, String> {
        let idx: Vec<usize> = samples.iter().map(|s| s.vehicle).collect();
        crate::index::vehicles(&idx, self.vehicles.len())?;
        let flags: Vec<[u8; 4]> = samples.iter().map(|s| self.wheel_flags(s)).collect();
        // the reference evaluates the curve of a step's pairs in one batch: one slip inside the
        // zero-slip bridge sends the whole batch through the law (Grid::curve)
        let used = |j: usize, w: usize| flags[j][w] & USED != 0;
        let mut bridged = [false; 3];
        for (j, s) in samples.iter().enumerate() {
            for w in 0..4 {
                if !used(j, w) {
                    continue;
                }
                bridged[0] |= self.grid.in_bridge(s.slip[w]);
                if let (Some(ends), Some(span)) = (s.slip_ends, s.span) {
                    if span[w] > 0.0 && ends[w].iter().all(|v| v.is_finite()) {
                        bridged[1] |= self.grid.in_bridge(ends[w][0]);
                        bridged[2] |= self.grid.in_bridge(ends[w][1]);
                    }
                }
            }
        }
        Ok(samples
            .iter()
            .zip(&flags)
            .map(|(s, f)| self.step_one(s, *f, bridged))
            .collect())
    }

    /// One vehicle's update.  Its loops over the grid run in vector registers; where the CPU has
    /// AVX2 the whole update is compiled a second time for it (four f64 lanes instead of two),
    /// chosen at run time.  Both copies do the same IEEE operations in the same order (no FMA:
    /// Rust does not contract a x b + c), so they give the same numbers to the bit.
    fn step_one(&mut self, s: &Sample, wheel: [u8; 4], bridged: [bool; 3]) -> Step {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked on the line above)
            return unsafe { self.step_one_avx2(s, wheel, bridged) };
        }
        self.step_one_body(s, wheel, bridged)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn step_one_avx2(&mut self, s: &Sample, wheel: [u8; 4], bridged: [bool; 3]) -> Step {
        self.step_one_body(s, wheel, bridged)
    }

    #[inline(always)]
    fn step_one_body(&mut self, s: &Sample, wheel: [u8; 4], bridged: [bool; 3]) -> Step {
        let grid = &self.grid;
        let cfg = &self.cfg;
        let g = grid.len();
        let w = &mut self.scratch;
        w.size(g);
        let b = &mut self.vehicles[s.vehicle];
        let dt = s.stamp - b.last_stamp;
        let pred = !b.last_stamp.is_nan() && dt > 0.0;
        if pred {
            let v = if s.speed.is_nan() { cfg.unknown_speed } else { s.speed }.abs();
            let dist = v * dt;
            let (q_log_k, per_metre) = (cfg.q_log_k, cfg.change_per_metre);
            grid.predict_with(&mut b.p, dt, dist, q_log_k, per_metre, &mut w.q);
            // the no-change belief diffuses without the change prior: no distance
            grid.predict_with(&mut b.p_stay, dt, 0.0, q_log_k, per_metre, &mut w.q);
            for axle in b.axles.p.iter_mut() {
                grid.predict_with(axle, dt, dist, q_log_k, per_metre, &mut w.q);
            }
            let hz = (cfg.change_per_metre * dist).min(1.0);
            b.w_stay *= 1.0 - hz; // P(no change over this step)
            if cfg.stay_forgetting > 0.0 {
                // the no-change belief's memory (report_median)
                let a = 1.0 - cfg.stay_forgetting * hz;
                // nodes at the 1e-300 floor all take the same power: one pow for them, made at
                // the first such node (most steps have none)
                let mut floor = f64::NAN;
                for (q, &v) in w.q.iter_mut().zip(&b.p_stay) {
                    let x = v.max(1e-300);
                    *q = if x == 1e-300 {
                        if floor.is_nan() {
                            floor = x.powf(a);
                        }
                        floor
                    } else {
                        x.powf(a)
                    };
                }
                let total = grid_sum(&w.q);
                for (p, v) in b.p_stay.iter_mut().zip(&w.q) {
                    *p = v / total;
                }
            }
        }
        b.last_stamp = s.stamp;
        let decay = if pred { (-dt / cfg.evidence_window).exp() } else { 1.0 };
        for v in b.stats.iter_mut() {
            *v *= decay;
        }
        for row in b.profile.iter_mut() {
            for v in row.iter_mut() {
                *v *= decay;
            }
        }
        let exponent = likelihood_exponent(cfg, if pred { dt } else { f64::NAN });
        let mut informed = false;
        let mut pairs = [Pair::default(); 4];
        let mut n_pairs = 0;
        for wh in (0..4).filter(|&wh| wheel[wh] & USED != 0) {
            let j = n_pairs;
            n_pairs += 1;
            let (h, d) = (&mut w.h[j], &mut w.d[j]);
            grid.curve(s.slip[wh], bridged[0], h, d);
            let span = s.span.map(|sp| sp[wh]);
            if let (Some(ends), Some(sp)) = (s.slip_ends, span) {
                // a refresh interval's pair: its mean gross traction against the curve
                // averaged over the interval's slip path (Simpson's rule)
                if sp > 0.0 && ends[wh].iter().all(|v| v.is_finite()) {
                    let [h0, d0, h1, d1] = &mut w.ends;
                    grid.curve(ends[wh][0], bridged[1], h0, d0);
                    grid.curve(ends[wh][1], bridged[2], h1, d1);
                    for i in 0..g {
                        h[i] = (h0[i] + 4.0 * h[i] + h1[i]) / 6.0;
                        d[i] = (d0[i] + 4.0 * d[i] + d1[i]) / 6.0;
                    }
                }
            }
            pairs[j] = Pair {
                wheel: wh,
                slip: s.slip[wh],
                observed: s.observed[wh],
                sig2: 0.0,
                exponent,
                span,
            };
        }
        let pairs = &mut pairs[..n_pairs];
        if !pairs.is_empty() {
            // the slip term of the variance at the prior belief's median, the same for every K
            // (docs/method.md §9, quasi-likelihood): per K it would pull K to the flattest curve
            let reference = Grid::median_node(Grid::cdf_into(&b.p, &mut w.cdf), 0, g - 1);
            let ms2 = cfg.model_sigma * cfg.model_sigma;
            for (j, pr) in pairs.iter_mut().enumerate() {
                let wh = pr.wheel;
                let dh = w.d[j][reference] * s.slip_sigma[wh];
                pr.sig2 = s.variance[wh] + ms2 + dh * dh;
                let (obs, sig2) = (pr.observed, pr.sig2);
                for (r2, &h) in w.r2[j].iter_mut().zip(&w.h[j]) {
                    *r2 = (obs - h) * (obs - h) / sig2;
                }
                // one pair is one observation: a refresh interval's pair weighs its own interval, at most 1
                if let Some(sp) = pr.span {
                    if sp > 0.0 {
                        pr.exponent = (cfg.temper * sp / cfg.temper_interval).min(1.0);
                    }
                }
                tempered_loglike(&w.r2[j], sig2, cfg.outlier_prob, pr.exponent, &mut w.loglike[j]);
            }
            // the pairs' sum in their order, the first row copied (as loglike[0].clone() += ...)
            w.like.copy_from_slice(&w.loglike[0]);
            for ll in &w.loglike[1..pairs.len()] {
                for (a, &l) in w.like.iter_mut().zip(ll) {
                    *a += l;
                }
            }
            let mut wheels = [0usize; 4];
            for (wv, pr) in wheels.iter_mut().zip(pairs.iter()) {
                *wv = pr.wheel;
            }
            b.axles.update_with(
                s.stamp,
                &wheels[..pairs.len()],
                &w.loglike[..pairs.len()],
                &mut w.axle_acc,
                &mut w.axle_post,
            );
            let top = row_top(&w.like);
            for l in w.like.iter_mut() {
                *l = (*l - top).exp();
            }
            for (((post, post_stay), &l), (&p, &p_stay)) in w
                .post
                .iter_mut()
                .zip(w.post_stay.iter_mut())
                .zip(&w.like)
                .zip(b.p.iter().zip(&b.p_stay))
            {
                *post = p * l;
                *post_stay = p_stay * l;
            }
            let (total, total_stay) = (grid_sum(&w.post), grid_sum(&w.post_stay));
            if total > 0.0 && total.is_finite() {
                for (p, v) in b.p.iter_mut().zip(&w.post) {
                    *p = v / total;
                }
                // Bayes on the two hypotheses: P(no change | data) = P(no change) Z_stay / Z_pooled
                b.w_stay = (b.w_stay * total_stay / total).clamp(0.0, 1.0);
                if cfg.change_evidence > 0.0 {
                    // the data's own say, ln Z_stay / Z_pooled, over the last change_evidence s
                    let fade = (-(if pred { dt.min(1.0) } else { 0.0 }) / cfg.change_evidence).exp();
                    b.stay_llr = b.stay_llr * fade + (total_stay.max(1e-300) / total).ln();
                }
                if total_stay > 0.0 {
                    for (p, v) in b.p_stay.iter_mut().zip(&w.post_stay) {
                        *p = v / total_stay;
                    }
                }
                informed = true;
            }
        }
        let cdf = Grid::cdf_into(&b.p, &mut w.cdf);
        let (k_report, taken) = report_median(grid, cfg, b, cdf, &mut w.q);
        if taken {
            // the window's statistics were gathered on the old soil
            b.stats = [0.0; 5];
            for row in b.profile.iter_mut() {
                row.fill(0.0);
            }
        }
        if !pairs.is_empty() {
            let rows = Rows {
                h: &w.h,
                d: &w.d,
                r2: &w.r2,
            };
            window_stats(grid, b, pairs, &rows, cdf, dt, [&mut w.oh, &mut w.hh]);
        }
        if let Some(sigma) = s.scale_sigma {
            b.scale_prior = sigma;
        }
        if !pairs.is_empty() || taken {
            let sigma = match s.scale_sigma {
                Some(_) => b.scale_prior,
                None => cfg.gross_scale_sigma,
            };
            b.scale_sys = scale_shift_with(
                &b.profile[0],
                &b.profile[1],
                sigma,
                &self.nodes,
                &grid.theta,
                grid.dtheta,
                &mut w.scale,
            );
        }
        let [q16, _, q84] = grid.quantiles(cdf);
        let floor_cdf = cdf[self.floor_idx.min(g - 1)];
        let [s_kk, s_kh] = [b.stats[2], b.stats[3]];
        let sens = if s_kk > 0.0 { s_kh.abs() / s_kk } else { 0.0 }; // d ln K per relative scale
        let tolerance = cfg.axle_scale_sigma * sens;
        let axle = b.axles.judge_with(grid, cfg, s.stamp, dt, tolerance, &mut w.q);
        Step {
            wheel,
            dt,
            informed,
            taken,
            k_report,
            log_stat: (q84 - q16) / 2.0,
            stats: b.stats,
            scale: b.scale_sys,
            axle,
            floor_cdf,
        }
    }
}

/// A pair's tempered log-likelihood on the grid, `exponent` x ln((1 - op) e^{-r2/2} / sigma + op)
/// from its r^2 row, sigma^2 = `sig2`, the outlier weight op (docs/method.md §9).
///
/// Where e^{-r2/2} is so small that the first term is below half an ulp of op, the sum
/// rounds to op exactly, and its logarithm is ln(op): such nodes (a fifth of them on the bench's
/// drive) take ln(op) x exponent, computed once, without their exp and ln.  The cut is
/// conservative: e^x < B = op sigma 2^-55 for every x < ln B - 1 (libm's exp and ln are within
/// an ulp), then (1 - op) e^x / sigma < op 2^-54 after rounding, below half an ulp of op.
#[inline(always)]
fn tempered_loglike(r2: &[f64], sig2: f64, op: f64, exponent: f64, out: &mut [f64]) {
    let root = sig2.sqrt();
    let like = |r2: f64| (1.0 - op) * (-0.5 * r2).exp() / root + op;
    // op and sigma in a range where every bound below is a normal number (else: no cut)
    let cut = if op > 1e-250 && op < 1.0 && root > 1e-30 && root < 1e30 {
        (op * root * (f64::EPSILON / 8.0)).ln() - 1.0 // EPSILON / 8 = 2^-55
    } else {
        f64::NEG_INFINITY
    };
    let floor = op.ln() * exponent;
    for (o, &r2) in out.iter_mut().zip(r2) {
        *o = if -0.5 * r2 < cut {
            floor
        } else {
            like(r2).ln() * exponent
        };
    }
}

/// The pairs' grid rows a step's window statistics read (row j: pair j).
struct Rows<'a> {
    h: &'a [Vec<f64>; 4],
    d: &'a [Vec<f64>; 4],
    r2: &'a [Vec<f64>; 4],
}

/// A sample's likelihood exponent `dt` s after the vehicle's previous one (NaN: no interval
/// known): temper x dt / temper_interval, at most temper_max (docs/method.md §9, "Information per
/// second": what a second of samples says about K is the same at any rate).
pub fn likelihood_exponent(cfg: &Params, dt: f64) -> f64 {
    let step = if dt.is_nan() { cfg.temper_interval } else { dt };
    (cfg.temper * step / cfg.temper_interval).min(cfg.temper_max)
}

/// The K the vehicle reports and whether a change is taken now (docs/method.md §9, "Reporting
/// across a possible change"): the no-change belief's median until a change is the more probable
/// hypothesis (w < 1/2) and the recent data favour it (stay_llr < 0); then the no-change belief
/// restarts from the pooled one, whose median is reported.  change_evidence 0: always the pooled
/// median, no change taken.
#[inline(always)]
fn report_median(grid: &Grid, cfg: &Params, b: &mut Belief, cdf: &[f64], scratch: &mut [f64]) -> (f64, bool) {
    let (changed, taken) = if cfg.change_evidence > 0.0 {
        let t = b.w_stay < 0.5 && b.stay_llr < 0.0;
        (t, t)
    } else {
        (true, false)
    };
    if changed {
        b.p_stay.clone_from(&b.p);
        b.w_stay = 1.0;
        b.stay_llr = 0.0;
    }
    let theta = if changed {
        grid.median(cdf)
    } else {
        grid.median(Grid::cdf_into(&b.p_stay, scratch))
    };
    (theta.exp(), taken)
}

/// Accumulate the window's NIS at the posterior median, the systematic budget's sums and the
/// scale profile's per-node sums, weighted as the belief weighs the samples (exponent /
/// variance); a refresh interval's pair stands for its interval.
#[inline(always)]
fn window_stats(
    grid: &Grid,
    b: &mut Belief,
    pairs: &[Pair],
    rows: &Rows,
    cdf: &[f64],
    dt: f64,
    [oh, hh]: [&mut Vec<f64>; 2],
) {
    let g = grid.len();
    let j = Grid::median_node(cdf, 1, g - 2); // the posterior median's node (central differences)
    let step = if dt.is_nan() || dt <= 0.0 { 0.0 } else { dt.min(1.0) };
    let n_used = pairs.len() as f64;
    let mut sums = [0.0; 4];
    let mut step_row = f64::NAN;
    for (i, pr) in pairs.iter().enumerate() {
        let (h, d) = (&rows.h[i], &rows.d[i]);
        let step_w = match pr.span {
            Some(sp) if sp > 0.0 => sp.min(1.0),
            _ => step,
        };
        step_row = if i == 0 { step_w } else { step_row.max(step_w) };
        let nis = rows.r2[i][j];
        let h_k = (h[j + 1] - h[j - 1]) / (2.0 * grid.dtheta); // dh/dlnK at the median
        let wt = 1.0 / pr.sig2;
        let ds = 1.0 - pr.slip.abs().min(1.0); // dS/dlnR_w (eq. 1, both slip signs)
        let terms = [
            step_w * nis / n_used,
            step_w * wt * (h_k * h_k),
            step_w * wt * h_k * h[j],
            step_w * wt * h_k * d[j] * ds,
        ];
        for (s, t) in sums.iter_mut().zip(terms) {
            *s = if i == 0 { t } else { *s + t };
        }
    }
    if pairs[0].span.is_none() {
        step_row = step;
    }
    b.stats[0] += step_row;
    for (st, s) in b.stats[1..].iter_mut().zip(sums) {
        *st += s;
    }
    // the scale profile's sums over the pairs: the first pair's terms, then the others' added
    // in order (one loop per pair, without a branch per node)
    for (i, pr) in pairs.iter().enumerate() {
        let wt = pr.exponent / pr.sig2;
        let obs = pr.observed;
        let rows = oh.iter_mut().zip(hh.iter_mut()).zip(&rows.h[i]);
        if i == 0 {
            for ((o, q), &h) in rows {
                let wh = wt * h;
                *o = wh * obs;
                *q = wh * h;
            }
        } else {
            for ((o, q), &h) in rows {
                let wh = wt * h;
                *o += wh * obs;
                *q += wh * h;
            }
        }
    }
    for (p, &v) in b.profile[0].iter_mut().zip(oh.iter()) {
        *p += v;
    }
    for (p, &v) in b.profile[1].iter_mut().zip(hh.iter()) {
        *p += v;
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::constants::Constants;
    use crate::traction::{self, Kind};

    fn bank() -> SoilGridBank {
        let g = 241;
        let (a, b) = (5f64.ln(), 5000f64.ln());
        let theta: Vec<f64> = (0..g).map(|i| a + (b - a) * i as f64 / (g - 1) as f64).collect();
        let k = theta.iter().map(|t| t.exp()).collect();
        let grid = Grid::new(theta, k, None, Kind::Gross, Constants::PAPER).unwrap();
        let cfg = Params::default();
        let z: Vec<f64> = (0..25).map(|i| -4.0 + 8.0 * i as f64 / 24.0).collect();
        let nodes = ScaleNodes {
            log_prior: z.iter().map(|z| -0.5 * z * z).collect(),
            z,
        };
        SoilGridBank::new(grid, cfg, nodes, 20.0, 1).unwrap()
    }

    fn sample(i: usize) -> Sample {
        // a traction test on K = 100 with a deterministic wobble of the readings
        let t = i as f64 * 0.01;
        let s = 0.02 + 0.3 * (0.5 + 0.5 * (t * 1.3).sin());
        let slip = [s, s * 0.9, -0.3 * s, -0.25 * s];
        let observed = slip.map(|s| {
            traction::curve(Kind::Gross, s, 100.0, &Constants::PAPER).value * (1.0 + 0.02 * (t * 7.0 + s).sin())
        });
        Sample {
            vehicle: 0,
            stamp: t,
            slip,
            observed,
            variance: [1e-4; 4],
            slip_sigma: [0.005; 4],
            gate_slip: slip,
            gate_sigma: [0.005; 4],
            informative: [true; 4],
            held: [false; 4],
            ground_stale: false,
            identifiable: true,
            speed: 1.0,
            span: None,
            slip_ends: None,
            unusable: [0; 4],
            scale_sigma: None,
        }
    }

    /// The AVX2 copy of the update and the plain one give the same numbers to the bit (what
    /// `step_one` relies on when it picks one at run time).
    #[test]
    fn avx2_copy_equals_the_plain_update_to_the_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let (mut plain, mut wide) = (bank(), bank());
        let mut informed = 0;
        for i in 0..400 {
            let s = sample(i);
            // the wheels' flags and the bridge as `step` makes them
            let flags = plain.wheel_flags(&s);
            let bridged = [
                (0..4).any(|w| flags[w] & USED != 0 && plain.grid.in_bridge(s.slip[w])),
                false,
                false,
            ];
            let a = plain.step_one_body(&s, flags, bridged);
            // SAFETY: the CPU has AVX2 (checked above)
            let b = unsafe { wide.step_one_avx2(&s, flags, bridged) };
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "sample {i}");
            informed += usize::from(a.informed);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&plain.vehicles[0].p), bits(&wide.vehicles[0].p), "sample {i}");
        }
        assert!(informed > 300, "the drive must inform the belief ({informed} of 400)");
    }
}
