//! One vehicle's Kalman filter steps (soilocp's former numpy kernel, filterpy's procedural form):
//! the ZOH prediction (eq. 34), the gated / Huber update in Joseph form (eq. 35 in its standard
//! form, docs/method.md §7, §12) and the conditioning of P with the state's physical box (§12).
//! Matrices are row-major slices; `n` is the state size, [`N_MEAS`] the measurement rows.

use super::layout::N_MEAS;
use super::numeric::{clip, matmul, matmul_bt, matvec, nan_max, nan_min};

/// Scratch matrices of one step, allocated once per bank.
pub struct Workspace {
    n: usize,
    f: Vec<f64>,
    aq: Vec<f64>,
    qd: Vec<f64>,
    t1: Vec<f64>,
    t2: Vec<f64>,
    hm: Vec<f64>,
    pht: Vec<f64>,
    s: Vec<f64>,
    s_inv: Vec<f64>,
    k: Vec<f64>,
    kr: Vec<f64>,
    v: Vec<f64>,
    bt: Vec<f64>,
}

impl Workspace {
    pub fn new(n: usize) -> Workspace {
        let nn = n * n;
        let nm = n * N_MEAS;
        Workspace {
            n,
            f: vec![0.0; nn],
            aq: vec![0.0; nn],
            qd: vec![0.0; nn],
            t1: vec![0.0; nn],
            t2: vec![0.0; nn],
            hm: vec![0.0; nm],
            pht: vec![0.0; nm],
            s: vec![0.0; N_MEAS * N_MEAS],
            s_inv: vec![0.0; N_MEAS * N_MEAS],
            k: vec![0.0; nm],
            kr: vec![0.0; nm],
            v: vec![0.0; n],
            bt: vec![0.0; nn.max(nm)],
        }
    }
}

/// ZOH prediction over dt > 0 (eq. 34, exact because A is nilpotent, A A = 0):
/// F = I + A dt, G = b dt + A b dt^2/2, Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3,
/// x <- F x + G, P <- F P F^T + Q_d.  `q`: the diagonal of the (diagonal) Q; `dt_cubed`: dt^3, made
/// once per sample by the caller.
#[allow(clippy::too_many_arguments)]
pub fn predict(
    x: &mut [f64],
    p: &mut [f64],
    a: &[f64],
    b: &[f64],
    q: &[f64],
    dt: f64,
    dt_cubed: f64,
    ws: &mut Workspace,
) {
    let n = ws.n;
    let h2 = dt * dt / 2.0;
    let h3 = dt_cubed / 3.0;
    for i in 0..n {
        for j in 0..n {
            let e = a[i * n + j] * dt;
            ws.f[i * n + j] = if i == j { e + 1.0 } else { e };
            ws.aq[i * n + j] = a[i * n + j] * q[j];
        }
    }
    // A Q A^T before Q_d's sum, in Q_d's order: (AQ + AQ^T) h2 + Q dt + (AQ A^T) h3
    matmul_bt(&ws.aq, a, &mut ws.t1, n, n, n, &mut ws.bt);
    for i in 0..n {
        for j in 0..n {
            let mut v = (ws.aq[i * n + j] + ws.aq[j * n + i]) * h2;
            v += if i == j { q[i] * dt } else { 0.0 * dt };
            ws.qd[i * n + j] = v + ws.t1[i * n + j] * h3;
        }
    }
    matmul(&ws.f, p, &mut ws.t1, n, n, n);
    matmul_bt(&ws.t1, &ws.f, &mut ws.t2, n, n, n, &mut ws.bt);
    for (pij, (fpf, qd)) in p.iter_mut().zip(ws.t2.iter().zip(ws.qd.iter())) {
        *pij = fpf + qd;
    }
    matvec(a, b, &mut ws.v, n, n);
    let ab: Vec<f64> = ws.v.clone();
    matvec(&ws.f, x, &mut ws.v, n, n);
    for i in 0..n {
        x[i] = ws.v[i] + (b[i] * dt + ab[i] * h2);
    }
}

