//! N vehicles' grid Bayes filters over ln K (docs/method.md §9), stepped together: one call per
//! step for k selected vehicles.  Per vehicle: the pooled belief p, the no-change belief p_stay
//! with its posterior probability and the recent evidence for a change, the window statistics
//! (evidence, NIS, the systematic budget's sums), the scale profile, the scale's systematic term
//! and the axle check.

use crate::observer::numeric::np_sign as sign;
use crate::soil::axles::{AxleCheck, AxleVerdict};
use crate::soil::grid::Grid;
use crate::soil::numeric::{pairwise_sum, row_max};
use crate::soil::params::Params;
use crate::soil::scale::{scale_shift, ScaleNodes};

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
}

/// A used wheel's pair within one step: its curve on the grid and its likelihood's pieces.
struct Pair {
    wheel: usize,
    slip: f64,
    observed: f64,
    h: Vec<f64>,
    d: Vec<f64>,
    sig2: f64,
    r2: Vec<f64>,
    exponent: f64,
    span: Option<f64>,
    loglike: Vec<f64>,
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
        let n = self.vehicles.len();
        let mut seen = vec![false; n];
        for s in samples {
            if s.vehicle >= n {
                return Err(format!("vehicle index {} out of range (bank of {n})", s.vehicle));
            }
            if seen[s.vehicle] {
                return Err(format!("vehicle index {} given twice in one step", s.vehicle));
            }
            seen[s.vehicle] = true;
        }
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

