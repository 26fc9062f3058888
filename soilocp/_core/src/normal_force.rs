//! Normal forces on the four wheels from the measured specific force, eqs. 16-25, with the
//! corrections of docs/method.md §2-3: the 4x4 A of eq. 23 has rank 3 (A (1,-1,1,-1)^T = 0, the
//! warp mode), so eq. 25's A^{-1} does not exist and the solution is the zero-warp, minimum-norm
//! F = A^+ B; and only the specific force f = V_dot + g enters B (eq. 24), not acceleration and
//! gravity (eq. 20) separately.  Wheels 1 LR, 2 LF, 3 RF, 4 RR.
//!
//! B is linear in f (B = f C, C of eq. 24 being 3 x 4), so F = f M with M = C (A^+)^T, one matrix
//! per vehicle, prepared here once per vehicle in closed form ([`zero_warp_map`]: A is a sum of the
//! Klein-four permutation matrices, so its eigenvectors are the Hadamard vectors and A^+ needs no
//! SVD), and the per-sample product.  Every caller (the services, the batched path, the offline
//! estimate, the simulator) takes M from here.
//!
//! Eq. 20 (gravity from roll and pitch) is here too, once: the specific force at rest, for the
//! static normal forces, the simulator and the gravity reaction of the torque scale's balance.

/// m/s^2, the standard gravity (`soilocp.model.normal_force.STANDARD_GRAVITY`).
pub const STANDARD_GRAVITY: f64 = 9.80665;

/// Eq. 20: the gravity reaction in the body frame, (-g s(theta), g s(alpha) c(theta),
/// g c(alpha) c(theta)), from roll alpha and pitch theta (rad; REP-103: roll > 0 left side up,
/// pitch > 0 nose down).  What an accelerometer at rest reads (docs/method.md §3: the measured
/// specific force replaces eq. 20 in eq. 24; this is its zero-acceleration special case), so at
/// rest on a climb (pitch < 0) f_x > 0.  Products in the order of the print (libm's sin and cos,
/// which numpy's agree with on this platform).
#[inline]
pub fn gravity_from_attitude(roll: f64, pitch: f64, g: f64) -> [f64; 3] {
    let (sp, cp) = (pitch.sin(), pitch.cos());
    [-g * sp, g * roll.sin() * cp, g * roll.cos() * cp]
}

/// M = C (A^+)^T (3 x 4) of eqs. 21-25 with the zero-warp pseudo-inverse (docs/method.md §2), for
/// the geometry a, b (CoM to rear / front axle), c, d (CoM to left / right wheels), h (CoM height),
/// all m, and the mass (kg): F = f M.
///
/// A of eq. 23, [[0, L, L+W, W], [L, 0, W, L+W], [L+W, W, 0, L], [W, L+W, L, 0]] with L = a + b and
/// W = c + d, is L P1 + (L + W) P2 + W P3 for the three Klein-four permutation matrices, so its
/// eigenvectors are the Hadamard vectors: h0 = (1, 1, 1, 1) with eigenvalue 2 (L + W),
/// (1, -1, 1, -1) with 0 (the warp mode, eq. 25's A^{-1} does not exist), h2 = (1, 1, -1, -1)
/// with -2 W and h3 = (1, -1, -1, 1) with -2 L.  Hence
/// A^+ = h0 h0^T / (8 (L + W)) - h2 h2^T / (8 W) - h3 h3^T / (8 L), and with C's rows (eq. 24,
/// the specific force in place of V_dot + g, §3) m (-h, h, h, -h), m (h, h, -h, -h) and
/// m (a + c, b + c, b + d, a + d), the rows of M = C A^+ are
///
/// * f_x: m h / (2 L) h3 (load moves to the rear axle under forward acceleration),
/// * f_y: -m h / (2 W) h2 (to the right side under a leftward one),
/// * f_z: m / 4 h0 - m (c - d) / (4 W) h2 - m (a - b) / (4 L) h3 (the static split).
///
/// Equal to LAPACK's SVD pseudo-inverse (numpy.linalg.pinv, which computed M before) within
/// LAPACK's own error, not to the bit: a few ulp for the rover (the tests below), growing with
/// (L + W) / min(L, W) (tests/test_normal_force.py); this closed form is exact to its rounding.  The
/// two-step equivalence of the change is in docs/performance.md.  `Err` names a length or mass
/// that is not finite and > 0.
pub fn zero_warp_map(a: f64, b: f64, c: f64, d: f64, h: f64, mass: f64) -> Result<[[f64; 4]; 3], String> {
    for (name, v) in [("a", a), ("b", b), ("c", c), ("d", d), ("h", h)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!(
                "vehicle geometry {name} must be a finite length > 0, got {v:?}"
            ));
        }
    }
    if !(mass.is_finite() && mass > 0.0) {
        return Err(format!("vehicle mass must be finite and > 0, got {mass:?}"));
    }
    let (el, w) = (a + b, c + d);
    let mh = mass * h;
    let x = mh / (2.0 * el);
    let y = mh / (2.0 * w);
    let q = mass / 4.0;
    let p = mass * (c - d) / (4.0 * w);
    let r = mass * (a - b) / (4.0 * el);
    Ok([
        [x, -x, -x, x],
        [-y, -y, y, y],
        [q - p - r, q - p + r, q + p + r, q + p - r],
    ])
}

