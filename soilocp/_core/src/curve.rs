//! The wheel's own traction curve, learnt where the drive shows it (docs/method.md §14, §19).
//!
//! On one soil, eq. 6 for S > 0 is mu(S) = A (1 - e^(-C3 S)) - c - b S with A = C1 (1 - e^(-C2 K)),
//! b = C6 / sqrt(K) and c = C5 / K.  The OCPs need that shape, not K: dmu/dS = 0 gives
//! S_T = ln(A C3 / b) / C3 and mu_T = mu(S_T).  A drive whose slips spread over the bend (a traction
//! sweep, hard accelerations and brakes) shows the shape, whatever the wheel's constants.
//!
//! [`CurveLearner`] keeps the wheels' recent (slip, net traction) pairs and fits the shape to those
//! of the current soil (a change of soil shows as recent pairs that leave the fitted curve): for each
//! C3 on a grid the fit is linear in (A, b, c), so the least-squares problem is a one-dimensional
//! search.  Eq. 6 is odd in S, so a braking wheel's pair
//! (S < 0, mu < 0) is the driving pair (-S, -mu).  The band of (S_T, mu_T) is the delta method on
//! the fit's covariance, with the residual variance inflated for the residuals' correlation in time
//! (consecutive samples of one wheel are not independent).  A peak beyond the slips the window holds
//! is an extrapolation: the fit then says `shown = false`.
//!
//! Each wheel's pairs are fitted as g_w mu(S), one shape with a traction scale per wheel shrunk
//! towards 1 (a torque gain or load share a few percent off on one wheel, which would otherwise
//! move the peak where the wheels sit at different slips), and a pair formed under another
//! ground-speed latency estimate than the current one is dropped (its slip carries the old lag).

use std::collections::VecDeque;

use pyo3::prelude::*;

use crate::settings::settings_struct;

settings_struct! {
    /// The learner's settings (soilocp.estimation.curve_config.CurveConfig is built from these
    /// declarations).
    pub struct Params("curve") {
        /// Pairs older than this are dropped: the (slip, traction) pairs of the last window are fitted.
        window: Float = 8.0, Internal, "s", [gt 0.0];
        /// The recent pairs whose mean departure from the fitted curve tells a change of soil.
        change_window: Float = 0.5, Internal, "s", [gt 0.0];
        /// Mean departure of those pairs' traction coefficient from the curve beyond which the soil
        /// changed (the pairs are dropped and the fit starts over).
        change_shift: Float = 0.04, Internal, "", [gt 0.0];
        /// Recent pairs needed to judge a change of soil, counted as pairs on the curve's flat part
        /// (pair_slip_sigma).
        change_pairs: Int = 20.0, Internal, "", [ge 1.0];
        /// |slip| below this is not fitted (the zero-slip bridge, eq. 1's noise).
        slip_min: Float = 0.02, Internal, "", [ge 0.0];
        /// |slip| above this is not fitted (a spinning or locked wheel).
        slip_max: Float = 0.95, Internal, "", [gt 0.0];
        /// Pairs of the current soil needed before a fit.
        min_pairs: Int = 200.0, Internal, "", [ge 5.0];
        /// Pairs on each side of the fitted S_T, within peak_span of it, for the peak to count as
        /// shown (else the curve past the data is an extrapolation).
        min_beyond: Int = 40.0, Internal, "", [ge 1.0];
        /// Slip distance from S_T within which min_beyond pairs on each side show the bend.
        peak_span: Float = 0.1, Internal, "", [gt 0.0];
        /// Time between two fits (and at once after a change of soil).
        interval: Float = 0.5, Internal, "s", [ge 0.0];
        /// 1-sigma of a pair's slip (the ground speed's noise and lag): where the curve rises steeply
        /// a small slip error is a large traction error, so in the change test a pair counts as
        /// s_mu^2 / (s_mu^2 + (dmu/dS s_slip)^2) of a pair on the curve's flat part (s_slip this,
        /// s_mu pair_mu_sigma).
        pair_slip_sigma: Float = 0.03, Internal, "", [ge 0.0];
        /// 1-sigma of a pair's net traction coefficient where the curve is flat (the observer's).
        pair_mu_sigma: Float = 0.02, Internal, "", [gt 0.0];
        /// Prior 1-sigma of a wheel's traction scale about the common curve (a torque constant or
        /// wheel radius a few percent off on one wheel): each wheel's pairs are fitted as
        /// g_w mu(S), g_w shrunk towards 1 by this prior, so a wheel held at one slip that reads low
        /// moves no peak.  0 fits one curve to every wheel as read.
        wheel_scale_sigma: Float = 0.05, Internal, "", [ge 0.0];
        /// Change of the ground-speed latency estimate (the observer's) beyond which the pairs
        /// formed under the old estimate are dropped: their slips carry the old lag's error.
        latency_change: Float = 0.03, Internal, "s", [gt 0.0];
        /// Systematic 1-sigma added to the learnt S_T's band, whatever the curve's shape: the learnt
        /// peak's error against a known curve.
        s_t_sys: Float = 0.02, Internal, "", [ge 0.0];
        /// Systematic error of the observed net traction per unit slip: a tilt that moves the fitted
        /// peak by tilt_sys / |mu''(S_T)|, added to S_T's band, so that a flat peak is not reported as
        /// precise.
        tilt_sys: Float = 0.06, Internal, "", [ge 0.0];
        /// Systematic 1-sigma added to the learnt mu_T's band.
        mu_t_sys: Float = 0.02, Internal, "", [ge 0.0];
    }
}

/// One (slip, net traction) pair of one wheel, folded onto the driving branch.
#[derive(Clone, Copy, Debug)]
struct Pair {
    t: f64,
    wheel: u8,
    s: f64,
    mu: f64,
    /// the ground-speed latency estimate the slip was formed under, s
    lat: f64,
}

