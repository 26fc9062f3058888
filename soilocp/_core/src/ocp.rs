//! The optimal control parameters of a soil strength K: S_T (eq. 7, sign corrected), mu_T
//! (eq. 8), S_E (eq. 10, clamped at 0) and the tractive efficiency at S_E (eq. 9).

use crate::constants::Constants;
use crate::traction;

/// mu_T, S_T, S_E and TE(S_E) of one K; all NaN for a missing K (NaN).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ocp {
    pub mu_t: f64,
    pub s_t: f64,
    pub s_e: f64,
    pub te_at_s_e: f64,
}

/// S_T(K), eq. 7 with its sign corrected (docs/method.md §1): d mu/dS = 0 in eq. 6 gives
/// S_T = (1/C3) ln(C1 C3 sqrt(K) (1 - e^{-C2 K}) / C6), the reciprocal of the printed argument.
/// Below K of about 12.9 (paper constants) the argument is < 1: no interior peak, S_T = 0.
#[inline]
pub fn slip_traction(k: f64, c: &Constants) -> f64 {
    let arg = c.c1 * c.c3 * k.sqrt() * -(-c.c2 * k).exp_m1() / c.c6;
    (arg.ln() / c.c3).max(0.0)
}

/// mu_T(K) = mu(S_T(K), K), eq. 8 (eq. 6 at the corrected S_T).  With a bridge (docs/method.md
/// §8) a peak at the origin is taken at the bridge's end point, where the printed curve starts.
#[inline]
pub fn max_traction(k: f64, s_t: f64, c: &Constants) -> f64 {
    let s = if c.bridge_slip > 0.0 {
        s_t.max(c.bridge_slip)
    } else {
        s_t
    };
    traction::net(s, k, c).value
}

/// S_E(K) = (K - alpha) / beta, eq. 10, clamped at 0 (docs/method.md §5: above K = alpha the
/// most efficient slip is the smallest one; eq. 9 has no interior peak with the printed C5).
#[inline]
pub fn slip_efficiency(k: f64, c: &Constants) -> f64 {
    ((k - c.alpha) / c.beta).max(0.0)
}

/// Whether K is a soil strength the model can evaluate: NaN (no estimate) or finite, > 0, with
/// C5 / K finite.
#[inline]
pub fn evaluable(k: f64, c: &Constants) -> bool {
    k.is_nan() || (k.is_finite() && k > 0.0 && (c.c5 / k).is_finite())
}

/// The OCPs ([`ocp`]) of a bank of K, or the error that names the first K the model cannot
/// evaluate (its index in `ks`).
pub fn bank(ks: &[f64], c: &Constants) -> Result<Vec<Ocp>, String> {
    if let Some(i) = ks.iter().position(|&k| !evaluable(k, c)) {
        return Err(format!(
            "soil_strength[{i}] = {} is not a K the model can evaluate (finite, > 0, C5 / K finite)",
            ks[i]
        ));
    }
    Ok(ks.iter().map(|&k| ocp(k, c)).collect())
}

/// Eqs. 7, 8, 10 and eq. 9 at S_E (NaN where S_E is not a driving slip in (0, 1)), for a K the
/// caller has found [`evaluable`]; all NaN for a missing K.
#[inline]
pub fn ocp(k: f64, c: &Constants) -> Ocp {
    if k.is_nan() {
        return Ocp {
            mu_t: f64::NAN,
            s_t: f64::NAN,
            s_e: f64::NAN,
            te_at_s_e: f64::NAN,
        };
    }
    let s_t = slip_traction(k, c);
    let s_e = slip_efficiency(k, c);
    let te_at_s_e = if s_e > 0.0 && s_e < 1.0 {
        traction::tractive_efficiency(s_e, k, c)
    } else {
        f64::NAN
    };
    Ocp {
        mu_t: max_traction(k, s_t, c),
        s_t,
        s_e,
        te_at_s_e,
    }
}

/// Points of K's band at which [`band`] evaluates the OCPs (odd: K itself is one).
const BAND_POINTS: usize = 9;

