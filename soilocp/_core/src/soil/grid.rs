//! The ln K grid of the Bayes soil estimator (docs/method.md §9, §11): the traction curve on the
//! grid, the belief's prediction (random walk in ln K and a change hazard per metre), and the
//! belief's median and 16-84 % band.

use crate::constants::Constants;
use crate::soil::numeric::{interp, midpoint_cdf};
use crate::traction::{self, Kind};

/// The grid and the slip-independent factors of the curve on it.
#[derive(Clone, Debug)]
pub struct Grid {
    pub theta: Vec<f64>,
    pub k: Vec<f64>,
    pub dtheta: f64,
    pub span: f64,
    pub kind: Kind,
    pub c: Constants,
    /// C1 (1 - e^{-C2 K}), eq. 3's soil-strength factor
    amp: Vec<f64>,
    /// amp x C3, the first product of dh/dS (`amp * c3 * e` rounds amp x C3 first): made once here
    amp_c3: Vec<f64>,
    /// per side of S = 0 (0: S >= 0, 1: S < 0): the offset and the |S| slope of the curve
    offset: [Vec<f64>; 2],
    slope: [Vec<f64>; 2],
}

impl Grid {
    /// The grid `theta` (ln K nodes, equally spaced, increasing), `k` = e^theta and `amp` =
    /// C1 (1 - e^{-C2 K}) as the Python side made them (`np.linspace`, `np.exp`, `np.expm1`: numpy's
    /// exp differs from libm's in the last bit), for the `gross` or `net` curve; `amp` None: here.
    pub fn new(theta: Vec<f64>, k: Vec<f64>, amp: Option<Vec<f64>>, kind: Kind, c: Constants) -> Result<Grid, String> {
        let g = theta.len();
        if g < 3 || k.len() != g {
            return Err(format!(
                "grid: theta ({g}) and K ({}) need the same length >= 3",
                k.len()
            ));
        }
        if !theta.windows(2).all(|w| w[1] > w[0]) || !k.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err("grid: theta must increase and K be finite and > 0".into());
        }
        let amp = amp.unwrap_or_else(|| k.iter().map(|&v| crate::traction::amplitude(v, &c)).collect());
        if amp.len() != g {
            return Err(format!("grid: amp has {} values for {g} nodes", amp.len()));
        }
        let (offset, slope) = match kind {
            // S > 0: eq. 3.  S < 0 (§11): -mu(|S|) + r(|S|) = -g(|S|) + 2 r(|S|)
            Kind::Gross => (
                [vec![c.c4; g], k.iter().map(|&v| c.c4 + 2.0 * c.c5 / v).collect()],
                [vec![0.0; g], k.iter().map(|&v| 2.0 * c.c6 / v.sqrt()).collect()],
            ),
            // eq. 6, odd
            Kind::Net => (
                [
                    k.iter().map(|&v| -c.c5 / v).collect(),
                    k.iter().map(|&v| c.c5 / v).collect(),
                ],
                [
                    k.iter().map(|&v| -c.c6 / v.sqrt()).collect(),
                    k.iter().map(|&v| c.c6 / v.sqrt()).collect(),
                ],
            ),
            Kind::Resistance => return Err("grid: the soil estimator compares gross or net traction".into()),
        };
        let amp_c3 = amp.iter().map(|&a| a * c.c3).collect();
        Ok(Grid {
            dtheta: theta[1] - theta[0],
            span: theta[g - 1] - theta[0],
            theta,
            k,
            kind,
            c,
            amp,
            amp_c3,
            offset,
            slope,
        })
    }

    pub fn len(&self) -> usize {
        self.theta.len()
    }

    pub fn is_empty(&self) -> bool {
        self.theta.is_empty()
    }

    /// h(S, K_grid) and dh/dS into `h`, `d` (G each): gross traction g = mu + r (eq. 3 for S > 0,
    /// docs/method.md §11 for S < 0) or net traction (eq. 6).  `bridged`: some slip of the same
    /// batch lies inside the zero-slip bridge (§8): the whole batch is evaluated by the law itself
    /// (as the reference does); otherwise the curve factorises into grid constants and one exp:
    /// h = sign amp (1 - e^{-C3 |S|}) + offset_side + slope_side |S|.
    #[inline(always)]
    pub fn curve(&self, s: f64, bridged: bool, h: &mut [f64], d: &mut [f64]) {
        if bridged {
            for ((hv, dv), &k) in h.iter_mut().zip(d.iter_mut()).zip(&self.k) {
                let r = traction::curve(self.kind, s, k, &self.c);
                *hv = r.value;
                *dv = r.d_s;
            }
            return;
        }
        let a = s.abs();
        let e = (-self.c.c3 * a).exp();
        let side = usize::from(s < 0.0);
        let sign = if side == 1 { -1.0 } else { 1.0 };
        let (off, sl) = (&self.offset[side], &self.slope[side]);
        let one_e = 1.0 - e;
        // the same operations per node as amp (1 - e) x sign + off + sl |S| and amp C3 e + sl sign,
        // over zipped rows (no bounds checks: the loop runs in vector registers)
        let rows = self.amp.iter().zip(&self.amp_c3).zip(off.iter().zip(sl));
        for ((hv, dv), ((&amp, &amp_c3), (&o, &slope))) in h.iter_mut().zip(d.iter_mut()).zip(rows) {
            let rise = amp * one_e;
            *hv = sign * rise + o + slope * a;
            *dv = amp_c3 * e + slope * sign;
        }
    }

    /// Whether a slip lies inside the zero-slip bridge (§8), where the curve does not factorise.
    pub fn in_bridge(&self, s: f64) -> bool {
        s.abs() < self.c.bridge_slip
    }

    #[cfg(test)] // the allocating form, for the tests
    /// [`Self::predict_with`] with its own scratch row.
    pub fn predict(&self, p: &mut [f64], dt: f64, distance: f64, q_log_k: f64, change_per_metre: f64) {
        let mut q = vec![0.0; p.len()];
        self.predict_with(p, dt, distance, q_log_k, change_per_metre, &mut q);
    }

    /// A belief `p` (G) after `dt` > 0 s over `distance` m: diffusion of ln K (random walk in time,
    /// q_log_k per sqrt(s)) by a reflecting 3-tap kernel, then mixing with the uniform change prior
    /// with the hazard change_per_metre x distance; after a long gap or a long way, uniform at once.
    ///
    /// With a scratch row `q` (G) of the caller's: no allocation per step.
    #[inline(always)]
    pub fn predict_with(
        &self,
        p: &mut [f64],
        dt: f64,
        distance: f64,
        q_log_k: f64,
        change_per_metre: f64,
        q: &mut [f64],
    ) {
        let g = p.len();
        let h = change_per_metre * distance;
        let q2 = q_log_k * q_log_k;
        let lost = h >= 1.0 || q2 * dt >= self.span * self.span;
        let mut eps = if lost {
            p.fill(1.0 / g as f64);
            0.0
        } else {
            q2 * dt / (2.0 * (self.dtheta * self.dtheta))
        };
        let q = &mut q[..g];
        while eps > 0.0 {
            let e = eps.min(0.25); // the 3-tap kernel is a valid step for eps <= 1/4
            let w = 1.0 - 2.0 * e;
            // per node (w p_i + e p_{i-1}) + e p_{i+1}, the neighbour missing at an end; the ends'
            // nodes out of the loop, which then has no branch (g >= 3: Grid::new)
            q[0] = w * p[0] + e * p[1];
            for (qi, win) in q[1..g - 1].iter_mut().zip(p.windows(3)) {
                *qi = w * win[1] + e * win[0] + e * win[2];
            }
            q[g - 1] = w * p[g - 1] + e * p[g - 2];
            q[0] += e * p[0]; // reflecting ends keep the mass
            q[g - 1] += e * p[g - 1];
            p.copy_from_slice(q);
            eps -= e;
        }
        let h = h.min(1.0);
        let u = h / g as f64;
        for v in p.iter_mut() {
            *v = (1.0 - h) * *v + u;
        }
    }

    /// The node index of a mid-point CDF's median: the number of nodes below 1/2, within [lo, hi].
    #[inline(always)]
    pub fn median_node(cdf: &[f64], lo: usize, hi: usize) -> usize {
        cdf.iter().filter(|&&c| c < 0.5).count().max(lo).min(hi)
    }

    /// ln K at a belief's median from its mid-point CDF: `np.interp(0.5, cdf, theta)`, beyond the
    /// CDF's ends the end node.
    #[inline(always)]
    pub fn median(&self, cdf: &[f64]) -> f64 {
        let i = Self::median_node(cdf, 1, self.len() - 1);
        let (c0, c1) = (cdf[i - 1], cdf[i]);
        let f = ((0.5 - c0) / if c1 > c0 { c1 - c0 } else { 1.0 }).clamp(0.0, 1.0);
        self.theta[i - 1] + f * (self.theta[i] - self.theta[i - 1])
    }

    /// (ln K at 16 %, 50 %, 84 %) of a belief from its mid-point CDF: the band is half the 16-84 %
    /// interval (moments would be dominated by the small uniform change mass over K = 5..5000).
    #[inline(always)]
    pub fn quantiles(&self, cdf: &[f64]) -> [f64; 3] {
        [0.15865, 0.5, 0.84135].map(|x| interp(x, cdf, &self.theta))
    }

    #[cfg(test)] // the reference the tests hold the `_with` / fast form to
    /// The mid-point CDF of `p` (a fresh vector).
    pub fn cdf(p: &[f64]) -> Vec<f64> {
        let mut c = vec![0.0; p.len()];
        midpoint_cdf(p, &mut c);
        c
    }

    /// The mid-point CDF of `p` into the caller's row `c` (G): no allocation per step.
    #[inline(always)]
    pub fn cdf_into<'a>(p: &[f64], c: &'a mut [f64]) -> &'a [f64] {
        let c = &mut c[..p.len()];
        midpoint_cdf(p, c);
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(kind: Kind) -> Grid {
        let g = 241;
        let (a, b) = (5f64.ln(), 5000f64.ln());
        let theta: Vec<f64> = (0..g).map(|i| a + (b - a) * i as f64 / (g - 1) as f64).collect();
        let k = theta.iter().map(|t| t.exp()).collect();
        Grid::new(theta, k, None, kind, Constants::PAPER).unwrap()
    }

    /// The factorised curve is the law's (traction::curve) outside the bridge, both kinds and signs.
    #[test]
    fn factorised_curve_is_the_law() {
        for kind in [Kind::Gross, Kind::Net] {
            let gr = grid(kind);
            let (mut h, mut d) = (vec![0.0; 241], vec![0.0; 241]);
            for s in [0.3, 0.05, -0.2, -0.9] {
                gr.curve(s, false, &mut h, &mut d);
                for (g, &k) in gr.k.iter().enumerate() {
                    let want = traction::curve(kind, s, k, &Constants::PAPER);
                    assert!((h[g] - want.value).abs() < 1e-12, "{kind:?} {s} {k}");
                    assert!((d[g] - want.d_s).abs() < 1e-10);
                }
            }
        }
    }

    /// docs/method.md "Values of the curves": gross traction at K 200, S 0.3 is 1.0288.
    #[test]
    fn curve_test_vector() {
        let mut gr = grid(Kind::Gross);
        gr.k = vec![200.0; 3];
        let gr = Grid::new(vec![0.0, 1.0, 2.0], gr.k.clone(), None, Kind::Gross, Constants::PAPER).unwrap();
        let (mut h, mut d) = (vec![0.0; 3], vec![0.0; 3]);
        gr.curve(0.3, false, &mut h, &mut d);
        assert!((h[0] - 1.0288).abs() < 5e-5);
    }

    /// The prediction keeps the mass, spreads a spike, and a long way makes the belief uniform.
    #[test]
    fn predict_keeps_mass_and_spreads() {
        let gr = grid(Kind::Gross);
        let mut p = vec![0.0; 241];
        p[120] = 1.0;
        gr.predict(&mut p, 1.0, 0.0, 0.1, 0.5);
        assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(p[120] < 1.0 && p[119] > 0.0 && p[119] == p[121]);
        gr.predict(&mut p, 0.01, 2.0, 0.1, 0.5);
        assert!(p.iter().all(|&v| (v - 1.0 / 241.0).abs() < 1e-15));
    }

    #[test]
    fn median_of_a_symmetric_belief_is_its_centre() {
        let gr = grid(Kind::Gross);
        let p: Vec<f64> = (0..241)
            .map(|i| (-0.5 * ((i as f64 - 100.0) / 5.0).powi(2)).exp())
            .collect();
        let s: f64 = p.iter().sum();
        let p: Vec<f64> = p.iter().map(|v| v / s).collect();
        let cdf = Grid::cdf(&p);
        assert!((gr.median(&cdf) - gr.theta[100]).abs() < 1e-9);
        let [lo, mid, hi] = gr.quantiles(&cdf);
        assert!((mid - gr.theta[100]).abs() < 1e-9 && (hi - mid - (mid - lo)).abs() < 1e-9);
        assert!(((hi - lo) / 2.0 - 5.0 * gr.dtheta).abs() < 0.05 * gr.dtheta * 5.0);
    }
}
