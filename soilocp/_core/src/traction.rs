//! The improved Brixius traction law, per unit normal load (paper eqs. 2-6 and 9), with the
//! corrections of docs/method.md §8 (linear bridge through S = 0) and §11 (net traction odd in S,
//! motion resistance even, gross = net + resistance).  Scalar functions of one (S, K): the Python
//! wrappers and every kernel that needs a traction coefficient call these.

use crate::constants::Constants;

/// A coefficient and its partial derivatives d/dS and d/dK.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Curve {
    pub value: f64,
    pub d_s: f64,
    pub d_k: f64,
}

/// Which curve of the law.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Net (drawbar) traction mu = F_DP / W, eq. 6.
    Net,
    /// Gross traction g = F_GT / W = mu + r, eq. 2 (eq. 3 while driving).
    Gross,
    /// Motion resistance r = F_MR / W, eq. 4 with |S|.
    Resistance,
}

impl Kind {
    pub fn parse(name: &str) -> Option<Kind> {
        match name {
            "net" => Some(Kind::Net),
            "gross" => Some(Kind::Gross),
            "resistance" => Some(Kind::Resistance),
            _ => None,
        }
    }
}

/// C1 (1 - e^{-C2 K}): the soil-strength factor shared by eqs. 3, 5, 6 and 8.
#[inline]
pub fn amplitude(k: f64, c: &Constants) -> f64 {
    c.c1 * -(-c.c2 * k).exp_m1()
}

/// Eq. 3 as printed for s >= 0: g = C1 (1 - e^{-C2 K})(1 - e^{-C3 s}) + C4.
#[inline]
fn gross_one_sided(s: f64, k: f64, c: &Constants) -> Curve {
    let amp = amplitude(k, c);
    let e = (-c.c3 * s).exp();
    Curve {
        value: amp * (1.0 - e) + c.c4,
        d_s: amp * c.c3 * e,
        d_k: c.c1 * c.c2 * (-c.c2 * k).exp() * (1.0 - e),
    }
}

/// Eq. 4 as printed for s >= 0: r = C5 / K + C4 + C6 s / sqrt(K).
#[inline]
fn resistance_one_sided(s: f64, k: f64, c: &Constants) -> Curve {
    let sq = k.sqrt();
    Curve {
        value: c.c5 / k + c.c4 + c.c6 * s / sq,
        d_s: c.c6 / sq,
        d_k: -c.c5 / (k * k) - 0.5 * c.c6 * s / (k * sq),
    }
}

/// Eq. 6 for s >= 0: mu = g - r (eq. 5 = eq. 3 - eq. 4).
#[inline]
fn net_one_sided(s: f64, k: f64, c: &Constants) -> Curve {
    let g = gross_one_sided(s, k, c);
    let r = resistance_one_sided(s, k, c);
    Curve {
        value: g.value - r.value,
        d_s: g.d_s - r.d_s,
        d_k: g.d_k - r.d_k,
    }
}

/// The odd extension of a one-sided curve, f(-S) = -f(S), with the linear bridge of
/// docs/method.md §8: inside |S| < bridge_slip the curve is the straight line through the origin
/// that meets the printed curve at +-bridge_slip (eq. 6 jumps from -C5/K to +C5/K at S = 0).
#[inline]
fn odd_bridged(one_sided: fn(f64, f64, &Constants) -> Curve, s: f64, k: f64, c: &Constants) -> Curve {
    let sign = if s < 0.0 { -1.0 } else { 1.0 };
    let a = s.abs();
    let b = c.bridge_slip;
    let mut out = one_sided(a, k, c);
    if b > 0.0 && a < b {
        let at_b = one_sided(b, k, c);
        let frac = a / b;
        out = Curve {
            value: at_b.value * frac,
            d_s: at_b.value / b,
            d_k: at_b.d_k * frac,
        };
    }
    Curve {
        value: sign * out.value,
        d_s: out.d_s,
        d_k: sign * out.d_k,
    }
}

