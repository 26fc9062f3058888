//! Eq. 1, the longitudinal slip ratio, written once for every kernel of the core (the observer's
//! resistance map, the slip gate, the torque scale's window test).
//!
//! Corrections to the print (docs/method.md §6, §10, §17):
//! * the denominator is max(|V|, |R_w omega|, floor), so S is finite at standstill (the print
//!   divides 0 by 0);
//! * with speeds of either sign the same formula gives S > 0 for a driving wheel, S < 0 for a
//!   braking one, in the body frame; [`travel_slip`] turns it into the wheel's direction of travel
//!   (the print is for forward travel only).

use crate::observer::numeric::{nan_max, sign};

/// m/s: below this the ground under a wheel does not move of its own, and the wheel's direction of
/// travel is its rim's.
pub const V_STILL: f64 = 0.02;

/// Eq. 1 with the floor of §10: S = (R_w omega - V) / max(|V|, |R_w omega|, floor), from the rim
/// speed R_w omega and the ground speed under the wheel V (m/s).  NaN in, NaN out (numpy's rules).
#[inline]
pub fn slip(rim: f64, ground: f64, floor: f64) -> f64 {
    (rim - ground) / nan_max(scale(rim, ground), floor)
}

/// max(|R_w omega|, |V|): the measure eq. 1's deadband (§6) is judged on.
#[inline]
pub fn scale(rim: f64, ground: f64) -> f64 {
    nan_max(rim.abs(), ground.abs())
}

/// The wheel's direction of travel d, +-1 (§17): the sign of the ground speed under it, or of its rim
/// where the ground stands (|V| < [`V_STILL`]), +1 where both stand.
#[inline]
pub fn travel_direction(rim: f64, ground: f64) -> f64 {
    let d = if ground.abs() >= V_STILL {
        sign(ground)
    } else {
        sign(rim)
    };
    if d == 0.0 {
        1.0
    } else {
        d
    }
}

/// Eq. 1 in the wheel's direction of travel (§17): (d S, d).  A wheel travelling backwards is the
/// mirror image of one travelling forwards: its slip and its traction are both negated.
#[inline]
pub fn travel_slip(rim: f64, ground: f64, floor: f64) -> (f64, f64) {
    let d = travel_direction(rim, ground);
    (d * slip(rim, ground, floor), d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors_of_method_md() {
        // §6: driving 0.2, braking -0.2 at 1 m/s; §10: standstill finite; §17: reversing driving wheel
        assert!((slip(1.25, 1.0, 0.05) - 0.2).abs() < 1e-15);
        assert!((slip(0.8, 1.0, 0.05) + 0.2).abs() < 1e-15);
        assert_eq!(slip(0.0, 0.0, 0.05), 0.0);
        assert!((slip(0.01, 0.0, 0.05) - 0.2).abs() < 1e-15);
        let (s, d) = travel_slip(-0.45, -0.04, 0.05);
        assert_eq!(d, -1.0);
        assert!(
            (s - (0.41 / 0.45)).abs() < 1e-12,
            "reversing with spin drives at +0.91, got {s}"
        );
    }

    /// docs/method.md §17's table (floor 0.05 m/s): rim speed R_w omega, ground speed -> travel-frame
    /// slip (to its 4 digits), direction; and §11's reversing wheel at travel slip 0.2.
    #[test]
    fn travel_vectors_of_method_md() {
        #[rustfmt::skip]
        let cases = [
            (1.1, 1.0, 0.0909, 1.0),
            (0.9, 1.0, -0.1, 1.0),
            (-1.1, -1.0, 0.0909, -1.0), // driving backwards: the mirror image of driving forwards
            (-0.9, -1.0, -0.1, -1.0),   // braking backwards
            (-0.45, -0.04, 0.9111, -1.0), // a Husky reversing with spinning wheels
            (0.45, -0.04, -1.0889, -1.0), // the body drifts back while the wheel turns forwards: beyond eq. 1
            (-0.3, 0.0, 1.0, -1.0),     // spinning backwards at standstill
            (0.0, 0.0, 0.0, 1.0),
            (-0.15 * 1.25, -0.15, 0.2, -1.0),
        ];
        for (rim, ground, want_s, want_d) in cases {
            let (s, d) = travel_slip(rim, ground, 0.05);
            assert!(
                (s - want_s).abs() < 5e-5 && d == want_d,
                "({rim}, {ground}): ({s}, {d})"
            );
        }
    }

    #[test]
    fn direction_follows_the_rim_where_the_ground_stands() {
        assert_eq!(travel_direction(-0.3, 0.01), -1.0);
        assert_eq!(travel_direction(0.0, 0.0), 1.0);
        assert_eq!(travel_direction(0.3, -0.5), -1.0);
        assert!(slip(f64::NAN, 1.0, 0.05).is_nan());
    }
}
