//! The systematic part of K's band from a gross-traction scale error c common to every sample
//! (the torque constant; docs/method.md §9, "The band"): the scale profile over the window's
//! samples, minimised over ln K for each c on nodes over +-4 sigma, and c's posterior.

use crate::soil::numeric::{grid_sum, row_min_ignoring_nan, row_top};

/// The nodes of c in units of its 1-sigma (`np.linspace(-4, 4, 25)` from the Python side) and
/// their log prior N(0, 1) in those units.
#[derive(Clone, Debug)]
pub struct ScaleNodes {
    pub z: Vec<f64>,
    pub log_prior: Vec<f64>,
}

/// ln K at the least value of a profile row `f` (G) and that value, both refined by the parabola
/// through the nodes around it (at the grid's ends: its last interior node +- half a step).
/// Values within 1e-9 (relative) of the least are ties and the lowest ln K among them is taken:
/// where the curve saturates (K >~ 1000, §9) a scaled profile is flat to 1e-14, and a plain argmin
/// would pick a node of that plateau by rounding.
pub fn profile_argmin(f: &[f64], theta: &[f64], dtheta: f64) -> (f64, f64) {
    profile_argmin_from(f, row_min_ignoring_nan(f), theta, dtheta)
}

/// [`profile_argmin`] given the row's least non-NaN value `low` (the fold of f64::min; a zero's
/// sign aside, which the tie below does not see: low + 1e-9 |low| is +0 for either).
#[inline(always)]
fn profile_argmin_from(f: &[f64], low: f64, theta: &[f64], dtheta: f64) -> (f64, f64) {
    let g = f.len();
    let tie = low + 1e-9 * low.abs();
    let least = f.iter().position(|&v| v <= tie).unwrap_or(0);
    let i = least.clamp(1, g - 2);
    let (y0, y1, y2) = (f[i - 1], f[i], f[i + 1]);
    let curv = y0 - 2.0 * y1 + y2;
    let off = if curv > 0.0 { 0.5 * (y0 - y2) / curv } else { 0.0 };
    let off = off.clamp(-0.5, 0.5); // NaN stays NaN
    (theta[i] + off * dtheta, y1 - 0.25 * (y0 - y2) * off)
}

/// [`scale_shift_with`]'s rows, kept by the caller between steps: no allocation per step.
#[derive(Clone, Debug, Default)]
pub struct ScaleScratch {
    row: Vec<f64>,
    two_oh: Vec<f64>,
    c: Vec<f64>,
    th: Vec<f64>,
    post: Vec<f64>,
    shift2: Vec<f64>,
    pc: Vec<f64>,
    pc2: Vec<f64>,
}

/// A scale c's misfit row c (c S_hh - 2 S_oh) into `row`, and its least non-NaN value.
#[inline(always)]
fn misfit_row(cv: f64, s_hh: &[f64], two_oh: &[f64], row: &mut [f64]) -> f64 {
    for ((r, &hh), &oh2) in row.iter_mut().zip(s_hh).zip(two_oh) {
        *r = cv * (cv * hh - oh2);
    }
    row_min_ignoring_nan(row)
}