/// The even extension of a one-sided curve, f(-S) = f(S) (docs/method.md §11), with the same
/// bridge, so that it vanishes at zero slip.
#[inline]
fn even_bridged(one_sided: fn(f64, f64, &Constants) -> Curve, s: f64, k: f64, c: &Constants) -> Curve {
    let sign = if s < 0.0 { -1.0 } else { 1.0 };
    let out = odd_bridged(one_sided, s.abs(), k, c);
    Curve {
        value: out.value,
        d_s: sign * out.d_s,
        d_k: out.d_k,
    }
}

/// Net traction mu(S, K), eq. 6, odd in S (docs/method.md §11), bridged near S = 0 (§8).
#[inline]
pub fn net(s: f64, k: f64, c: &Constants) -> Curve {
    odd_bridged(net_one_sided, s, k, c)
}

/// Motion resistance r(S, K), eq. 4 with |S|: even in S (docs/method.md §11), bridged (§8).
#[inline]
pub fn resistance(s: f64, k: f64, c: &Constants) -> Curve {
    even_bridged(resistance_one_sided, s, k, c)
}

/// Gross traction g = mu + r (eq. 2 with docs/method.md §11): eq. 3 while driving; for a braking
/// wheel -mu(|S|) + r(|S|), written as eq. 3's odd extension plus 2 r(|S|) so that eq. 3 and its
/// d/dK stay exact for S > 0 (not eq. 3's printed lower branch); bridged near S = 0 (§8).
#[inline]
pub fn gross(s: f64, k: f64, c: &Constants) -> Curve {
    let g = odd_bridged(gross_one_sided, s, k, c);
    if s < 0.0 {
        let r = even_bridged(resistance_one_sided, s, k, c);
        Curve {
            value: g.value + 2.0 * r.value,
            d_s: g.d_s + 2.0 * r.d_s,
            d_k: g.d_k + 2.0 * r.d_k,
        }
    } else {
        g
    }
}

/// One curve of the law by kind.
#[inline]
pub fn curve(kind: Kind, s: f64, k: f64, c: &Constants) -> Curve {
    match kind {
        Kind::Net => net(s, k, c),
        Kind::Gross => gross(s, k, c),
        Kind::Resistance => resistance(s, k, c),
    }
}

