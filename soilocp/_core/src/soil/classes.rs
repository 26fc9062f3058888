//! The soil class of a belief ln K ~ N(ln K, sigma^2) (docs/method.md §9, the record's class and
//! its probability): the Gaussian's mass between the class boundaries in ln K, which the Python
//! side makes from the soil table (soilocp.estimation.soil_state.class_bounds) with the names.

extern "C" {
    /// The C library's erf (Rust's standard library has none).
    #[link_name = "erf"]
    fn libm_erf(x: f64) -> f64;
}

#[inline]
fn erf(x: f64) -> f64 {
    // SAFETY: erf is a pure function of one double in the C library the standard library links
    unsafe { libm_erf(x) }
}

/// The most probable class (its index, ordered as `edges`' intervals) of ln K ~ N(`log_k`,
/// max(`log_k_std`, 1e-6)^2) and its probability, from the classes' boundaries `edges` (m + 1
/// values, ascending; +inf allowed: erf(+-inf) = +-1).  The first of equal maxima; a NaN wins, as
/// in numpy's argmax.
pub fn classify(log_k: f64, log_k_std: f64, edges: &[f64]) -> (usize, f64) {
    let sig = if log_k_std.is_nan() {
        f64::NAN
    } else {
        log_k_std.max(1e-6)
    };
    let den = sig * std::f64::consts::SQRT_2;
    let cdf = |e: f64| 0.5 * (1.0 + erf((e - log_k) / den));
    let mut best = (0, f64::NEG_INFINITY);
    let mut lo = cdf(edges[0]);
    for (i, &e) in edges[1..].iter().enumerate() {
        let hi = cdf(e);
        let p = hi - lo;
        if p.is_nan() {
            return (i, p);
        }
        if i == 0 || p > best.1 {
            best = (i, p);
        }
        lo = hi;
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_class_of_a_narrow_belief_is_its_interval() {
        let edges = [2.0, 3.0, 4.0, f64::INFINITY];
        let (i, p) = classify(3.5, 0.01, &edges);
        assert_eq!(i, 1);
        assert!(p > 0.999_999);
        let (i, p) = classify(10.0, 0.1, &edges);
        assert_eq!((i, p), (2, 1.0));
        assert!((classify(3.0, 1e-9, &edges).1 - 0.5).abs() < 1e-12);
    }
}