/// The gate's result for one vehicle's rows.
pub struct Gated {
    /// rows taken at full weight (available and inside the gate, or past the patience)
    pub keep: [bool; N_MEAS],
}

/// The measurement variance of a row for the update (docs/method.md §12): R where the row passes
/// its gate; beyond it, the variance that puts its innovation exactly on the gate,
/// max(R, nu^2 / gate^2 - H P H^T) (Huber's weighting: a spike moves the state by at most a gate's
/// worth, and a model that is off is still followed).
#[inline]
pub fn outlier_variance(innov: f64, hph: f64, r: f64, gate_sigma: f64, keep: bool) -> f64 {
    if keep {
        r
    } else {
        nan_max(r, innov * innov / (gate_sigma * gate_sigma) - hph)
    }
}

/// Kalman update (eq. 35, standard form; Joseph form) of x, P by z with diagonal R = `r` and
/// H (7 x n).  Each row is gated on its normalised innovation (nu^2 / S_ii <= gate_sigma^2); a row
/// beyond it is down-weighted ([`outlier_variance`]) unless it was beyond it `patience` times in
/// a row (`counts`, updated here).  A row not `available` (a held reading) takes no part: its H
/// row and innovation are zeroed, its gain column is then exactly zero.
/// K = P H^T S^-1, S = H P H^T + R;  x+ = x + K nu;  P+ = (I - K H) P (I - K H)^T + K R K^T.
#[allow(clippy::too_many_arguments)]
pub fn gated_update(
    x: &mut [f64],
    p: &mut [f64],
    z: &[f64; N_MEAS],
    r: &[f64; N_MEAS],
    h: &[f64],
    gate_sigma: f64,
    counts: &mut [i64],
    patience: i64,
    available: &[bool; N_MEAS],
    ws: &mut Workspace,
) -> Gated {
    let n = ws.n;
    let m = N_MEAS;
    let mut hx = [0.0; N_MEAS];
    matvec(h, x, &mut hx, m, n);
    let mut innov = [0.0; N_MEAS];
    for i in 0..m {
        innov[i] = z[i] - hx[i];
    }
    // H P H^T's diagonal: each row of H P times the row of H, summed
    matmul(h, p, &mut ws.pht, m, n, n);
    let mut hph = [0.0; N_MEAS];
    for i in 0..m {
        for j in 0..n {
            ws.v[j] = ws.pht[i * n + j] * h[i * n + j];
        }
        hph[i] = ws.v[..n].iter().sum();
    }
    let gate2 = gate_sigma * gate_sigma;
    let mut keep = [false; N_MEAS];
    for i in 0..m {
        let nis = innov[i] * innov[i] / (hph[i] + r[i]);
        let k = nis <= gate2 || counts[i] >= patience;
        if available[i] {
            counts[i] = if k { 0 } else { counts[i] + 1 };
        }
        keep[i] = k && available[i];
    }
    if !available.iter().any(|&a| a) {
        return Gated { keep };
    }
    let mut y = [0.0; N_MEAS];
    let mut rm = [0.0; N_MEAS];
    for i in 0..m {
        let av = if available[i] { 1.0 } else { 0.0 };
        for j in 0..n {
            ws.hm[i * n + j] = h[i * n + j] * av;
        }
        y[i] = innov[i] * av;
        rm[i] = if available[i] {
            outlier_variance(innov[i], hph[i], r[i], gate_sigma, keep[i])
        } else {
            1.0
        };
    }
    matmul_bt(p, &ws.hm, &mut ws.pht, n, n, m, &mut ws.bt);
    matmul(&ws.hm, &ws.pht, &mut ws.s, m, n, m);
    for i in 0..m {
        ws.s[i * m + i] += rm[i];
    }
    invert(&ws.s, &mut ws.s_inv, m);
    matmul(&ws.pht, &ws.s_inv, &mut ws.k, n, m, m);
    matvec(&ws.k, &y, &mut ws.v, n, m);
    for i in 0..n {
        x[i] += ws.v[i];
    }
    // I - K H, then (I - K H) P (I - K H)^T + (K R) K^T
    matmul(&ws.k, &ws.hm, &mut ws.t1, n, m, n);
    for i in 0..n {
        for j in 0..n {
            let e = if i == j { 1.0 } else { 0.0 };
            ws.f[i * n + j] = e - ws.t1[i * n + j];
        }
    }
    matmul(&ws.f, p, &mut ws.t1, n, n, n);
    matmul_bt(&ws.t1, &ws.f, &mut ws.t2, n, n, n, &mut ws.bt);
    for i in 0..n {
        for j in 0..m {
            ws.kr[i * m + j] = ws.k[i * m + j] * rm[j];
        }
    }
    matmul_bt(&ws.kr, &ws.k, &mut ws.t1, n, m, n, &mut ws.bt);
    for (pij, (a, b)) in p.iter_mut().zip(ws.t2.iter().zip(ws.t1.iter())) {
        *pij = a + b;
    }
    Gated { keep }
}

