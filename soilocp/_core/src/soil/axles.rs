//! Do the front and the rear axle read the same soil?  A check of the normal forces
//! (docs/method.md §16): per vehicle a front-only and a rear-only belief over ln K (the same
//! prediction and likelihood as the pooled one) and the decaying share of the window's time in
//! which they disagree by more than `axle_mismatch_z` of their combined spread.

use crate::soil::grid::Grid;
use crate::soil::numeric::{grid_sum, row_top};
use crate::soil::params::Params;

/// Per wheel (paper order: left-rear, left-front, right-front, right-rear): 0 front axle, 1 rear.
pub const AXLE_OF_WHEEL: [usize; 4] = [1, 0, 0, 1];

/// The verdict of one sample: whether the axles disagree, their z and each axle's ln K (NaN
/// while either axle has not informed its belief within `hold_after`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxleVerdict {
    pub mismatch: bool,
    pub z: f64,
    pub theta_front: f64,
    pub theta_rear: f64,
}

/// One vehicle's axle beliefs (front then rear, G each) and running disagreement.
#[derive(Clone, Debug)]
pub struct AxleCheck {
    pub p: [Vec<f64>; 2],
    /// stamp of each axle's last informative sample (NaN: never)
    pub informed: [f64; 2],
    /// decaying sums over judged samples: the time with z over the threshold, and all the time
    pub over: f64,
    pub weight: f64,
}

impl AxleCheck {
    pub fn new(g: usize) -> AxleCheck {
        AxleCheck {
            p: [vec![1.0 / g as f64; g], vec![1.0 / g as f64; g]],
            informed: [f64::NAN; 2],
            over: 0.0,
            weight: 0.0,
        }
    }

    #[cfg(test)] // the allocating form, for the tests
    /// [`Self::update_with`] with its own scratch rows.
    pub fn update<L: AsRef<[f64]>>(&mut self, stamp: f64, wheels: &[usize], loglike: &[L]) {
        let g = self.p[0].len();
        let (mut acc, mut post) = (vec![0.0; g], vec![0.0; g]);
        self.update_with(stamp, wheels, loglike, &mut acc, &mut post);
    }

    /// Fuse the used wheels' tempered log-likelihoods: `loglike[j]` (G) of wheel `wheels[j]`.
    /// Both axles' beliefs are renormalised (an axle without a wheel gets a factor 1).
    ///
    /// With the caller's scratch rows `acc`, `post` (G each).
    #[inline(always)]
    pub fn update_with<L: AsRef<[f64]>>(
        &mut self,
        stamp: f64,
        wheels: &[usize],
        loglike: &[L],
        acc: &mut [f64],
        post: &mut [f64],
    ) {
        let g = self.p[0].len();
        let (acc, post) = (&mut acc[..g], &mut post[..g]);
        for axle in 0..2 {
            acc.fill(0.0);
            let mut hit = false;
            for (j, &w) in wheels.iter().enumerate() {
                if AXLE_OF_WHEEL[w] == axle {
                    hit = true;
                    for (a, &l) in acc.iter_mut().zip(loglike[j].as_ref()) {
                        *a += l;
                    }
                }
            }
            if hit {
                let top = row_top(acc);
                for ((v, &p), &a) in post.iter_mut().zip(&self.p[axle]).zip(acc.iter()) {
                    *v = p * (a - top).exp();
                }
            } else {
                // no wheel: every acc is 0.0, its top 0.0 and exp(0.0 - 0.0) exactly 1: p x 1 = p
                post.copy_from_slice(&self.p[axle]);
            }
            let total = grid_sum(post);
            if total > 0.0 && total.is_finite() {
                for (p, v) in self.p[axle].iter_mut().zip(post.iter()) {
                    *p = v / total;
                }
            }
            if hit {
                self.informed[axle] = stamp;
            }
        }
    }

    #[cfg(test)] // the allocating form, for the tests
    /// [`Self::judge_with`] with its own scratch row.
    pub fn judge(&mut self, grid: &Grid, cfg: &Params, stamp: f64, dt: f64, tolerance: f64) -> AxleVerdict {
        let mut cdf = vec![0.0; self.p[0].len()];
        self.judge_with(grid, cfg, stamp, dt, tolerance, &mut cdf)
    }

