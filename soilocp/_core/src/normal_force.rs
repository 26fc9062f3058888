//! Normal forces on the four wheels from the measured specific force, eqs. 16-25, with the
//! corrections of docs/method.md §2-3: the 4x4 A of eq. 23 has rank 3 (A (1,-1,1,-1)^T = 0, the
//! warp mode), so eq. 25's A^{-1} does not exist and the solution is the zero-warp, minimum-norm
//! F = A^+ B; and only the specific force f = V_dot + g enters B (eq. 24), not acceleration and
//! gravity (eq. 20) separately.  Wheels 1 LR, 2 LF, 3 RF, 4 RR.

/// The vehicle's CoM geometry (m) and mass (kg).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub d: f64,
    pub h: f64,
    pub mass: f64,
}

/// A of eq. 23 (symmetric, rank 3).
pub fn system_matrix(g: &Geometry) -> [[f64; 4]; 4] {
    let (l, w) = (g.a + g.b, g.c + g.d);
    [
        [0.0, l, l + w, w],
        [l, 0.0, w, l + w],
        [l + w, w, 0.0, l],
        [w, l + w, l, 0.0],
    ]
}

/// B of eq. 24 as a linear map of the specific force: B = f @ coeff, coeff (3 x 4).
fn load_coefficients(g: &Geometry) -> [[f64; 4]; 3] {
    let (m, h) = (g.mass, g.h);
    [
        [-h * m, h * m, h * m, -h * m],
        [h * m, h * m, -h * m, -h * m],
        [(g.a + g.c) * m, (g.b + g.c) * m, (g.b + g.d) * m, (g.a + g.d) * m],
    ]
}

/// Inverse of a non-singular 4x4 matrix (Gauss-Jordan, partial pivoting).
fn invert4(m: [[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let mut a = m;
    let mut inv = [[0.0; 4]; 4];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for col in 0..4 {
        let pivot = (col..4).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, pivot);
        inv.swap(col, pivot);
        let p = a[col][col];
        for j in 0..4 {
            a[col][j] /= p;
            inv[col][j] /= p;
        }
        for r in 0..4 {
            if r != col {
                let f = a[r][col];
                for j in 0..4 {
                    a[r][j] -= f * a[col][j];
                    inv[r][j] -= f * inv[col][j];
                }
            }
        }
    }
    Some(inv)
}

/// The Moore-Penrose pseudo-inverse of eq. 23's A.  A is symmetric with null space spanned by
/// u = (1,-1,1,-1)/2, so A + u u^T is invertible and A^+ = (A + u u^T)^{-1} - u u^T.
pub fn pseudo_inverse(g: &Geometry) -> Option<[[f64; 4]; 4]> {
    const U: [f64; 4] = [0.5, -0.5, 0.5, -0.5];
    let mut m = system_matrix(g);
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] += U[i] * U[j];
        }
    }
    let mut p = invert4(m)?;
    for i in 0..4 {
        for j in 0..4 {
            p[i][j] -= U[i] * U[j];
        }
    }
    Some(p)
}

/// The zero-warp solution of eqs. 21-25 for one geometry, prepared once: F = f @ map with
/// map = coeff @ (A^+)^T (B = f @ coeff, eq. 24 with the measured specific force).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalForceMap {
    pub map: [[f64; 4]; 3],
}