/// The fitted shape mu(S) = a (1 - e^(-c3 S)) - c - b S on the current soil and the OCPs that follow from it:
/// `soilocp._core.CurveFit` to Python, read-only.
#[pyclass(frozen, get_all, name = "CurveFit", module = "soilocp._core")]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    pub a: f64,
    pub c3: f64,
    pub b: f64,
    pub c: f64,
    /// slip of maximum net traction and its 1-sigma
    pub s_t: f64,
    pub s_t_std: f64,
    /// maximum net traction coefficient and its 1-sigma
    pub mu_t: f64,
    pub mu_t_std: f64,
    /// the 1-sigma the OCP records serve for S_T and mu_T: the fit's own with the learner's
    /// systematic errors (`s_t_sys`, `mu_t_sys`), S_T's flatness (`tilt_sys`) and the slips' reach,
    /// and mu_T's level (the torques' common scale); see [`Fit::with_bands`]
    pub s_t_band: f64,
    pub mu_t_band: f64,
    /// pairs fitted, pairs within `peak_span` below and above S_T, the largest |S| fitted
    pub pairs: usize,
    pub below: usize,
    pub beyond: usize,
    pub slip_top: f64,
    /// the slip that `min_beyond` of the fitted pairs reach or pass
    pub reach: f64,
    /// rms of the residuals
    pub rms: f64,
    /// each wheel's traction scale g_w about the common curve (mu = g_w mu(S); 1 for a wheel without
    /// pairs), normalised to a mean of 1 weighted by what each wheel's pairs tell
    pub wheel_scale: [f64; 4],
    /// the fitted slips surround the peak (`below` and `beyond` >= `min_beyond`): not an extrapolation,
    /// nor an interpolation over a gap
    pub shown: bool,
    /// stamp of the fit, s
    pub stamp: f64,
}

impl Fit {
    /// This fit with the bands the OCP records serve.  S_T's 1-sigma is the fit's own, `s_t_sys`, the
    /// peak's flatness (a tilt `tilt_sys` of the observed traction per unit slip moves the peak by
    /// tilt_sys / |mu''(S_T)|) and the part of `peak_span` past S_T that the slips do not reach
    /// (`reach`: a sweep that stops just past a peak it places there, short of the true one, shows
    /// nothing of the curve beyond).  mu_T's is the fit's own, `mu_t_sys` and the level: traction
    /// read through torques a few percent off (a motor constant, a payload; relative 1-sigma
    /// `scale_sigma`) is a curve as much high or low at every slip, which moves mu_T by
    /// mu_T `scale_sigma`, moves no peak, and so shows in no shape.
    pub fn with_bands(mut self, p: &Params, scale_sigma: f64) -> Fit {
        let curvature = self.a * self.c3 * self.c3 * (-self.c3 * self.s_t).exp(); // |mu''(S_T)|
        let flat = if curvature > 0.0 {
            p.tilt_sys / curvature
        } else {
            f64::INFINITY
        };
        let level = self.mu_t.abs() * scale_sigma;
        // slips that pass the peak by less than peak_span leave the rest of that span unseen: the
        // true peak may lie there, past the slips the drive reached
        let unseen = (p.peak_span - (self.reach - self.s_t)).max(0.0);
        self.s_t_band = self.s_t_std.hypot(p.s_t_sys).hypot(flat).hypot(unseen);
        self.mu_t_band = self.mu_t_std.hypot(p.mu_t_sys).hypot(level);
        self
    }
}

/// Net traction mu(S) = A (1 - e^(-C3 S)) - c - b S on one soil (eq. 6, S > 0).
pub fn shape(s: f64, a: f64, c3: f64, b: f64, c: f64) -> f64 {
    a * (1.0 - (-c3 * s).exp()) - c - b * s
}

/// Slope dmu/dS of [`shape`] at `s`.
pub fn slope(s: f64, a: f64, c3: f64, b: f64) -> f64 {
    a * c3 * (-c3 * s).exp() - b
}

/// How much a pair on a curve of slope `dmu` tells of its traction, as a share of a pair where the
/// curve is flat: s_mu^2 / (s_mu^2 + (dmu s_slip)^2) with s_mu `pair_mu_sigma` and s_slip
/// `pair_slip_sigma`, the slip's error carried into traction (errors in variables).
fn weight(p: &Params, dmu: f64) -> f64 {
    let m2 = p.pair_mu_sigma * p.pair_mu_sigma;
    let e = dmu * p.pair_slip_sigma;
    m2 / (m2 + e * e)
}

/// S_T and mu_T of a shape: the slip where dmu/dS = 0 (eq. 7's form) and mu there (eq. 8's); None
/// when the shape has no interior peak (b <= 0 or A C3 <= b: the curve falls from S = 0 on).
pub fn peak(a: f64, c3: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    if !(a > 0.0 && c3 > 0.0 && b > 0.0) || a * c3 <= b {
        return None;
    }
    let s_t = (a * c3 / b).ln() / c3;
    Some((s_t, shape(s_t, a, c3, b, c)))
}

/// The learner of one vehicle.
#[derive(Clone, Debug)]
pub struct CurveLearner {
    params: Params,
    /// relative 1-sigma of the torques' common scale, the level no shape shows (`Fit::with_bands`)
    scale_sigma: f64,
    pairs: VecDeque<Pair>,
    last_fit: f64,
    fit: Option<Fit>,
    /// changes of soil detected so far: the current soil's index in the drive
    changes: usize,
}

impl CurveLearner {
    /// A learner with the curve settings `params`, whose traction is read through torques of common
    /// scale relative 1-sigma `scale_sigma` (the soil estimator's `gross_scale_sigma`).
    pub fn new(params: Params, scale_sigma: f64) -> Self {
        CurveLearner {
            params,
            scale_sigma,
            pairs: VecDeque::new(),
            last_fit: f64::NEG_INFINITY,
            fit: None,
            changes: 0,
        }
    }