    fn step_one(&mut self, s: &Sample, wheel: [u8; 4], bridged: [bool; 3]) -> Step {
        let grid = &self.grid;
        let cfg = &self.cfg;
        let g = grid.len();
        let b = &mut self.vehicles[s.vehicle];
        let dt = s.stamp - b.last_stamp;
        let pred = !b.last_stamp.is_nan() && dt > 0.0;
        if pred {
            let v = if s.speed.is_nan() { cfg.unknown_speed } else { s.speed }.abs();
            let dist = v * dt;
            grid.predict(&mut b.p, dt, dist, cfg.q_log_k, cfg.change_per_metre);
            // the no-change belief diffuses without the change prior: no distance
            grid.predict(&mut b.p_stay, dt, 0.0, cfg.q_log_k, cfg.change_per_metre);
            for axle in b.axles.p.iter_mut() {
                grid.predict(axle, dt, dist, cfg.q_log_k, cfg.change_per_metre);
            }
            let hz = (cfg.change_per_metre * dist).min(1.0);
            b.w_stay *= 1.0 - hz; // P(no change over this step)
            if cfg.stay_forgetting > 0.0 {
                // the no-change belief's memory (report_median)
                let a = 1.0 - cfg.stay_forgetting * hz;
                let q: Vec<f64> = b.p_stay.iter().map(|&v| v.max(1e-300).powf(a)).collect();
                let total = pairwise_sum(&q);
                for (p, v) in b.p_stay.iter_mut().zip(&q) {
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
        let mut pairs: Vec<Pair> = Vec::new();
        if wheel.iter().any(|f| f & USED != 0) {
            pairs = (0..4)
                .filter(|&w| wheel[w] & USED != 0)
                .map(|w| {
                    let (mut h, mut d) = (vec![0.0; g], vec![0.0; g]);
                    grid.curve(s.slip[w], bridged[0], &mut h, &mut d);
                    let span = s.span.map(|sp| sp[w]);
                    if let (Some(ends), Some(sp)) = (s.slip_ends, span) {
                        // a refresh interval's pair: its mean gross traction against the curve
                        // averaged over the interval's slip path (Simpson's rule)
                        if sp > 0.0 && ends[w].iter().all(|v| v.is_finite()) {
                            let (mut h0, mut d0, mut h1, mut d1) =
                                (vec![0.0; g], vec![0.0; g], vec![0.0; g], vec![0.0; g]);
                            grid.curve(ends[w][0], bridged[1], &mut h0, &mut d0);
                            grid.curve(ends[w][1], bridged[2], &mut h1, &mut d1);
                            for i in 0..g {
                                h[i] = (h0[i] + 4.0 * h[i] + h1[i]) / 6.0;
                                d[i] = (d0[i] + 4.0 * d[i] + d1[i]) / 6.0;
                            }
                        }
                    }
                    Pair {
                        wheel: w,
                        slip: s.slip[w],
                        observed: s.observed[w],
                        h,
                        d,
                        sig2: 0.0,
                        r2: Vec::new(),
                        exponent,
                        span,
                        loglike: Vec::new(),
                    }
                })
                .collect();
            // the slip term of the variance at the prior belief's median, the same for every K
            // (docs/method.md §9, quasi-likelihood): per K it would pull K to the flattest curve
            let reference = Grid::median_node(&Grid::cdf(&b.p), 0, g - 1);
            let ms2 = cfg.model_sigma * cfg.model_sigma;
            for pr in pairs.iter_mut() {
                let w = pr.wheel;
                let dh = pr.d[reference] * s.slip_sigma[w];
                pr.sig2 = s.variance[w] + ms2 + dh * dh;
                pr.r2 =
                    pr.h.iter()
                        .map(|&h| (pr.observed - h) * (pr.observed - h) / pr.sig2)
                        .collect();
                let root = pr.sig2.sqrt();
                let like = |r2: f64| (1.0 - cfg.outlier_prob) * (-0.5 * r2).exp() / root + cfg.outlier_prob;
                // one pair is one observation: a refresh interval's pair weighs its own interval, at most 1
                if let Some(sp) = pr.span {
                    if sp > 0.0 {
                        pr.exponent = (cfg.temper * sp / cfg.temper_interval).min(1.0);
                    }
                }
                pr.loglike = pr.r2.iter().map(|&r2| like(r2).ln() * pr.exponent).collect();
            }
            let mut loglike = pairs[0].loglike.clone();
            for pr in &pairs[1..] {
                for (a, &l) in loglike.iter_mut().zip(&pr.loglike) {
                    *a += l;
                }
            }
            let wheels: Vec<usize> = pairs.iter().map(|p| p.wheel).collect();
            let lls: Vec<Vec<f64>> = pairs.iter().map(|p| p.loglike.clone()).collect();
            b.axles.update(s.stamp, &wheels, &lls);
            let top = row_max(&loglike);
            let like: Vec<f64> = loglike.iter().map(|&l| (l - top).exp()).collect();
            let post: Vec<f64> = b.p.iter().zip(&like).map(|(p, l)| p * l).collect();
            let post_stay: Vec<f64> = b.p_stay.iter().zip(&like).map(|(p, l)| p * l).collect();
            let (total, total_stay) = (pairwise_sum(&post), pairwise_sum(&post_stay));
            if total > 0.0 && total.is_finite() {
                b.p = post.iter().map(|v| v / total).collect();
                // Bayes on the two hypotheses: P(no change | data) = P(no change) Z_stay / Z_pooled
                b.w_stay = (b.w_stay * total_stay / total).clamp(0.0, 1.0);
                if cfg.change_evidence > 0.0 {
                    // the data's own say, ln Z_stay / Z_pooled, over the last change_evidence s
                    let fade = (-(if pred { dt.min(1.0) } else { 0.0 }) / cfg.change_evidence).exp();
                    b.stay_llr = b.stay_llr * fade + (total_stay.max(1e-300) / total).ln();
                }
                if total_stay > 0.0 {
                    b.p_stay = post_stay.iter().map(|v| v / total_stay).collect();
                }
                informed = true;
            }
        }
        let cdf = Grid::cdf(&b.p);
        let (k_report, taken) = report_median(grid, cfg, b, &cdf);
        if taken {
            // the window's statistics were gathered on the old soil
            b.stats = [0.0; 5];
            b.profile = [vec![0.0; g], vec![0.0; g]];
        }
        if !pairs.is_empty() {
            window_stats(grid, b, &pairs, &cdf, dt);
        }
        if let Some(sigma) = s.scale_sigma {
            b.scale_prior = sigma;
        }
        if !pairs.is_empty() || taken {
            let (sigma, one_prior) = match s.scale_sigma {
                Some(_) => (b.scale_prior, false),
                None => (cfg.gross_scale_sigma, true),
            };
            b.scale_sys = scale_shift(
                &b.profile[0],
                &b.profile[1],
                sigma,
                &self.nodes,
                &grid.theta,
                grid.dtheta,
                one_prior,
            );
        }
        let [q16, _, q84] = grid.quantiles(&cdf);
        let [s_kk, s_kh] = [b.stats[2], b.stats[3]];
        let sens = if s_kk > 0.0 { s_kh.abs() / s_kk } else { 0.0 }; // d ln K per relative scale
        let axle = b.axles.judge(grid, cfg, s.stamp, dt, cfg.axle_scale_sigma * sens);
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
            floor_cdf: cdf[self.floor_idx.min(g - 1)],
        }
    }
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
fn report_median(grid: &Grid, cfg: &Params, b: &mut Belief, cdf: &[f64]) -> (f64, bool) {
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
        grid.median(&Grid::cdf(&b.p_stay))
    };
    (theta.exp(), taken)
}

/// Accumulate the window's NIS at the posterior median, the systematic budget's sums and the
/// scale profile's per-node sums, weighted as the belief weighs the samples (exponent /
/// variance); a refresh interval's pair stands for its interval.
fn window_stats(grid: &Grid, b: &mut Belief, pairs: &[Pair], cdf: &[f64], dt: f64) {
    let g = grid.len();
    let j = Grid::median_node(cdf, 1, g - 2); // the posterior median's node (central differences)
    let step = if dt.is_nan() || dt <= 0.0 { 0.0 } else { dt.min(1.0) };
    let n_used = pairs.len() as f64;
    let mut sums = [0.0; 4];
    let mut step_row = f64::NAN;
    for (i, pr) in pairs.iter().enumerate() {
        let step_w = match pr.span {
            Some(sp) if sp > 0.0 => sp.min(1.0),
            _ => step,
        };
        step_row = if i == 0 { step_w } else { step_row.max(step_w) };
        let nis = pr.r2[j];
        let h_k = (pr.h[j + 1] - pr.h[j - 1]) / (2.0 * grid.dtheta); // dh/dlnK at the median
        let wt = 1.0 / pr.sig2;
        let ds = 1.0 - pr.slip.abs().min(1.0); // dS/dlnR_w (eq. 1, both slip signs)
        let terms = [
            step_w * nis / n_used,
            step_w * wt * (h_k * h_k),
            step_w * wt * h_k * pr.h[j],
            step_w * wt * h_k * pr.d[j] * ds,
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
    let mut oh = vec![0.0; g];
    let mut hh = vec![0.0; g];
    for (i, pr) in pairs.iter().enumerate() {
        let wt = pr.exponent / pr.sig2;
        for k in 0..g {
            let wh = wt * pr.h[k];
            let (a, c) = (wh * pr.observed, wh * pr.h[k]);
            if i == 0 {
                oh[k] = a;
                hh[k] = c;
            } else {
                oh[k] += a;
                hh[k] += c;
            }
        }
    }
    for k in 0..g {
        b.profile[0][k] += oh[k];
        b.profile[1][k] += hh[k];
    }
}