impl NormalForceMap {
    /// `Err` names the first geometry length that is not finite and > 0.
    pub fn new(g: &Geometry) -> Result<Self, String> {
        for (name, v) in [
            ("a", g.a),
            ("b", g.b),
            ("c", g.c),
            ("d", g.d),
            ("h", g.h),
            ("mass", g.mass),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("vehicle geometry {name} must be a finite value > 0, got {v}"));
            }
        }
        let p = pseudo_inverse(g).ok_or("vehicle geometry gives a degenerate eq. 23 system")?;
        let coeff = load_coefficients(g);
        let mut map = [[0.0; 4]; 3];
        for i in 0..3 {
            for j in 0..4 {
                map[i][j] = (0..4).map(|l| coeff[i][l] * p[j][l]).sum();
            }
        }
        Ok(NormalForceMap { map })
    }

    /// F_z per wheel (N) for one specific force (m/s^2).  Satisfies A F = B, sum F = m f_z and
    /// F1 + F3 = F2 + F4; a negative wheel (lift-off) is returned, not clipped.
    #[inline]
    pub fn solve(&self, f: [f64; 3]) -> [f64; 4] {
        let m = &self.map;
        std::array::from_fn(|j| f[0] * m[0][j] + f[1] * m[1][j] + f[2] * m[2][j])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default rover of soilocp/data/rover.json (docs/method.md §2's "default vehicle").
    const ROVER: Geometry = Geometry {
        a: 0.27,
        b: 0.23,
        c: 0.25,
        d: 0.25,
        h: 0.3,
        mass: 60.0,
    };

    fn close4(got: [f64; 4], want: [f64; 4], tol: f64) {
        for j in 0..4 {
            assert!(
                (got[j] - want[j]).abs() <= tol,
                "wheel {}: got {got:?}, want {want:?}",
                j + 1
            );
        }
    }

    /// docs/method.md §2, the test-vector table (default vehicle).
    #[test]
    fn zero_warp_vectors_of_method_md() {
        let nf = NormalForceMap::new(&ROVER).unwrap();
        close4(
            nf.solve([0.0, 0.0, 9.80665]),
            [135.3318, 158.8677, 158.8677, 135.3318],
            5e-5,
        );
        close4(
            nf.solve([2.0, 0.0, 9.80665]),
            [171.3318, 122.8677, 122.8677, 171.3318],
            5e-5,
        );
        close4(
            nf.solve([0.0, 1.5, 9.80665]),
            [108.3318, 131.8677, 185.8677, 162.3318],
            5e-5,
        );
    }

    /// docs/method.md §3: a 10 degree climb at rest, f = (1.7029, 0, 9.6577).
    #[test]
    fn climb_at_rest_of_method_md() {
        let th: f64 = -(10f64.to_radians());
        let g = 9.80665;
        let nf = NormalForceMap::new(&ROVER).unwrap();
        close4(
            nf.solve([-g * th.sin(), 0.0, g * th.cos()]),
            [163.9281, 125.8018, 125.8018, 163.9281],
            5e-5,
        );
    }

    /// A F = B, sum F = m f_z and no warp, for the default and another geometry.
    #[test]
    fn statics_hold_and_warp_is_zero() {
        let other = Geometry {
            a: 0.3,
            b: 0.2,
            c: 0.22,
            d: 0.28,
            h: 0.4,
            mass: 60.0,
        };
        for geo in [ROVER, other] {
            let nf = NormalForceMap::new(&geo).unwrap();
            let a = system_matrix(&geo);
            let coeff = load_coefficients(&geo);
            for f in [[0.0, 0.0, 9.80665], [2.0, -1.0, 9.0], [-3.0, 2.5, 11.0]] {
                let fz = nf.solve(f);
                for i in 0..4 {
                    let af: f64 = (0..4).map(|j| a[i][j] * fz[j]).sum();
                    let b: f64 = (0..3).map(|l| f[l] * coeff[l][i]).sum();
                    assert!((af - b).abs() < 1e-10, "A F = B row {i}: {af} vs {b}");
                }
                assert!((fz.iter().sum::<f64>() - geo.mass * f[2]).abs() < 1e-10);
                assert!((fz[0] + fz[2] - fz[1] - fz[3]).abs() < 1e-10);
            }
        }
    }

    #[test]
    fn bad_geometry_is_named() {
        let err = NormalForceMap::new(&Geometry { h: 0.0, ..ROVER }).unwrap_err();
        assert!(err.contains("geometry h"), "{err}");
        let err = NormalForceMap::new(&Geometry { a: f64::NAN, ..ROVER }).unwrap_err();
        assert!(err.contains("geometry a"), "{err}");
    }
}