    /// The current soil's index in the drive: the changes of soil detected so far.
    pub fn changes(&self) -> usize {
        self.changes
    }

    /// Forget every pair and fit (a restarted vehicle).
    pub fn reset(&mut self) {
        self.pairs.clear();
        self.last_fit = f64::NEG_INFINITY;
        self.fit = None;
        self.changes = 0;
    }

    /// One sample: the wheels' slips and net traction coefficients (4,), which of them inform
    /// (`used`) and the ground-speed latency estimate the slips were formed under (s).  Returns the
    /// current soil's fit (refitted at most every `interval` s), or None while the current soil has
    /// too few pairs or shows no peak.
    ///
    /// A change of soil is read from the fit itself: when the pairs of the last `change_window` s
    /// leave a fitted curve that shows its peak by more than `change_shift` on average, the ground
    /// under the wheels is another, and only those pairs are kept.  The soil strength that a curve nobody checked reads
    /// is no guide here: on another tyre it swings by factors on one soil.
    ///
    /// A latency estimate that moved by more than `latency_change` since a pair was formed drops that
    /// pair (its slip carries the old lag's error: acceleration read as slip) and refits at once; the
    /// soil did not change.
    pub fn step(&mut self, stamp: f64, slip: &[f64; 4], mu: &[f64; 4], used: &[bool; 4], latency: f64) -> Option<Fit> {
        let p = self.params;
        if stamp < self.last_fit {
            self.reset(); // time ran backwards: another run
        }
        let latency = if latency.is_finite() { latency } else { 0.0 };
        let before = self.pairs.len();
        self.pairs.retain(|q| (q.lat - latency).abs() <= p.latency_change);
        let relagged = self.pairs.len() < before;
        for w in 0..4 {
            let (s, m) = (slip[w], mu[w]);
            if used[w] && s.is_finite() && m.is_finite() && s.abs() >= p.slip_min && s.abs() <= p.slip_max {
                let sign = s.signum();
                self.pairs.push_back(Pair {
                    t: stamp,
                    wheel: w as u8,
                    s: s * sign,
                    mu: m * sign,
                    lat: latency,
                });
            }
        }
        while self.pairs.front().is_some_and(|q| q.t < stamp - p.window) {
            self.pairs.pop_front();
        }
        let mut changed = false;
        // judged against a curve that shows its peak only: a fit of a few pairs on one flank, made just
        // after a change, would read the next flank's pairs as another change
        if let Some(f) = self.fit.filter(|f| f.shown) {
            let since = stamp - p.change_window;
            // (weight, residual) of the recent pairs, newest first: on the curve's steep rise a GNSS-grade
            // ground speed's slip error alone leaves a pair well below or above the curve, so such a pair
            // counts for little (`weight`) and a few of them tell no change
            let recent: Vec<(f64, f64)> = self
                .pairs
                .iter()
                .rev()
                .take_while(|q| q.t > since)
                .map(|q| {
                    let g = f.wheel_scale[q.wheel as usize];
                    (
                        weight(&p, g * slope(q.s, f.a, f.c3, f.b)),
                        q.mu - g * shape(q.s, f.a, f.c3, f.b, f.c),
                    )
                })
                .collect();
            let n = recent.len();
            let (total_w, total) = recent.iter().fold((0.0, 0.0), |(sw, sr), (w, r)| (sw + w, sr + w * r));
            // change_pairs flat-part pairs' worth, whose weighted mean shift is beyond the noise the fit
            // leaves and beyond change_shift
            let shift = p.change_shift.max(CHANGE_RMS * f.rms);
            if total_w >= p.change_pairs && (total / total_w).abs() > shift {
                // the change's moment: the split of the recent residuals (newest first) whose two weighted
                // means differ the most, weighted by their weights; the pairs before it are the old soil's
                let (mut head_w, mut head, mut best, mut keep) = (0.0, 0.0, 0.0, n);
                for (k, (w, r)) in recent.iter().enumerate().take(n - 1) {
                    head_w += w;
                    head += w * r;
                    let (na, nb) = (head_w, total_w - head_w);
                    if na <= 0.0 || nb <= 0.0 {
                        continue;
                    }
                    let gap = head / na - (total - head) / nb;
                    let score = na * nb / (na + nb) * gap * gap;
                    if score > best {
                        best = score;
                        keep = k + 1;
                    }
                }
                let drop = self.pairs.len() - keep;
                self.pairs.drain(..drop);
                changed = true;
                self.changes += 1;
            }
        }
        if changed || relagged || stamp - self.last_fit >= p.interval {
            self.last_fit = stamp;
            self.fit = fit_pairs(self.pairs.make_contiguous(), &p, stamp).map(|f| f.with_bands(&p, self.scale_sigma));
        }
        self.fit
    }
}

/// Weighted pairs summed by slip bin: the fit's normal equations for any C3 from one pass over the
/// bins, not the pairs (the exponential of a bin's mean slip stands for its pairs': within a bin of
/// `BIN` the first-order terms cancel and the rest is below 1e-6).
struct Bins {
    /// per occupied bin: (sum w, sum w S, sum w mu, sum w S mu)
    sums: Vec<[f64; 4]>,
    /// sum w mu^2 over every pair
    mu2: f64,
}

/// Slip bin width of [`Bins`].
const BIN: f64 = 0.0025;

