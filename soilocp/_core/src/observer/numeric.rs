//! The arithmetic rules the observer's numbers depend on:
//!
//! * a NaN must reach the divergence guard: [`nan_min`] / [`nan_max`] propagate it (Rust's `f64::min`
//!   drops it), and [`sign`] keeps a zero's sign and a NaN as they came;
//! * a matrix product is, for each entry, one fused multiply-add per term in index order from 0
//!   ([`matmul`]; [`matvec`] is its one-column case): one rounding per term, the same numbers on every
//!   machine with FMA, and the zeros of our sparse matrices skipped.

/// -1, 0 or +1; 0.0, -0.0 and NaN as they came.
#[inline]
pub fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x
    }
}

/// The smaller of a and b, NaN if either is NaN.
#[inline]
pub fn nan_min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a < b {
        a
    } else {
        b
    }
}

/// The larger of a and b, NaN if either is NaN.
#[inline]
pub fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a > b {
        a
    } else {
        b
    }
}

/// x inside [lo, hi], NaN if x is NaN.
#[inline]
pub fn clip(x: f64, lo: f64, hi: f64) -> f64 {
    nan_min(nan_max(x, lo), hi)
}

/// C (m x p) = A (m x q) B (q x p), row-major, each entry's terms by fused multiply-adds in
/// order l = 0..q from 0.0.  A term whose a_il is 0 is skipped: it
/// adds an exact zero (our A, H, F and J are mostly zeros); only a non-finite b_lj behind a zero
/// a_il would have made the entry NaN, and the bank's divergence guard checks the state and P.
pub fn matmul(a: &[f64], b: &[f64], c: &mut [f64], m: usize, q: usize, p: usize) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has the FMA instructions (checked on the line above)
        unsafe { matmul_fma(a, b, c, m, q, p) };
        return;
    }
    matmul_body(a, b, c, m, q, p);
}

/// C (m x p) = A (m x q) B^T with B given as (p x q): B transposed into
/// `scratch` (at least q x p), then [`matmul`].
#[allow(clippy::too_many_arguments)]
pub fn matmul_bt(a: &[f64], b: &[f64], c: &mut [f64], m: usize, q: usize, p: usize, scratch: &mut [f64]) {
    for j in 0..p {
        for l in 0..q {
            scratch[l * p + j] = b[j * q + l];
        }
    }
    matmul(a, &scratch[..q * p], c, m, q, p);
}

/// y (m) = A (m x q) x (q), row-major: [`matmul`] of one column.
pub fn matvec(a: &[f64], x: &[f64], y: &mut [f64], m: usize, q: usize) {
    matmul(a, x, y, m, q, 1);
}

// `f64::mul_add` is one instruction where the compiler may use FMA, and a call to libm's fma
// (software, tens of ns) where it may not, as on the baseline x86-64 target: the product is
// compiled twice, the FMA copy chosen at run time.  Both round each fused product once: the same
// numbers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "fma")]
unsafe fn matmul_fma(a: &[f64], b: &[f64], c: &mut [f64], m: usize, q: usize, p: usize) {
    matmul_body(a, b, c, m, q, p);
}

#[inline(always)]
fn matmul_body(a: &[f64], b: &[f64], c: &mut [f64], m: usize, q: usize, p: usize) {
    // the row widths of the filter's products (N_MEAS = 7; the state sizes of the layouts: 12, 13,
    // 14, 19) with the row in registers through the l loop: the same fused multiply-adds per entry
    match p {
        7 => return matmul_rows::<7>(a, b, c, m, q),
        12 => return matmul_rows::<12>(a, b, c, m, q),
        13 => return matmul_rows::<13>(a, b, c, m, q),
        14 => return matmul_rows::<14>(a, b, c, m, q),
        19 => return matmul_rows::<19>(a, b, c, m, q),
        _ => {}
    }
    // the p entries of a row are independent chains, run side by side in vector registers
    for i in 0..m {
        let row = &mut c[i * p..(i + 1) * p];
        row.fill(0.0);
        for l in 0..q {
            let ail = a[i * q + l];
            if ail == 0.0 {
                continue;
            }
            for (cj, &blj) in row.iter_mut().zip(&b[l * p..(l + 1) * p]) {
                *cj = ail.mul_add(blj, *cj);
            }
        }
    }
}