/// (systematic 1-sigma of ln K, c's posterior mean, c's posterior 1-sigma) from the window's
/// per-node sums `s_oh` = sum w obs h(theta), `s_hh` = sum w h(theta)^2 (G each), for a scale
/// 1-sigma `sigma`.  The misfit of obs = c h(theta), less sum w obs^2 (the same for every c), is
/// M(c) = min_theta c (c S_hh - 2 S_oh); c's posterior is its prior times exp(-M / 2), and the
/// systematic 1-sigma the root mean square of theta*(c) - theta*(1) under it.
///
/// `w`: the caller's scratch rows (no allocation per step).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn scale_shift_with(
    s_oh: &[f64],
    s_hh: &[f64],
    sigma: f64,
    nodes: &ScaleNodes,
    theta: &[f64],
    dtheta: f64,
    w: &mut ScaleScratch,
) -> [f64; 3] {
    if sigma <= 0.0 {
        return [0.0, 1.0, 0.0];
    }
    if !s_hh.iter().any(|&v| v != 0.0) {
        // no samples in the window: every c fits alike
        return [0.0, 1.0, sigma];
    }
    let nc = nodes.z.len();
    let g = s_hh.len();
    let fill = |v: &mut Vec<f64>, n: usize| {
        v.clear();
        v.resize(n, 0.0);
    };
    w.c.clear();
    w.c.extend(nodes.z.iter().map(|&z| 1.0 + sigma * z));
    fill(&mut w.row, g);
    fill(&mut w.th, nc);
    fill(&mut w.post, nc); // first ln of c's posterior, then the posterior
                           // 2 S_oh, the same product for every c: made once
    w.two_oh.clear();
    w.two_oh.extend(s_oh.iter().map(|&oh| 2.0 * oh));
    for (ci, &cv) in w.c.iter().enumerate() {
        let low = misfit_row(cv, s_hh, &w.two_oh, &mut w.row);
        let (t, m) = profile_argmin_from(&w.row, low, theta, dtheta);
        w.th[ci] = t;
        w.post[ci] = nodes.log_prior[ci] - 0.5 * m;
    }
    let top = row_top(&w.post);
    for v in w.post.iter_mut() {
        *v = (*v - top).exp();
    }
    let total = grid_sum(&w.post);
    for v in w.post.iter_mut() {
        *v /= total;
    }
    let (post, th, c) = (&w.post, &w.th, &w.c);
    let mid = th[nc / 2];
    w.shift2.clear();
    w.shift2
        .extend(post.iter().zip(th).map(|(&p, &t)| p * ((t - mid) * (t - mid))));
    w.pc.clear();
    w.pc.extend(post.iter().zip(c).map(|(&p, &cv)| p * cv));
    w.pc2.clear();
    w.pc2.extend(post.iter().zip(c).map(|(&p, &cv)| p * (cv * cv)));
    let (c_mean, c2) = (grid_sum(&w.pc), grid_sum(&w.pc2));
    [
        grid_sum(&w.shift2).sqrt(),
        c_mean,
        (c2 - c_mean * c_mean).max(0.0).sqrt(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nodes() -> ScaleNodes {
        let z: Vec<f64> = (0..25).map(|i| -4.0 + 8.0 * i as f64 / 24.0).collect();
        let log_prior = z.iter().map(|v| -0.5 * (v * v)).collect();
        ScaleNodes { z, log_prior }
    }

    #[test]
    fn argmin_refines_a_parabola() {
        let theta: Vec<f64> = (0..11).map(|i| i as f64).collect();
        let f: Vec<f64> = theta.iter().map(|t| (t - 4.3) * (t - 4.3) + 2.0).collect();
        let (t, m) = profile_argmin(&f, &theta, 1.0);
        assert!((t - 4.3).abs() < 1e-12 && (m - 2.0).abs() < 1e-12);
    }

    /// Where the curve saturates the scaled misfit is flat to 1e-14 over a plateau of ln K: theta*(c)
    /// is the plateau's lowest node whatever the rounding (a plain argmin picked any node in it).
    #[test]
    fn a_flat_profile_gives_its_lowest_node() {
        let g = 241;
        let theta: Vec<f64> = (0..g).map(|i| i as f64 * 0.03).collect();
        for seed in 0..5u64 {
            let mut f: Vec<f64> = (0..g)
                .map(|i| {
                    if i < 150 {
                        -900.0 - 100.0 * i as f64 / 149.0
                    } else {
                        -1000.0
                    }
                })
                .collect();
            // +-1e-14 relative wobble on the plateau (a cheap deterministic pseudo-random sequence)
            let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            for v in f[150..].iter_mut() {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                *v *= 1.0 + 1e-14 * (((x >> 11) as f64 / (1u64 << 53) as f64) - 0.5);
            }
            let (t, least) = profile_argmin(&f, &theta, 0.03);
            assert!((t - theta[150]).abs() <= 0.03, "seed {seed}: {t}");
            assert!((least + 1000.0).abs() < 1.0);
        }
    }

    #[test]
    fn empty_window_and_no_scale_error() {
        let theta = [0.0, 1.0, 2.0];
        assert_eq!(
            scale_shift_with(
                &[0.0; 3],
                &[0.0; 3],
                0.05,
                &nodes(),
                &theta,
                1.0,
                &mut ScaleScratch::default()
            ),
            [0.0, 1.0, 0.05]
        );
        assert_eq!(
            scale_shift_with(
                &[1.0; 3],
                &[1.0; 3],
                0.0,
                &nodes(),
                &theta,
                1.0,
                &mut ScaleScratch::default()
            ),
            [0.0, 1.0, 0.0]
        );
    }

    /// Data that fit c = 1 at a profile curved in theta: c's posterior centres near 1.
    #[test]
    fn data_at_unit_scale() {
        let theta: Vec<f64> = (0..41).map(|i| i as f64 * 0.1).collect();
        // h(theta) = theta, obs = 2: S_oh = w obs h, S_hh = w h^2 with w = 100
        let s_oh: Vec<f64> = theta.iter().map(|t| 100.0 * 2.0 * t).collect();
        let s_hh: Vec<f64> = theta.iter().map(|t| 100.0 * t * t).collect();
        let [sys, mean, sd] = scale_shift_with(&s_oh, &s_hh, 0.05, &nodes(), &theta, 0.1, &mut ScaleScratch::default());
        assert!((mean - 1.0).abs() < 0.02 && sd < 0.06 && sys > 0.0, "{sys} {mean} {sd}");
    }
}