impl Bins {
    fn of(pairs: &[Pair], weights: &[f64]) -> Bins {
        let mut by_bin: Vec<(i64, [f64; 4])> = Vec::new();
        let mut mu2 = 0.0;
        let mut order: Vec<usize> = (0..pairs.len()).filter(|&k| weights[k] > 0.0).collect();
        order.sort_unstable_by_key(|&k| (pairs[k].s / BIN) as i64);
        for k in order {
            let (q, w) = (pairs[k], weights[k]);
            let bin = (q.s / BIN) as i64;
            if by_bin.last().map_or(true, |(b, _)| *b != bin) {
                by_bin.push((bin, [0.0; 4]));
            }
            let acc = &mut by_bin.last_mut().expect("pushed above").1;
            acc[0] += w;
            acc[1] += w * q.s;
            acc[2] += w * q.mu;
            acc[3] += w * q.s * q.mu;
            mu2 += w * q.mu * q.mu;
        }
        Bins {
            sums: by_bin.into_iter().map(|(_, a)| a).collect(),
            mu2,
        }
    }

    /// Weighted least squares of (A, b, c) for a fixed C3: (A, b, c, weighted residual sum of
    /// squares), or None when the normal equations are singular (all slips alike).
    fn linear_fit(&self, c3: f64) -> Option<(f64, f64, f64, f64)> {
        // columns: f1 = 1 - e^(-C3 S) (A), f2 = -S (b), f3 = -1 (c), at each bin's mean slip
        let mut m = [[0.0f64; 3]; 3];
        let mut v = [0.0f64; 3];
        for &[w, ws, wmu, wsmu] in &self.sums {
            let s = ws / w;
            let f1 = 1.0 - (-c3 * s).exp();
            // sum w f f^T and sum w f mu, with sum w S^2 taken as w s^2 (the bin's spread is below BIN^2)
            let (a11, a12, a13, a22, a23, a33) = (w * f1 * f1, -f1 * ws, -w * f1, ws * s, ws, w);
            m[0][0] += a11;
            m[0][1] += a12;
            m[0][2] += a13;
            m[1][1] += a22;
            m[1][2] += a23;
            m[2][2] += a33;
            v[0] += f1 * wmu;
            v[1] -= wsmu;
            v[2] -= wmu;
        }
        m[1][0] = m[0][1];
        m[2][0] = m[0][2];
        m[2][1] = m[1][2];
        let x = solve3(m, v)?;
        // sum w r^2 = sum w mu^2 - 2 x.v + x^T M x
        let xv: f64 = (0..3).map(|i| x[i] * v[i]).sum();
        let xmx: f64 = (0..3).map(|i| (0..3).map(|j| x[i] * m[i][j] * x[j]).sum::<f64>()).sum();
        Some((x[0], x[1], x[2], (self.mu2 - 2.0 * xv + xmx).max(0.0)))
    }

    /// The C3 of least weighted residual: the grid's best node (all of `C3_GRID`, or the nodes within
    /// one step of `near`), refined by golden section between its neighbours; with its (A, b, c, rss).
    fn search(&self, near: Option<f64>) -> Option<(f64, (f64, f64, f64, f64))> {
        let (lo, hi, n) = C3_GRID;
        let step = (hi / lo).ln() / (n - 1) as f64;
        let (from, to) = match near {
            Some(c3) => {
                let i = ((c3 / lo).ln() / step).round() as i64;
                ((i - 1).max(0) as usize, ((i + 1).max(0) as usize).min(n - 1))
            }
            None => (0, n - 1),
        };
        let mut best: Option<(f64, f64)> = None;
        for i in from..=to {
            let c3 = lo * (step * i as f64).exp();
            if let Some(f) = self.linear_fit(c3) {
                if best.map_or(true, |(_, r)| f.3 < r) {
                    best = Some((c3, f.3));
                }
            }
        }
        let (c3_node, _) = best?;
        let (mut a, mut b) = (c3_node.ln() - step, c3_node.ln() + step);
        let g = 0.5 * (5.0f64.sqrt() - 1.0);
        let rss = |lc3: f64| self.linear_fit(lc3.exp()).map_or(f64::INFINITY, |f| f.3);
        let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
        let (mut f1, mut f2) = (rss(x1), rss(x2));
        for _ in 0..24 {
            if f1 < f2 {
                b = x2;
                x2 = x1;
                f2 = f1;
                x1 = b - g * (b - a);
                f1 = rss(x1);
            } else {
                a = x1;
                x1 = x2;
                f1 = f2;
                x2 = a + g * (b - a);
                f2 = rss(x2);
            }
        }
        let c3 = (0.5 * (a + b)).exp();
        Some((c3, self.linear_fit(c3)?))
    }
}

/// x with m x = v (3 x 3); None if singular.
fn solve3(m: [[f64; 3]; 3], v: [f64; 3]) -> Option<[f64; 3]> {
    gauss_jordan(m, v.map(|x| [x]), 1e-12).map(|x| x.map(|[x]| x))
}

/// Inverse of a symmetric positive definite N x N matrix; None if singular.
fn invert<const N: usize>(a: [[f64; N]; N]) -> Option<[[f64; N]; N]> {
    let identity = std::array::from_fn(|i| std::array::from_fn(|k| if i == k { 1.0 } else { 0.0 }));
    gauss_jordan(a, identity, 1e-14)
}