/// The inverse of the m x m matrix `s` (numpy's inv: LU with partial pivoting, then the columns
/// of the identity solved).  S = H P H^T + R is positive definite for a finite P; a singular or
/// non-finite S gives non-finite entries, which the bank's divergence guard resets.
pub fn invert(s: &[f64], out: &mut [f64], m: usize) {
    let mut lu = [0.0; N_MEAS * N_MEAS];
    lu[..m * m].copy_from_slice(&s[..m * m]);
    let mut perm = [0usize; N_MEAS];
    for (i, p) in perm.iter_mut().enumerate().take(m) {
        *p = i;
    }
    for c in 0..m {
        // the first row of largest magnitude (LAPACK's idamax)
        let mut piv = c;
        for r in c + 1..m {
            if lu[r * m + c].abs() > lu[piv * m + c].abs() {
                piv = r;
            }
        }
        if piv != c {
            for j in 0..m {
                lu.swap(c * m + j, piv * m + j);
            }
            perm.swap(c, piv);
        }
        let d = lu[c * m + c];
        for r in c + 1..m {
            let f = lu[r * m + c] / d;
            lu[r * m + c] = f;
            for j in c + 1..m {
                lu[r * m + j] -= f * lu[c * m + j];
            }
        }
    }
    for col in 0..m {
        let mut y = [0.0; N_MEAS];
        for i in 0..m {
            let mut v = if perm[i] == col { 1.0 } else { 0.0 };
            for j in 0..i {
                v -= lu[i * m + j] * y[j];
            }
            y[i] = v;
        }
        for i in (0..m).rev() {
            let mut v = y[i];
            for j in i + 1..m {
                v -= lu[i * m + j] * y[j];
            }
            y[i] = v / lu[i * m + i];
        }
        for i in 0..m {
            out[i * m + col] = y[i];
        }
    }
}