/// The zero-warp solution of eqs. 21-25 for one vehicle: F = f M (M = C (A^+)^T, 3 x 4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalForceMap {
    pub map: [[f64; 4]; 3],
}

impl NormalForceMap {
    /// The map of one vehicle's geometry and mass ([`zero_warp_map`]).
    pub fn for_vehicle(a: f64, b: f64, c: f64, d: f64, h: f64, mass: f64) -> Result<Self, String> {
        Self::new(zero_warp_map(a, b, c, d, h, mass)?)
    }

    /// `Err` if an entry of M is not finite.
    pub fn new(map: [[f64; 4]; 3]) -> Result<Self, String> {
        if map.iter().flatten().any(|v| !v.is_finite()) {
            return Err(format!("the normal-force map must be finite, got {map:?}"));
        }
        Ok(NormalForceMap { map })
    }

    /// F_z per wheel (N) for one specific force (m/s^2): sum F = m f_z and F1 + F3 = F2 + F4; a
    /// negative wheel (lift-off) is returned, not clipped.  Summed in the order f_x, f_y, f_z.
    #[inline]
    pub fn solve(&self, f: [f64; 3]) -> [f64; 4] {
        let m = &self.map;
        std::array::from_fn(|j| f[0] * m[0][j] + f[1] * m[1][j] + f[2] * m[2][j])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// M of the default rover (soilocp/data/rover.json: m 60 kg, a 0.27, b 0.23, c = d 0.25,
    /// h 0.3 m), as `soilocp.model.normal_force` prepares it (numpy's pinv), to the last digit.
    const ROVER: [[f64; 4]; 3] = [
        [
            18.000000000000007,
            -18.00000000000001,
            -17.999999999999986,
            17.999999999999993,
        ],
        [
            -18.000000000000007,
            -18.000000000000004,
            17.999999999999996,
            18.000000000000007,
        ],
        [
            13.800000000000004,
            16.20000000000001,
            16.199999999999996,
            13.80000000000001,
        ],
    ];

    /// M of a non-symmetric geometry (a 0.3, b 0.2, c 0.22, d 0.28, h 0.4 m, m 75 kg) by numpy's
    /// pinv, to the last digit.
    const SKEWED: [[f64; 4]; 3] = [
        [
            30.000000000000014,
            -30.00000000000002,
            -29.999999999999975,
            29.999999999999993,
        ],
        [
            -30.00000000000001,
            -30.000000000000007,
            29.999999999999993,
            30.000000000000007,
        ],
        [
            17.25000000000001,
            24.750000000000014,
            20.24999999999999,
            12.750000000000014,
        ],
    ];

    /// One unit in the last place of |x|.
    fn ulp(x: f64) -> f64 {
        let x = x.abs();
        f64::from_bits(x.to_bits() + 1) - x
    }

    /// The closed form equals LAPACK's pseudo-inverse within 8 ulp of each row's largest entry
    /// (numpy's rows are off the exact values by up to 7), for the rover and a skewed geometry.
    #[test]
    fn closed_form_map_equals_lapack_pinv_within_a_few_ulp() {
        for ((a, b, c, d, h, m), want) in [
            ((0.27, 0.23, 0.25, 0.25, 0.3, 60.0), ROVER),
            ((0.3, 0.2, 0.22, 0.28, 0.4, 75.0), SKEWED),
        ] {
            let got = zero_warp_map(a, b, c, d, h, m).unwrap();
            for i in 0..3 {
                let big = want[i].iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
                for j in 0..4 {
                    assert!(
                        (got[i][j] - want[i][j]).abs() <= 8.0 * ulp(big),
                        "M[{i}][{j}]: closed form {}, pinv {}",
                        got[i][j],
                        want[i][j]
                    );
                }
            }
        }
        // the rover's closed form is the exact 18 / 13.8 / 16.2 (to the rounding of the decimals)
        let got = zero_warp_map(0.27, 0.23, 0.25, 0.25, 0.3, 60.0).unwrap();
        assert_eq!(got[0], [18.0, -18.0, -18.0, 18.0]);
        assert_eq!(got[1], [-18.0, -18.0, 18.0, 18.0]);
    }

    /// A (closed form) A^+ A = A: M solves eqs. 21-25 (A F = B for every f) and has no warp, for
    /// geometries well away from the rover's.
    #[test]
    fn closed_form_map_solves_the_statics() {
        for (a, b, c, d, h, m) in [
            (0.1, 0.9, 0.05, 0.7, 1.5, 500.0),
            (2.0, 0.01, 0.3, 0.3, 0.2, 3.0),
            (0.27, 0.23, 0.25, 0.25, 0.3, 60.0),
        ] {
            let nf = NormalForceMap::for_vehicle(a, b, c, d, h, m).unwrap();
            for f in [[0.0, 0.0, 9.80665], [2.0, -1.0, 9.0], [-3.0, 2.5, 11.0]] {
                let fz = nf.solve(f);
                let scale = m * 12.0;
                assert!((fz.iter().sum::<f64>() - m * f[2]).abs() < 1e-13 * scale);
                assert!((fz[0] + fz[2] - fz[1] - fz[3]).abs() < 1e-13 * scale);
                let pitch = -a * fz[0] + b * fz[1] + b * fz[2] - a * fz[3];
                let roll = c * fz[0] + c * fz[1] - d * fz[2] - d * fz[3];
                assert!((pitch + h * m * f[0]).abs() < 1e-12 * scale, "pitch moment {pitch}");
                assert!((roll + h * m * f[1]).abs() < 1e-12 * scale, "roll moment {roll}");
            }
        }
    }

    #[test]
    fn a_bad_geometry_is_refused_by_name() {
        let e = zero_warp_map(0.27, 0.23, 0.25, 0.25, f64::NAN, 60.0).unwrap_err();
        assert!(e.contains("geometry h") && e.contains("NaN"), "{e}");
        let e = zero_warp_map(0.27, 0.0, 0.25, 0.25, 0.3, 60.0).unwrap_err();
        assert!(e.contains("geometry b"), "{e}");
        let e = NormalForceMap::for_vehicle(0.27, 0.23, 0.25, 0.25, 0.3, -1.0).unwrap_err();
        assert!(e.contains("vehicle mass"), "{e}");
    }

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
        let nf = NormalForceMap::new(ROVER).unwrap();
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

    /// docs/method.md §3: a 10 degree climb at rest.
    #[test]
    fn climb_at_rest_of_method_md() {
        let th: f64 = -(10f64.to_radians());
        let g = 9.80665;
        let nf = NormalForceMap::new(ROVER).unwrap();
        close4(
            nf.solve([-g * th.sin(), 0.0, g * th.cos()]),
            [163.9281, 125.8018, 125.8018, 163.9281],
            5e-5,
        );
    }

    /// sum F = m f_z, the moments of eqs. 16-19 and no warp (docs/method.md §2).
    #[test]
    fn statics_hold_and_warp_is_zero() {
        let nf = NormalForceMap::new(ROVER).unwrap();
        let (m, h, a, b, c, d) = (60.0, 0.3, 0.27, 0.23, 0.25, 0.25);
        for f in [[0.0, 0.0, 9.80665], [2.0, -1.0, 9.0], [-3.0, 2.5, 11.0]] {
            let fz = nf.solve(f);
            assert!((fz.iter().sum::<f64>() - m * f[2]).abs() < 1e-10);
            assert!((fz[0] + fz[2] - fz[1] - fz[3]).abs() < 1e-10);
            // pitch: sum x_i F_i = -h m f_x with x = (-a, b, b, -a); roll: sum y_i F_i = -h m f_y
            let pitch = -a * fz[0] + b * fz[1] + b * fz[2] - a * fz[3];
            let roll = c * fz[0] + c * fz[1] - d * fz[2] - d * fz[3];
            assert!((pitch + h * m * f[0]).abs() < 1e-10, "pitch moment {pitch}");
            assert!((roll + h * m * f[1]).abs() < 1e-10, "roll moment {roll}");
        }
    }

    /// docs/method.md §3 (eq. 20): gravity_from_attitude(0, -10 deg) = (1.7029, 0, 9.6577) and
    /// gravity_from_attitude(+5 deg, 0) = (0, 0.8547, 9.7693) m/s^2.
    #[test]
    fn gravity_vectors_of_method_md() {
        let g = gravity_from_attitude(0.0, -(10f64.to_radians()), STANDARD_GRAVITY);
        for (got, want) in g.iter().zip([1.7029, 0.0, 9.6577]) {
            assert!((got - want).abs() < 5e-5, "{g:?}");
        }
        let g = gravity_from_attitude(5f64.to_radians(), 0.0, STANDARD_GRAVITY);
        for (got, want) in g.iter().zip([0.0, 0.8547, 9.7693]) {
            assert!((got - want).abs() < 5e-5, "{g:?}");
        }
        // its magnitude is g, and at rest on a slope the static forces carry m g cos(pitch)
        let f = gravity_from_attitude(0.3, -0.2, STANDARD_GRAVITY);
        assert!(((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() - STANDARD_GRAVITY).abs() < 1e-12);
        let fz = NormalForceMap::new(ROVER)
            .unwrap()
            .solve(gravity_from_attitude(0.0, -0.2, STANDARD_GRAVITY));
        assert!((fz.iter().sum::<f64>() - 60.0 * STANDARD_GRAVITY * 0.2f64.cos()).abs() < 1e-9);
    }

    #[test]
    fn a_non_finite_map_is_refused() {
        let mut bad = ROVER;
        bad[1][2] = f64::NAN;
        assert!(NormalForceMap::new(bad).unwrap_err().contains("finite"));
    }
}