/// The 1-sigma that K's own band carries into (mu_T, S_T): half the largest departure of each from
/// its value at K over ln K +- 2 `log_std` (the 2-sigma band of a belief Gaussian in ln K),
/// evaluated at [`BAND_POINTS`] points because mu_T(K) is not monotone (it has a minimum near
/// K = 30 with the paper's constants).  NaN for a missing K or band.
pub fn band(k: f64, log_std: f64, c: &Constants) -> [f64; 2] {
    if !(k.is_finite() && k > 0.0 && log_std.is_finite() && log_std >= 0.0) {
        return [f64::NAN; 2];
    }
    let at = ocp(k, c);
    let (mut mu, mut s) = (0.0_f64, 0.0_f64);
    for i in 0..BAND_POINTS {
        let z = 4.0 * i as f64 / (BAND_POINTS - 1) as f64 - 2.0;
        let o = ocp(k * (z * log_std).exp(), c);
        mu = mu.max((o.mu_t - at.mu_t).abs());
        s = s.max((o.s_t - at.s_t).abs());
    }
    [0.5 * mu, 0.5 * s]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::close;

    const C: Constants = Constants::PAPER;

    /// docs/method.md, "Test vectors: the OCP table".
    #[test]
    fn ocp_table_of_method_md() {
        for (k, s_t, mu_t, s_e) in [
            (50.0, 0.2626, 0.3828, 0.1197),
            (80.0, 0.3435, 0.5614, 0.1139),
            (120.0, 0.4060, 0.7501, 0.1063),
            (200.0, 0.4724, 0.9754, 0.0911),
            (300.0, 0.5145, 1.1004, 0.0720),
            (1000.0, 0.6070, 1.2102, 0.0),
        ] {
            let o = ocp(k, &C);
            close(o.s_t, s_t, 5e-5);
            close(o.mu_t, mu_t, 5e-5);
            close(o.s_e, s_e, 5e-5);
        }
        assert!(ocp(1000.0, &C).te_at_s_e.is_nan(), "S_E = 0 is not a driving slip");
    }

    /// Full precision for sand (`soilocp ocp -k 50 --json`, docs/method.md).
    #[test]
    fn sand_to_full_precision() {
        let o = ocp(50.0, &C);
        close(o.mu_t, 0.38280820557669404, 1e-15);
        close(o.s_t, 0.26260852957602204, 1e-15);
        close(o.s_e, 0.11966659673081692, 1e-15);
    }

    /// docs/method.md §1 and §5: S_T(12.93) ~ 0, S_T(15) = 0.0302, mu_T at low K, S_E at alpha.
    #[test]
    fn low_k_and_eq10_vectors_of_method_md() {
        assert!(slip_traction(12.93, &C) < 1e-4);
        close(slip_traction(15.0, &C), 0.0302, 5e-5);
        for (k, mu_t) in [
            (10.0, 0.4980),
            (13.0, 0.3846),
            (20.0, 0.2803),
            (25.0, 0.2687),
            (30.0, 0.2780),
        ] {
            close(ocp(k, &C).mu_t, mu_t, 5e-5);
        }
        assert_eq!(slip_efficiency(677.4, &C), 0.0);
        close(slip_efficiency(677.39, &C), 1.9e-6, 5e-8);
        assert_eq!(slip_efficiency(1000.0, &C), 0.0);
    }

    #[test]
    fn missing_and_unevaluable_k() {
        assert!(ocp(f64::NAN, &C).mu_t.is_nan());
        assert!(evaluable(f64::NAN, &C) && evaluable(50.0, &C));
        assert!(!evaluable(0.0, &C) && !evaluable(-1.0, &C) && !evaluable(f64::INFINITY, &C));
        assert!(!evaluable(1e-320, &C), "C5 / K overflows");
        let got = bank(&[50.0, f64::NAN], &C).unwrap();
        assert_eq!(got[0], ocp(50.0, &C));
        assert!(got[1].mu_t.is_nan());
        let err = bank(&[50.0, f64::NAN, -1.0], &C).unwrap_err();
        assert!(err.starts_with("soil_strength[2] = -1"), "{err}");
    }

    #[test]
    fn band_carries_k_band_through_the_curve() {
        // no band: no spread; a missing K: none
        assert_eq!(band(80.0, 0.0, &C), [0.0, 0.0]);
        assert!(band(f64::NAN, 0.1, &C)[0].is_nan());
        // at K 80 a 2-sigma band of +-29 % (ln K 1-sigma 0.143) moves mu_T by 0.13 and S_T by 0.05
        let [mu, s] = band(80.0, 0.143, &C);
        let hi = ocp(80.0 * 0.286_f64.exp(), &C);
        let at = ocp(80.0, &C);
        close(mu, 0.5 * (hi.mu_t - at.mu_t), 1e-12);
        assert!(mu > 0.06 && mu < 0.07, "{mu}");
        assert!(s > 0.02 && s < 0.03, "{s}");
        // near mu_T's minimum (K 30) both ends rise: the largest departure, not the ends' difference
        let [mu30, _] = band(30.0, 0.143, &C);
        assert!(mu30 > 0.02, "{mu30}");
    }
}