/// Keep P symmetric and positive semi-definite, and x in its physical box (docs/method.md §12):
/// P <- (P + P^T) / 2, variances clamped to [floor, ceiling], correlations to +-0.9999; x clipped
/// to [lower, upper] (|mu| <= 1.5, the resistance within its physical range).
pub fn condition(x: &mut [f64], p: &mut [f64], lower: &[f64], upper: &[f64], floor: f64, ceiling: f64, n: usize) {
    for i in 0..n {
        for j in i..n {
            let s = (p[i * n + j] + p[j * n + i]) / 2.0;
            p[i * n + j] = s;
            p[j * n + i] = s;
        }
    }
    let mut sd = [0.0; 19];
    let mut var = [0.0; 19];
    for i in 0..n {
        var[i] = nan_min(nan_max(p[i * n + i], floor), ceiling);
        sd[i] = var[i].sqrt();
    }
    for i in 0..n {
        for j in 0..n {
            let lim = (0.9999 * sd[i]) * sd[j];
            p[i * n + j] = nan_max(nan_min(p[i * n + j], lim), -lim);
        }
        p[i * n + i] = var[i];
    }
    for i in 0..n {
        x[i] = clip(x[i], lower[i], upper[i]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_of_a_permuted_matrix() {
        // [[0, 2], [1, 1]]^-1 = [[-0.5, 1], [0.5, 0]]: needs the row swap
        let mut out = [0.0; 4];
        invert(&[0.0, 2.0, 1.0, 1.0], &mut out, 2);
        assert_eq!(out, [-0.5, 1.0, 0.5, 0.0]);
    }

    #[test]
    fn scalar_filter_matches_the_textbook() {
        // one state (n = 1) is not a layout; the update on a 1-state system through the 7-row
        // interface with one available row: P = 4, R = 1 -> K = 0.8, x = 0 + 0.8 * 10 = 8, P = 0.8
        let n = 1;
        let mut ws = Workspace::new(n);
        let mut x = [0.0];
        let mut p = [4.0];
        let mut h = [0.0; N_MEAS];
        h[0] = 1.0;
        let mut z = [0.0; N_MEAS];
        z[0] = 10.0;
        let r = [1.0; N_MEAS];
        let mut avail = [false; N_MEAS];
        avail[0] = true;
        let mut counts = [0i64; N_MEAS];
        // gate of 100 sigma: 10^2 / 5 = 20 <= 10^4, kept
        let g = gated_update(&mut x, &mut p, &z, &r, &h, 100.0, &mut counts, 10, &avail, &mut ws);
        assert!(g.keep[0] && !g.keep[1]);
        assert!((x[0] - 8.0).abs() < 1e-12 && (p[0] - 0.8).abs() < 1e-12, "{x:?} {p:?}");
        // beyond a 1-sigma gate (nu^2 / S = 100 / 1.8 > 1): Huber's R = nu^2 - P = 99.2 - 0.8
        let mut x2 = [8.0 + 0.0];
        let mut p2 = [0.8];
        z[0] = 18.0;
        let g = gated_update(&mut x2, &mut p2, &z, &r, &h, 1.0, &mut counts, 10, &avail, &mut ws);
        assert!(!g.keep[0] && counts[0] == 1);
        // R' = 100 - 0.8 = 99.2: x moves by 0.8 / 100 * 10 = 0.08, exactly on the gate
        assert!((x2[0] - 8.08).abs() < 1e-12, "{x2:?}");
    }

    #[test]
    fn condition_bounds_correlations_and_state() {
        let n = 2;
        let mut x = [3.0, -0.5];
        let mut p = [1.0, 2.0, 0.0, 4.0]; // asymmetric, correlation 1 / 2 after symmetrising: kept
        condition(&mut x, &mut p, &[-1.5, -1.0], &[1.5, 1.0], 1e-10, 1e4, n);
        assert_eq!(x, [1.5, -0.5]);
        assert_eq!(p, [1.0, 1.0, 1.0, 4.0]);
        let mut p = [1.0, 5.0, 5.0, 4.0]; // correlation 2.5: clamped to 0.9999 * 1 * 2
        condition(&mut x, &mut p, &[-1.5, -1.0], &[1.5, 1.0], 1e-10, 1e4, n);
        assert_eq!(p[1], 0.9999 * 2.0);
        let mut p = [f64::NAN, 0.0, 0.0, 1.0];
        condition(&mut x, &mut p, &[-1.5, -1.0], &[1.5, 1.0], 1e-10, 1e4, n);
        assert!(p[0].is_nan(), "a NaN variance stays NaN for the divergence guard");
    }
}
