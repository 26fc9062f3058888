//! The soil update's reductions over the grid: sums in eight lanes, the cumulative sum in order,
//! linear interpolation from the last node at or below x (beyond the ends: the end values), the
//! extremes of a row.

/// The mid-point CDF of a belief, `np.cumsum(p) - 0.5 * p`, into `out`.
#[inline(always)]
pub fn midpoint_cdf(p: &[f64], out: &mut [f64]) {
    let mut acc = 0.0;
    for (o, &x) in out.iter_mut().zip(p) {
        acc += x;
        *o = acc - 0.5 * x;
    }
}

/// `np.interp(x, xp, fp)` for one x (xp non-decreasing): beyond the ends the end values; between
/// nodes the line from the last node at or below x.
#[inline(always)]
pub fn interp(x: f64, xp: &[f64], fp: &[f64]) -> f64 {
    let n = xp.len();
    if x > xp[n - 1] {
        return fp[n - 1];
    }
    if x < xp[0] {
        return fp[0];
    }
    // the last j with xp[j] <= x (numpy's binary_search_with_guess)
    let j = xp.partition_point(|&v| v <= x) - 1;
    if j == n - 1 || xp[j] == x {
        return fp[j];
    }
    let slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
    let mut r = slope * (x - xp[j]) + fp[j];
    if r.is_nan() {
        r = slope * (x - xp[j + 1]) + fp[j + 1];
        if r.is_nan() && fp[j] == fp[j + 1] {
            r = fp[j];
        }
    }
    r
}

#[cfg(test)] // the reference the tests hold the `_with` / fast form to
/// The largest value of a row (`np.max`; NaN propagates).
pub fn row_max(a: &[f64]) -> f64 {
    let mut m = a[0];
    for &x in &a[1..] {
        if x > m || x.is_nan() {
            m = x;
        }
    }
    m
}

/// The sum of a row in eight lanes (vector registers), combined pairwise at the end, then the
/// last n % 8 values in order: one pass, and a rounding error that grows with n / 8.
#[inline(always)]
pub fn grid_sum(a: &[f64]) -> f64 {
    let chunks = a.chunks_exact(8);
    let rest = chunks.remainder();
    let mut r = [0.0f64; 8];
    for c in chunks {
        for (rj, &x) in r.iter_mut().zip(c) {
            *rj += x;
        }
    }
    let mut sum = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for &x in rest {
        sum += x;
    }
    sum
}

/// The largest value of a row, NaN if any is NaN: `np.max`'s value (the tests hold it to
/// `row_max`), found in four independent lanes (vector registers) instead of one chain.  Only the sign of a zero maximum can differ
/// from `row_max`'s (which keeps the first of equal values): callers that only subtract it from
/// the row before `exp` (x - 0.0 and x - (-0.0) are equal but for x = +-0, where exp gives 1
/// either way) get the same numbers.
#[inline(always)]
pub fn row_top(a: &[f64]) -> f64 {
    let mut lanes = [f64::NEG_INFINITY; 4];
    let mut nan = false;
    let mut chunks = a.chunks_exact(4);
    for c in &mut chunks {
        for (m, &x) in lanes.iter_mut().zip(c) {
            nan |= x.is_nan();
            *m = if x > *m { x } else { *m };
        }
    }
    for &x in chunks.remainder() {
        nan |= x.is_nan();
        lanes[0] = if x > lanes[0] { x } else { lanes[0] };
    }
    if nan {
        return f64::NAN;
    }
    let m01 = if lanes[1] > lanes[0] { lanes[1] } else { lanes[0] };
    let m23 = if lanes[3] > lanes[2] { lanes[3] } else { lanes[2] };
    if m23 > m01 {
        m23
    } else {
        m01
    }
}

/// The least non-NaN value of a row (`fold(INFINITY, f64::min)`: +inf if none), in four lanes;
/// only the sign of a zero minimum can differ from the fold's.
#[inline(always)]
pub fn row_min_ignoring_nan(a: &[f64]) -> f64 {
    // a lane is never NaN: x < m is false for a NaN x, which the lane then skips (f64::min's rule)
    let mut lanes = [f64::INFINITY; 4];
    let mut chunks = a.chunks_exact(4);
    for c in &mut chunks {
        for (m, &x) in lanes.iter_mut().zip(c) {
            *m = if x < *m { x } else { *m };
        }
    }
    for &x in chunks.remainder() {
        lanes[0] = if x < lanes[0] { x } else { lanes[0] };
    }
    lanes[0].min(lanes[1]).min(lanes[2].min(lanes[3]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_sum_adds_every_value() {
        assert_eq!(grid_sum(&[]), 0.0);
        assert_eq!(grid_sum(&[1.0, 2.0, 3.0]), 6.0);
        let long: Vec<f64> = (0..241).map(|i| i as f64 * 0.1).collect();
        let exact: f64 = (0..241).map(|i| i as f64).sum::<f64>() * 0.1;
        assert!((grid_sum(&long) - exact).abs() < 1e-9);
    }

    #[test]
    fn interp_matches_numpy_rules() {
        let xp = [0.0, 1.0, 1.0, 2.0];
        let fp = [0.0, 10.0, 20.0, 30.0];
        assert_eq!(interp(-1.0, &xp, &fp), 0.0);
        assert_eq!(interp(3.0, &xp, &fp), 30.0);
        assert_eq!(interp(0.5, &xp, &fp), 5.0);
        assert_eq!(interp(1.0, &xp, &fp), 20.0); // the last node at x
        assert_eq!(interp(1.5, &xp, &fp), 25.0);
    }

    /// The lane-wise extremes are the chained ones (NaN rules included).
    #[test]
    fn lane_extremes_are_the_chains() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for n in [1usize, 3, 4, 7, 25, 241] {
            for _ in 0..50 {
                let row: Vec<f64> = (0..n)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        (x >> 11) as f64 / (1u64 << 53) as f64 * 20.0 - 15.0
                    })
                    .collect();
                assert_eq!(row_top(&row).to_bits(), row_max(&row).to_bits());
                let fold = row.iter().copied().fold(f64::INFINITY, f64::min);
                assert_eq!(row_min_ignoring_nan(&row).to_bits(), fold.to_bits());
                let mut with_nan = row.clone();
                with_nan[n / 2] = f64::NAN;
                assert!(row_top(&with_nan).is_nan() && row_max(&with_nan).is_nan());
                let fold = with_nan.iter().copied().fold(f64::INFINITY, f64::min);
                assert_eq!(row_min_ignoring_nan(&with_nan).to_bits(), fold.to_bits());
            }
        }
        assert_eq!(row_min_ignoring_nan(&[f64::NAN; 5]), f64::INFINITY);
    }

    #[test]
    fn midpoint_cdf_of_uniform() {
        let p = [0.25; 4];
        let mut c = [0.0; 4];
        midpoint_cdf(&p, &mut c);
        assert_eq!(c, [0.125, 0.375, 0.625, 0.875]);
    }
}