/// X with A X = B (A n x n, B n x m) by Gauss-Jordan elimination with partial pivoting; None when a
/// pivot is at most `tol` times A's largest entry (singular to working precision).
fn gauss_jordan<const N: usize, const M: usize>(
    mut a: [[f64; N]; N],
    mut b: [[f64; M]; N],
    tol: f64,
) -> Option<[[f64; M]; N]> {
    let scale = a.iter().flatten().fold(0.0f64, |acc, x| acc.max(x.abs()));
    for col in 0..N {
        let piv = (col..N).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() <= tol * scale.max(f64::MIN_POSITIVE) {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        let d = a[col][col];
        a[col].iter_mut().for_each(|x| *x /= d);
        b[col].iter_mut().for_each(|x| *x /= d);
        let (pivot_a, pivot_b) = (a[col], b[col]);
        for row in (0..N).filter(|&row| row != col) {
            let f = a[row][col];
            for (x, p) in a[row].iter_mut().zip(&pivot_a) {
                *x -= f * p;
            }
            for (x, p) in b[row].iter_mut().zip(&pivot_b) {
                *x -= f * p;
            }
        }
    }
    Some(b)
}

/// The lag-1 autocorrelation of the residuals of each wheel's consecutive pairs, pooled; in [0, 0.99].
fn residual_correlation(pairs: &[Pair], res: &[f64]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for w in 0..4u8 {
        let mut prev: Option<f64> = None;
        for (q, r) in pairs.iter().zip(res) {
            if q.wheel != w {
                continue;
            }
            if let Some(p) = prev {
                num += p * r;
            }
            den += r * r;
            prev = Some(*r);
        }
    }
    if den > 0.0 {
        (num / den).clamp(0.0, 0.99)
    } else {
        0.0
    }
}

/// The C3 search grid: geometric from 1 to 40 (a curve that reaches 63 % of its rise by S = 1 ... 0.025).
const C3_GRID: (f64, f64, usize) = (1.0, 40.0, 40);

/// A change of soil shifts the recent pairs' mean residual by more than this many of the fit's rms
/// residuals (noisy slips, a GNSS ground speed, leave wider residuals on one soil).
const CHANGE_RMS: f64 = 1.5;

/// Tukey's biweight tuning constant (95 % efficiency for Gaussian residuals).
const TUKEY: f64 = 4.685;
/// Reweighting passes of the robust fit.
const PASSES: usize = 3;

/// Each wheel's traction scale about the common shape `h` (mu = g_w h(S)): per wheel the weighted
/// least squares of g_w, shrunk towards 1 by the prior `sigma_g` against the residuals' scale
/// `sigma_r` (the posterior mean of g_w given g_w ~ N(1, sigma_g^2)), then normalised to a mean of 1
/// weighted by each wheel's information sum w h^2: the common shape keeps the vehicle's level, the
/// scales only share it out.  All 1 when `sigma_g` is 0.
fn wheel_scales(pairs: &[Pair], weights: &[f64], h: &[f64], sigma_r: f64, sigma_g: f64) -> [f64; 4] {
    if sigma_g <= 0.0 {
        return [1.0; 4];
    }
    let prior = (sigma_r / sigma_g).powi(2);
    let (mut hy, mut hh) = ([0.0f64; 4], [0.0f64; 4]);
    for ((q, w), h) in pairs.iter().zip(weights).zip(h) {
        let k = q.wheel as usize;
        hy[k] += w * h * q.mu;
        hh[k] += w * h * h;
    }
    let g: [f64; 4] = std::array::from_fn(|k| (hy[k] + prior) / (hh[k] + prior).max(1e-12));
    let info: f64 = hh.iter().sum();
    let mean = if info > 0.0 {
        (0..4).map(|k| hh[k] * g[k]).sum::<f64>() / info
    } else {
        1.0
    };
    if mean.is_finite() && mean > 0.0 {
        g.map(|x| x / mean)
    } else {
        [1.0; 4]
    }
}

/// Covariance of the shape's (A, C3, b, c): sigma2 (J^T W J)^-1 over the weighted pairs, with the
/// wheels' scales as parameters too and their prior N(1, sigma_g^2) added to the normal matrix, so
/// that what the scales leave uncertain of the shape (the vehicle's level, which the scales share
/// with A, b and c; a scale that trades with the curve's bend where a wheel sits at one slip) widens
/// the band.  With `sigma_g` 0 the scales are fixed and only the shape's block is inverted.
fn shape_covariance(
    inliers: &[(Pair, f64)],
    scales: &[f64; 4],
    (amp, c3, b, offset): (f64, f64, f64, f64),
    sigma2: f64,
    sigma_g: f64,
) -> Option<[[f64; 4]; 4]> {
    // columns: A, C3, b, c of g_w h(S), then g_0 .. g_3 (h(S) for the pair's own wheel)
    let mut n = [[0.0f64; 8]; 8];
    for (q, w) in inliers {
        let e = (-c3 * q.s).exp();
        let k = q.wheel as usize;
        let g = scales[k];
        let mut j = [0.0f64; 8];
        j[..4].copy_from_slice(&[g * (1.0 - e), g * amp * q.s * e, -g * q.s, -g]);
        j[4 + k] = shape(q.s, amp, c3, b, offset);
        for r in 0..8 {
            for c in 0..8 {
                n[r][c] += w * j[r] * j[c];
            }
        }
    }
    let block = if sigma_g > 0.0 {
        let prior = sigma2 / (sigma_g * sigma_g);
        for (k, row) in n.iter_mut().enumerate().skip(4) {
            row[k] += prior;
        }
        let inv = invert(n)?;
        std::array::from_fn(|r| std::array::from_fn(|c| inv[r][c]))
    } else {
        invert(std::array::from_fn(|r| std::array::from_fn(|c| n[r][c])))?
    };
    Some(block.map(|row| row.map(|x| x * sigma2)))
}

/// Fit the shape to the current soil's pairs, robustly: Tukey's biweight on the residuals (scale by
/// their median absolute deviation), so that the few pairs of a soil the wheels just left (a rear
/// axle still on it) weigh nothing.  The common shape and each wheel's scale (`wheel_scales`) are
/// fitted in turn: the shape to the pairs divided by their wheel's scale, weighted by its square.
/// None when there are too few pairs or the fit has no peak.
fn fit_pairs(pairs: &[Pair], p: &Params, stamp: f64) -> Option<Fit> {
    if (pairs.len() as f64) < p.min_pairs.max(5.0) {
        return None;
    }
    let mut weights = vec![1.0; pairs.len()];
    let mut scales = [1.0f64; 4];
    let mut near = None;
    let mut fitted = None;
    for pass in 0..=PASSES {
        let scaled: Vec<Pair> = pairs
            .iter()
            .map(|q| Pair {
                mu: q.mu / scales[q.wheel as usize],
                ..*q
            })
            .collect();
        let scaled_w: Vec<f64> = pairs
            .iter()
            .zip(&weights)
            .map(|(q, w)| w * scales[q.wheel as usize].powi(2))
            .collect();
        let (c3, (amp, b, offset, _)) = Bins::of(&scaled, &scaled_w).search(near)?;
        near = Some(c3);
        fitted = Some((c3, amp, b, offset));
        if pass == PASSES {
            break;
        }
        let h: Vec<f64> = pairs.iter().map(|q| shape(q.s, amp, c3, b, offset)).collect();
        let mad_of = |res: &[f64]| {
            let mut abs: Vec<f64> = res.iter().map(|r| r.abs()).collect();
            let mid = abs.len() / 2;
            *abs.select_nth_unstable_by(mid, |x, y| x.total_cmp(y)).1
        };
        let res: Vec<f64> = pairs
            .iter()
            .zip(&h)
            .map(|(q, h)| q.mu - scales[q.wheel as usize] * h)
            .collect();
        // a pair on the curve's steep rise tells little of its wheel's gain: there a small slip error (a
        // wheel radius a little off, which moves driving and braking slips opposite ways) is a large
        // traction error, so each pair weighs as in the change test (`weight`)
        let gain_w: Vec<f64> = pairs
            .iter()
            .zip(&weights)
            .map(|(q, w)| w * weight(p, scales[q.wheel as usize] * slope(q.s, amp, c3, b)))
            .collect();
        scales = wheel_scales(pairs, &gain_w, &h, 1.4826 * mad_of(&res), p.wheel_scale_sigma);
        let res: Vec<f64> = pairs
            .iter()
            .zip(&h)
            .map(|(q, h)| q.mu - scales[q.wheel as usize] * h)
            .collect();
        let cut = TUKEY * 1.4826 * mad_of(&res).max(1e-6);
        for (w, r) in weights.iter_mut().zip(&res) {
            let u = r / cut;
            *w = if u.abs() < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
        }
    }
    let (c3, amp, b, offset) = fitted?;
    let (s_t, mu_t) = peak(amp, c3, b, offset)?;

    // the band: delta method on the weighted covariance of (A, C3, b, c), over the pairs that weigh
    let inliers: Vec<(Pair, f64)> = pairs
        .iter()
        .zip(&weights)
        .filter(|(_, &w)| w > 0.0)
        .map(|(q, &w)| (*q, w))
        .collect();
    let kept: Vec<Pair> = inliers.iter().map(|(q, _)| *q).collect();
    let res: Vec<f64> = kept
        .iter()
        .map(|q| q.mu - scales[q.wheel as usize] * shape(q.s, amp, c3, b, offset))
        .collect();
    let sum_w: f64 = inliers.iter().map(|(_, w)| w).sum();
    let wrss: f64 = inliers.iter().zip(&res).map(|((_, w), r)| w * r * r).sum();
    let rho = residual_correlation(&kept, &res);
    let inflation = (1.0 + rho) / (1.0 - rho);
    let sigma2 = wrss / (sum_w - 4.0).max(1.0) * inflation;
    let cov = shape_covariance(&inliers, &scales, (amp, c3, b, offset), sigma2, p.wheel_scale_sigma)?;
    let e_t = (-c3 * s_t).exp();
    // dS_T/d(A, C3, b, c) and dmu_T/d(A, C3, b, c) (the envelope theorem: dmu/dS = 0 at S_T)
    let ln_arg = (amp * c3 / b).ln();
    let g_s = [1.0 / (amp * c3), (1.0 - ln_arg) / (c3 * c3), -1.0 / (b * c3), 0.0];
    let g_m = [1.0 - e_t, amp * s_t * e_t, -s_t, -1.0];
    let quad = |g: &[f64; 4]| -> f64 {
        let mut acc = 0.0;
        for r in 0..4 {
            for c in 0..4 {
                acc += g[r] * cov[r][c] * g[c];
            }
        }
        acc.max(0.0).sqrt()
    };
    let beyond = kept.iter().filter(|q| q.s > s_t && q.s <= s_t + p.peak_span).count();
    let below = kept.iter().filter(|q| q.s <= s_t && q.s > s_t - p.peak_span).count();
    let slip_top = kept.iter().fold(0.0f64, |acc, q| acc.max(q.s));
    let mut slips: Vec<f64> = kept.iter().map(|q| q.s).collect();
    let nth = (p.min_beyond as usize).clamp(1, slips.len()) - 1;
    let reach = *slips.select_nth_unstable_by(nth, |x, y| y.total_cmp(x)).1;
    Some(Fit {
        a: amp,
        c3,
        b,
        c: offset,
        s_t,
        s_t_std: quad(&g_s),
        mu_t,
        mu_t_std: quad(&g_m),
        s_t_band: f64::NAN,
        mu_t_band: f64::NAN,
        pairs: kept.len(),
        below,
        beyond,
        slip_top,
        reach,
        rms: (wrss / sum_w.max(1e-12)).sqrt(),
        wheel_scale: scales,
        shown: below as f64 >= p.min_beyond && beyond as f64 >= p.min_beyond,
        stamp,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::close;

    /// eq. 6's shape of method.md §14's test tyre (C1 1.2, C2 0.015, C3 6.4, C5 -3, C6 3.5) at K = 100.
    fn tyre_shape() -> (f64, f64, f64, f64) {
        let k: f64 = 100.0;
        (1.2 * (1.0 - (-0.015 * k).exp()), 6.4, 3.5 / k.sqrt(), -3.0 / k)
    }

    #[test]
    fn peak_of_method_md_test_vector() {
        let (a, c3, b, c) = tyre_shape();
        let (s_t, mu_t) = peak(a, c3, b, c).unwrap();
        close(s_t, 0.4431, 5e-5);
        close(mu_t, 0.7525, 5e-5);
        // the paper's constants at the same K
        let k: f64 = 100.0;
        let (s_p, mu_p) = peak(1.3 * (1.0 - (-0.01 * k).exp()), 7.058, 4.0 / k.sqrt(), -5.0 / k).unwrap();
        close(s_p, 0.3789, 5e-5);
        close(mu_p, 0.6635, 5e-5);
        assert!(peak(a, c3, -0.1, c).is_none());
    }

    /// A sweep of the front wheels over 0.02..0.7 with the rear wheels braking at `rear(phase)` and
    /// reading `rear_gain` of their traction, with deterministic noise; the last step's fit.
    fn sweep(
        learner: &mut CurveLearner,
        from: f64,
        secs: f64,
        noise: f64,
        rear: impl Fn(f64) -> f64,
        rear_gain: f64,
    ) -> Option<Fit> {
        let (a, c3, b, c) = tyre_shape();
        let mut out = None;
        let steps = (secs * 100.0) as usize;
        for i in 0..steps {
            let t = from + i as f64 / 100.0;
            let phase = (t % 1.6) / 1.6;
            let s_front = 0.02 + 0.68 * (1.0 - (2.0 * phase - 1.0).abs());
            let s_rear = rear(phase);
            let slip = [s_rear, s_front, s_front, s_rear];
            let mut mu = [0.0; 4];
            for w in 0..4 {
                let s = slip[w];
                let gain = if s < 0.0 { rear_gain } else { 1.0 };
                let jitter = noise * ((i * 7 + w * 13) as f64 * 0.618).sin();
                mu[w] = gain * s.signum() * shape(s.abs(), a, c3, b, c) + jitter;
            }
            out = learner.step(t, &slip, &mu, &[true; 4], 0.0);
        }
        out
    }

    /// The sweep with the rear wheels braking lightly (-0.03..-0.08), every wheel read as it is.
    fn drive(learner: &mut CurveLearner, from: f64, secs: f64, noise: f64) -> Option<Fit> {
        sweep(learner, from, secs, noise, |phase| -0.03 - 0.05 * phase, 1.0)
    }

    #[test]
    fn learns_the_peak_of_a_sweep() {
        let mut l = CurveLearner::new(Params::default(), 0.05);
        let f = drive(&mut l, 0.0, 6.0, 0.01).expect("a fit");
        assert!(f.shown, "{f:?}");
        close(f.s_t, 0.4431, 0.01);
        close(f.mu_t, 0.7525, 0.01);
        assert!(f.s_t_std > 0.0 && f.s_t_std < 0.03, "{f:?}");
        assert!(f.mu_t_std > 0.0 && f.mu_t_std < 0.02, "{f:?}");
    }

    #[test]
    fn the_served_band_adds_the_systematic_errors_the_flatness_and_the_level() {
        let f = drive(&mut CurveLearner::new(Params::default(), 0.05), 0.0, 6.0, 0.01).expect("a fit");
        let p = Params::default();
        // the sweep's slips reach peak_span past the peak: no part of it is unseen
        assert!(f.reach - f.s_t >= p.peak_span, "{f:?}");
        // without systematic errors and scale the band is then the fit's own
        let none = Params {
            s_t_sys: 0.0,
            tilt_sys: 0.0,
            mu_t_sys: 0.0,
            ..p
        };
        let own = f.with_bands(&none, 0.0);
        close(own.s_t_band, f.s_t_std, 1e-12);
        close(own.mu_t_band, f.mu_t_std, 1e-12);
        // the level: mu_T's band grows with the torques' scale, S_T's does not
        let level = f.with_bands(&none, 0.1);
        close(level.mu_t_band, f.mu_t_std.hypot(0.1 * f.mu_t), 1e-12);
        close(level.s_t_band, f.s_t_std, 1e-12);
        // the flatness: a flatter peak (half the |mu''(S_T)|) serves a wider S_T band
        let served = f.with_bands(&p, 0.05);
        let flatter = Fit { a: f.a * 0.5, ..f }.with_bands(&p, 0.05);
        assert!(served.s_t_band > f.s_t_std.hypot(p.s_t_sys), "{served:?}");
        assert!(flatter.s_t_band > served.s_t_band, "{flatter:?} vs {served:?}");
        // the learner serves its fits with these bands
        assert_eq!(f, f.with_bands(&p, 0.05));
    }

    #[test]
    fn a_sweep_that_stops_just_past_the_peak_serves_a_wider_s_t_band() {
        let full = drive(&mut CurveLearner::new(Params::default(), 0.05), 0.0, 6.0, 0.01).expect("a fit");
        // the same sweep fitted up to |S| 0.5 only: 0.06 past the peak (0.443)
        let short_params = Params {
            slip_max: 0.5,
            ..Params::default()
        };
        let short = drive(&mut CurveLearner::new(short_params, 0.05), 0.0, 6.0, 0.01).expect("a fit");
        assert!(full.shown && short.shown, "{full:?} {short:?}");
        assert!(full.reach - full.s_t >= Params::default().peak_span, "{full:?}");
        assert!(short.reach <= 0.5 && short.reach - short.s_t < 0.07, "{short:?}");
        assert!(short.s_t_band > full.s_t_band + 0.02, "{short:?} vs {full:?}");
    }

    #[test]
    fn a_peak_beyond_the_slips_is_not_shown() {
        let mut l = CurveLearner::new(
            Params {
                slip_max: 0.3,
                ..Params::default()
            },
            0.05,
        );
        let f = drive(&mut l, 0.0, 6.0, 0.01);
        assert!(f.map_or(true, |f| !f.shown), "{f:?}");
    }

    #[test]
    fn another_soil_starts_anew() {
        let mut l = CurveLearner::new(Params::default(), 0.05);
        assert!(drive(&mut l, 0.0, 6.0, 0.01).is_some());
        // the same sweep on ground whose traction is 0.3 higher at every slip: the old pairs go at once
        let (a, c3, b, c) = tyre_shape();
        let mut fit = None;
        for i in 0..60 {
            let t = 6.0 + i as f64 / 100.0;
            let s = 0.1 + 0.005 * i as f64;
            fit = l.step(t, &[s; 4], &[shape(s, a, c3, b, c) + 0.3; 4], &[true; 4], 0.0);
            if fit.is_none() {
                break;
            }
        }
        assert!(fit.is_none(), "{fit:?}");
        assert!(l.pairs.iter().all(|q| q.t >= 6.0), "older pairs kept");
        assert_eq!(l.changes(), 1);
    }

    #[test]
    fn slip_errors_on_the_steep_rise_tell_no_change() {
        let mut l = CurveLearner::new(Params::default(), 0.05);
        assert!(drive(&mut l, 0.0, 6.0, 0.01).is_some_and(|f| f.shown));
        // the sweep's low end with every slip read 0.04 high for 0.3 s (a late GNSS ground speed): the
        // traction sits about 0.1 below the curve at those slips, yet the ground did not change
        let (a, c3, b, c) = tyre_shape();
        for i in 0..30 {
            let t = 6.0 + i as f64 / 100.0;
            let s = 0.05 + 0.001 * i as f64;
            l.step(t, &[s + 0.04; 4], &[shape(s, a, c3, b, c); 4], &[true; 4], 0.0);
        }
        assert_eq!(l.changes(), 0);
        // the traction 0.1 lower near the peak, where the curve is flat: another soil
        for i in 0..50 {
            let t = 6.3 + i as f64 / 100.0;
            let s = 0.4 + 0.001 * i as f64;
            l.step(t, &[s; 4], &[shape(s, a, c3, b, c) - 0.1; 4], &[true; 4], 0.0);
        }
        assert_eq!(l.changes(), 1);
    }

    #[test]
    fn too_few_pairs_give_no_fit() {
        let mut l = CurveLearner::new(Params::default(), 0.05);
        assert!(drive(&mut l, 0.0, 0.3, 0.0).is_none());
    }

    /// The sweep with the rear wheels held braking at |S| 0.35..0.36, reading `rear_gain` of their
    /// traction (a torque constant off on that axle); the fit of it.
    fn drive_with_the_rear_held(sigma_g: f64, rear_gain: f64) -> Fit {
        let mut l = CurveLearner::new(
            Params {
                wheel_scale_sigma: sigma_g,
                ..Params::default()
            },
            0.05,
        );
        sweep(&mut l, 0.0, 6.0, 0.01, |phase| -0.35 - 0.01 * phase, rear_gain).expect("a fit")
    }

    #[test]
    fn a_wheel_that_reads_low_moves_no_peak() {
        // one curve for every wheel: the rear axle's many low pairs at one slip pull the curve down
        // there and move the peak
        let one = drive_with_the_rear_held(0.0, 0.95);
        assert!((one.s_t - 0.4431).abs() > 0.02, "{one:?}");
        assert_eq!(one.wheel_scale, [1.0; 4]);
        // a scale per wheel: the peak stays, and the rear wheels' scale reads their gain
        let own = drive_with_the_rear_held(0.05, 0.95);
        assert!(own.shown, "{own:?}");
        close(own.s_t, 0.4431, 0.01);
        let ratio = own.wheel_scale[0] / own.wheel_scale[1];
        close(ratio, 0.95, 0.01);
        close(own.wheel_scale[0], own.wheel_scale[3], 0.005);
    }

    #[test]
    fn pairs_of_another_latency_are_dropped() {
        let mut l = CurveLearner::new(Params::default(), 0.05);
        assert!(drive(&mut l, 0.0, 6.0, 0.01).is_some());
        let n = l.pairs.len();
        let (a, c3, b, c) = tyre_shape();
        // the same latency within latency_change: every pair stays
        l.step(6.0, &[0.3; 4], &[shape(0.3, a, c3, b, c); 4], &[true; 4], 0.02);
        assert_eq!(l.pairs.len(), n + 4);
        // a latency estimate 0.1 s on: the pairs of the old one go, without a change of soil
        let fit = l.step(6.01, &[0.3; 4], &[shape(0.3, a, c3, b, c); 4], &[true; 4], 0.1);
        assert_eq!(l.pairs.len(), 4);
        assert!(fit.is_none(), "{fit:?}");
        assert_eq!(l.changes(), 0);
    }

    #[test]
    fn the_band_carries_what_the_wheel_scales_leave_uncertain() {
        // the scales share the vehicle's level with A, b and c: only their prior pins it, so the learnt
        // mu_T keeps about mu_T sigma_g / 2 (four wheels) of band however many pairs there are; S_T does
        // not depend on the level
        let fixed = drive_with_the_rear_held(0.0, 1.0);
        let free = drive_with_the_rear_held(0.05, 1.0);
        let level = free.mu_t * 0.05 / 2.0;
        assert!(
            free.mu_t_std > 0.9 * level && free.mu_t_std > 2.0 * fixed.mu_t_std,
            "{fixed:?} {free:?}"
        );
        assert!(free.s_t_std < 1.5 * fixed.s_t_std + 1e-3, "{fixed:?} {free:?}");
    }
}