/// [`matmul_body`] for rows of a width `P` known when compiled: each entry of C's row i is the
/// chain of fused multiply-adds a_il b_lj over l = 0..q from 0.0, a term with a_il = 0 skipped, as
/// in the general loop; the row stays in registers and its loop is unrolled.
#[inline(always)]
fn matmul_rows<const P: usize>(a: &[f64], b: &[f64], c: &mut [f64], m: usize, q: usize) {
    for i in 0..m {
        let mut row = [0.0f64; P];
        for l in 0..q {
            let ail = a[i * q + l];
            if ail == 0.0 {
                continue;
            }
            let bl = &b[l * P..(l + 1) * P];
            for (cj, &blj) in row.iter_mut().zip(bl) {
                *cj = ail.mul_add(blj, *cj);
            }
        }
        c[i * P..(i + 1) * P].copy_from_slice(&row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixed-width products (matmul_rows) give every entry of the plain loop's, to the bit:
    /// the fused multiply-adds a_il b_lj in l order from 0.0, zeros of A skipped.
    #[test]
    fn fixed_width_products_are_the_plain_loop() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut draw = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            if x % 3 == 0 {
                0.0
            } else {
                v * 10f64.powi((x % 9) as i32 - 4)
            }
        };
        for p in [7usize, 12, 13, 14, 19, 5] {
            for (m, q) in [(7usize, 14usize), (14, 14), (14, 7), (4, 19)] {
                let a: Vec<f64> = (0..m * q).map(|_| draw()).collect();
                let b: Vec<f64> = (0..q * p).map(|_| draw()).collect();
                let mut c = vec![f64::NAN; m * p];
                matmul(&a, &b, &mut c, m, q, p);
                for i in 0..m {
                    for j in 0..p {
                        let mut want = 0.0f64;
                        for l in 0..q {
                            if a[i * q + l] != 0.0 {
                                want = a[i * q + l].mul_add(b[l * p + j], want);
                            }
                        }
                        assert_eq!(c[i * p + j].to_bits(), want.to_bits(), "p {p} m {m} q {q} ({i}, {j})");
                    }
                }
            }
        }
    }

    #[test]
    fn min_max_propagate_nan() {
        assert!(nan_min(f64::NAN, 1.0).is_nan() && nan_min(1.0, f64::NAN).is_nan());
        assert!(nan_max(f64::NAN, 1.0).is_nan() && clip(f64::NAN, -1.0, 1.0).is_nan());
        assert_eq!(clip(3.0, -1.5, 1.5), 1.5);
        assert_eq!(clip(-3.0, -1.5, 1.5), -1.5);
    }

    #[test]
    fn matmul_is_fused_in_order() {
        // [[1, 2], [3, 4]] @ [[5, 6], [7, 8]] and its transposed form
        let a = [1.0, 2.0, 3.0, 4.0];
        let b = [5.0, 6.0, 7.0, 8.0];
        let mut c = [0.0; 4];
        matmul(&a, &b, &mut c, 2, 2, 2);
        assert_eq!(c, [19.0, 22.0, 43.0, 50.0]);
        matmul_bt(&a, &b, &mut c, 2, 2, 2, &mut [0.0; 4]);
        assert_eq!(c, [17.0, 23.0, 39.0, 53.0]);
        let mut y = [0.0; 2];
        matvec(&a, &[1.0, -1.0], &mut y, 2, 2);
        assert_eq!(y, [-1.0, -1.0]);
    }
}