/// Tractive efficiency TE = (mu / g)(1 - S), eq. 9, for a driving slip 0 < S < 1 (the caller
/// checks the range).  While driving g is eq. 3 and mu = g - r, so eq. 3 is evaluated once.
#[inline]
pub fn tractive_efficiency(s: f64, k: f64, c: &Constants) -> f64 {
    let g = odd_bridged(gross_one_sided, s, k, c).value;
    let r = odd_bridged(resistance_one_sided, s, k, c).value;
    (g - r) / g * (1.0 - s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::close;

    const C: Constants = Constants::PAPER;

    /// docs/method.md, "Values of the curves" (default constants, outside the bridge).
    #[test]
    fn curve_values_of_method_md() {
        let rows: [(f64, [f64; 8]); 4] = [
            (50.0, [0.3024, 0.3737, 0.3802, 0.3137, 0.2990, 0.4900, -0.0034, 0.1097]),
            (80.0, [0.3802, 0.5144, 0.5581, 0.5338, 0.4024, 0.6697, 0.0222, 0.1117]),
            (120.0, [0.4651, 0.6556, 0.7312, 0.7409, 0.4999, 0.8391, 0.0348, 0.1079]),
            (200.0, [0.5658, 0.8185, 0.9289, 0.9747, 0.6091, 1.0288, 0.0433, 0.0999]),
        ];
        for (k, v) in rows {
            for (i, s) in [0.1, 0.2, 0.3, 0.5].into_iter().enumerate() {
                close(net(s, k, &C).value, v[i], 5e-5);
            }
            close(gross(0.1, k, &C).value, v[4], 5e-5);
            close(gross(0.3, k, &C).value, v[5], 5e-5);
            close(resistance(0.1, k, &C).value, v[6], 5e-5);
            close(resistance(0.3, k, &C).value, v[7], 5e-5);
        }
    }

    /// docs/method.md §8: the bridge (mu(0) = 0, mu(0.0025), mu(0.005)).
    #[test]
    fn bridge_values_of_method_md() {
        for (k, half, end) in [
            (50.0, 0.05745, 0.11491),
            (80.0, 0.04254, 0.08509),
            (120.0, 0.03567, 0.07134),
            (200.0, 0.03128, 0.06256),
        ] {
            assert_eq!(net(0.0, k, &C).value, 0.0);
            close(net(0.0025, k, &C).value, half, 5e-6);
            close(net(0.005, k, &C).value, end, 5e-6);
        }
    }

    /// docs/method.md §11: braking wheels (mu odd, resistance even, g = mu + r).
    #[test]
    fn braking_values_of_method_md() {
        for (k, s, mu, r, g) in [
            (80.0, -0.3, -0.5581, 0.1117, -0.4464),
            (50.0, -0.2, -0.3737, 0.0531, -0.3206),
            (200.0, -0.2, -0.8185, 0.0716, -0.7469),
            (50.0, -0.1, -0.3024, -0.0034, -0.3058),
            (80.0, 0.3, 0.5581, 0.1117, 0.6697),
        ] {
            close(net(s, k, &C).value, mu, 5e-5);
            close(resistance(s, k, &C).value, r, 5e-5);
            close(gross(s, k, &C).value, g, 5e-5);
        }
    }

    /// docs/method.md §4: d mu/dK and d g/dK (print: bridge off).
    #[test]
    fn k_derivatives_of_method_md() {
        let print = Constants { bridge_slip: 0.0, ..C };
        let ks = [50.0, 80.0, 120.0, 200.0, 300.0, 1000.0];
        let dmu_02 = [-8.49e-4, 4.37e-5, 1.99e-4, 1.21e-4, 3.74e-5, -3.66e-6];
        let dmu_3 = [6.63e-3, 5.20e-3, 3.55e-3, 1.63e-3, 6.29e-4, 1.45e-5];
        let dg_05 = [2.34e-3, 1.74e-3, 1.16e-3, 5.23e-4, 1.92e-4, 1.75e-7];
        for i in 0..ks.len() {
            let rel = |got: f64, want: f64| assert!((got / want - 1.0).abs() < 6e-3, "{got} vs {want}");
            rel(net(0.02, ks[i], &print).d_k, dmu_02[i]);
            rel(net(0.3, ks[i], &print).d_k, dmu_3[i]);
            rel(gross(0.05, ks[i], &print).d_k, dg_05[i]);
        }
    }

    /// docs/method.md §5: TE(0.1, 80) = 0.8503, TE(0.2, 200) = 0.7357, TE(0.01, 50) = 1.709.
    #[test]
    fn tractive_efficiency_of_method_md() {
        close(tractive_efficiency(0.1, 80.0, &C), 0.8503, 5e-5);
        close(tractive_efficiency(0.2, 200.0, &C), 0.7357, 5e-5);
        close(tractive_efficiency(0.01, 50.0, &C), 1.709, 5e-4);
    }

    /// The derivatives are those of the values (central differences), on both slip signs.
    #[test]
    fn derivatives_match_finite_differences() {
        for kind in [Kind::Net, Kind::Gross, Kind::Resistance] {
            for &s in &[-0.6, -0.2, -0.003, 0.002, 0.05, 0.4] {
                for &k in &[20.0, 80.0, 400.0] {
                    let h = 1e-6;
                    let c0 = curve(kind, s, k, &C);
                    let ds = (curve(kind, s + h, k, &C).value - curve(kind, s - h, k, &C).value) / (2.0 * h);
                    let dk =
                        (curve(kind, s, k + h * k, &C).value - curve(kind, s, k - h * k, &C).value) / (2.0 * h * k);
                    close(c0.d_s, ds, 1e-6 * (1.0 + ds.abs()));
                    close(c0.d_k, dk, 1e-8 * (1.0 + dk.abs()));
                }
            }
        }
    }
}