    /// The verdict after this sample's update, `dt` s after the vehicle's previous sample (NaN:
    /// none), with the ordinary model error `tolerance` in ln K.  Judged only while both axles
    /// informed their belief within `hold_after` s; a mismatch needs `mismatch_min_evidence` s of
    /// judged samples in the window, z above `axle_mismatch_z` for more than half of them, and now.
    ///
    /// With the caller's scratch row `cdf` (G).
    #[inline(always)]
    pub fn judge_with(
        &mut self,
        grid: &Grid,
        cfg: &Params,
        stamp: f64,
        dt: f64,
        tolerance: f64,
        cdf: &mut [f64],
    ) -> AxleVerdict {
        let decay = if dt.is_finite() {
            (-dt.max(0.0) / cfg.evidence_window).exp()
        } else {
            0.0
        };
        self.over *= decay;
        self.weight *= decay;
        let [front, rear] = self.informed;
        if !(stamp - front <= cfg.hold_after && stamp - rear <= cfg.hold_after) {
            return AxleVerdict {
                mismatch: false,
                z: f64::NAN,
                theta_front: f64::NAN,
                theta_rear: f64::NAN,
            };
        }
        let [f16, f50, f84] = grid.quantiles(Grid::cdf_into(&self.p[0], cdf));
        let [r16, r50, r84] = grid.quantiles(Grid::cdf_into(&self.p[1], cdf));
        // ln of the reported K (the reference's exp then log)
        let (tf, tr) = (f50.exp().ln(), r50.exp().ln());
        let (sf, sr) = ((f84 - f16) / 2.0, (r84 - r16) / 2.0);
        let z = (tf - tr).abs() / (sf * sf + sr * sr + tolerance * tolerance).max(1e-24).sqrt();
        let step = if dt.is_finite() && dt > 0.0 { 1.0 - decay } else { 0.0 };
        self.weight += step;
        self.over += if z > cfg.axle_mismatch_z { step } else { 0.0 };
        let w = self.weight;
        let enough = w >= 1.0 - (-cfg.mismatch_min_evidence / cfg.evidence_window).exp();
        let mismatch = cfg.axle_mismatch_z > 0.0 && enough && z > cfg.axle_mismatch_z && self.over > 0.5 * w;
        AxleVerdict {
            mismatch,
            z,
            theta_front: tf,
            theta_rear: tr,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constants::Constants;
    use crate::traction::Kind;

    fn grid() -> Grid {
        let theta: Vec<f64> = (0..41).map(|i| i as f64 * 0.2).collect();
        let k = theta.iter().map(|t| t.exp()).collect();
        Grid::new(theta, k, None, Kind::Gross, Constants::PAPER).unwrap()
    }

    fn peak(at: usize) -> Vec<f64> {
        (0..41)
            .map(|i| (-0.5 * ((i as f64 - at as f64) / 2.0).powi(2)).exp())
            .collect()
    }

    /// Axles that read soils far apart for long enough are flagged; the same soil is not.
    #[test]
    fn disagreeing_axles_are_flagged() {
        let (gr, cfg) = (grid(), Params::default());
        for (front, rear, want) in [(10, 30, true), (20, 20, false)] {
            let mut a = AxleCheck::new(41);
            let mut last = AxleVerdict {
                mismatch: false,
                z: 0.0,
                theta_front: 0.0,
                theta_rear: 0.0,
            };
            for n in 0..300 {
                let stamp = n as f64 * 0.01;
                let ll: Vec<Vec<f64>> = [peak(rear), peak(front), peak(front), peak(rear)]
                    .iter()
                    .map(|v| v.iter().map(|x| 0.05 * x.ln()).collect())
                    .collect();
                a.update(stamp, &[0, 1, 2, 3], &ll);
                last = a.judge(&gr, &cfg, stamp, if n == 0 { f64::NAN } else { 0.01 }, 0.0);
            }
            assert_eq!(last.mismatch, want, "{last:?}");
        }
    }

    #[test]
    fn an_axle_never_informed_is_not_judged() {
        let (gr, cfg) = (grid(), Params::default());
        let mut a = AxleCheck::new(41);
        a.update(0.0, &[1], &[vec![0.0; 41]]);
        let v = a.judge(&gr, &cfg, 0.0, f64::NAN, 0.0);
        assert!(!v.mismatch && v.z.is_nan());
    }
}
