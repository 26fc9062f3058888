//! Eq. TC, the vehicle's longitudinal force balance with the torque channel's scale
//! (docs/method.md §15), and the motion resistance the model gives it (eq. 4 summed over the
//! wheels, §11, §17): one definition for the offline calibration (`soilocp calibrate-torque`,
//! `soilocp.analysis.torque_constant`, through `soilocp.model.force_balance`) and the online
//! torque-scale state ([`crate::torque_scale::bank`]).

use crate::constants::Constants;
use crate::traction;

/// The vehicle's numbers eq. TC reads: mass m (kg, the vehicle file's), one wheel's inertia I_w
/// (kg m^2) and the wheel radius R (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Body {
    pub mass: f64,
    pub wheel_inertia: f64,
    pub wheel_radius: f64,
}

impl Body {
    /// `Err` naming the field unless every number is finite and > 0.
    pub fn new(mass: f64, wheel_inertia: f64, wheel_radius: f64) -> Result<Body, String> {
        for (name, v) in [
            ("mass", mass),
            ("wheel_inertia", wheel_inertia),
            ("wheel_radius", wheel_radius),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("vehicle {name} = {v}: must be finite and > 0"));
            }
        }
        Ok(Body {
            mass,
            wheel_inertia,
            wheel_radius,
        })
    }
}

/// Eq. TC (docs/method.md §15): summed over the wheels, eq. 13 gives T_i / R = F_GT,i +
/// I_w omega_dot_i / R, and the body's balance (eq. 29, §3: only the specific force f_x enters,
/// so no grade term) gives m f_x = sum_i (F_GT,i - F_MR,i).  With the logged torque T_log = T / k:
///
///   m f_x + (I_w / R) sum_i omega_dot_i  =  k sum_i T_log,i / R  -  F_MR
///
/// Returns (x, y) = (sum T_log / R, m f_x + I_w sum omega_dot / R + F_MR,model) in N, so that
/// y = k x - b with b = F_MR - F_MR,model, the resistance the model does not give.
/// `resistance`: F_MR,model ([`modelled_resistance`]); None: b is the whole F_MR (the offline fit
/// knows no soil and fits it as a constant).  m is the vehicle file's: a payload it does not know
/// (true mass m') reads as k m / m'.  For samples or window means alike (the balance is linear).
#[inline]
pub fn longitudinal_balance(
    f_x: f64,
    omega_dot_sum: f64,
    torque_sum: f64,
    resistance: Option<f64>,
    body: &Body,
) -> (f64, f64) {
    longitudinal_balance_split(f_x, omega_dot_sum, torque_sum, resistance, 1.0, body)
}

/// Eq. TC with the scale split between the torque constant and the mass (docs/method.md §15, "The
/// wheels' inertia under an unknown payload").  With T = c T_log and a true mass m' = rho m, eq. TC
/// divided by rho reads
///
///   m f_x + (1 / rho) (I_w / R) sum_i omega_dot_i  =  k sum_i T_log,i / R  -  F_MR / rho,   k = c / rho:
///
/// the wheels spin with the motor's torque, not with the payload, so the inertia term carries
/// 1 / rho = k / c, not k.  `inertia_scale` is that 1 / rho (1: the scale is the torque constant's
/// alone, [`longitudinal_balance`]).  Returns (x, y) as [`longitudinal_balance`].
#[inline]
pub fn longitudinal_balance_split(
    f_x: f64,
    omega_dot_sum: f64,
    torque_sum: f64,
    resistance: Option<f64>,
    inertia_scale: f64,
    body: &Body,
) -> (f64, f64) {
    let r = body.wheel_radius;
    let x = torque_sum / r;
    let y = body.mass * f_x + inertia_scale * (body.wheel_inertia * omega_dot_sum / r);
    (x, resistance.map_or(y, |f| y + f))
}

/// F_MR,model = d sum_i F_z,i r(S_i, K) in N, the body-frame motion resistance eq. TC subtracts:
/// eq. 4 with |S| (docs/method.md §11: even in S, it opposes travel for both slip signs) at each
/// wheel's slip (eq. 1), the soil's K and the wheel's normal force; d = +-1 the direction of
/// travel (§17: in reverse the resistance pushes the body forwards).  Modelled, not a slow state:
/// eq. 4's C5 / K term makes it negative below K ~ 125, and at small slip it grows with |S|, i.e.
/// with the acceleration that identifies k (docs/robustness.md).  The four terms add in wheel
/// order.
#[inline]
pub fn modelled_resistance(slip: &[f64; 4], k: f64, normal_force: &[f64; 4], direction: f64, c: &Constants) -> f64 {
    let terms: [f64; 4] = std::array::from_fn(|j| normal_force[j] * traction::resistance(slip[j], k, c).value);
    direction * terms.iter().sum::<f64>()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A body of round numbers (eq. TC holds for any).
    const BODY: Body = Body {
        mass: 100.0,
        wheel_inertia: 0.1,
        wheel_radius: 0.25,
    };

    #[test]
    fn eq_tc_terms() {
        let (x, y) = longitudinal_balance(0.5, 4.0, 12.0, None, &BODY);
        assert_eq!(x, 12.0 / 0.25);
        assert_eq!(y, 100.0 * 0.5 + 0.1 * 4.0 / 0.25);
        let (_, y2) = longitudinal_balance(0.5, 4.0, 12.0, Some(25.0), &BODY);
        assert_eq!(y2, y + 25.0);
    }

    /// A robot that satisfies eq. TC with k = 0.8 and F_MR = 25 N: y = k x - F_MR.
    #[test]
    fn a_balanced_sample_gives_k_x_minus_resistance() {
        let (k, f_mr, a, od) = (0.8, 25.0, 0.7, 11.2);
        let true_torque = (BODY.mass * a + f_mr) * BODY.wheel_radius + BODY.wheel_inertia * od;
        let (x, y) = longitudinal_balance(a, od, true_torque / k, None, &BODY);
        assert!((k * x - f_mr - y).abs() < 1e-12);
    }

    /// Eq. 4 at each wheel (docs/method.md, "Values of the curves": r(0.1, 120) = 0.0348,
    /// r(0.3, 120) = 0.1079), even in S, and opposing travel in reverse.
    #[test]
    fn modelled_resistance_is_eq_4_summed() {
        let c = Constants::PAPER;
        let fz = [200.0, 250.0, 250.0, 200.0];
        let fwd = modelled_resistance(&[0.1, -0.1, 0.3, -0.3], 120.0, &fz, 1.0, &c);
        let want = 200.0 * 0.0348 + 250.0 * 0.0348 + 250.0 * 0.1079 + 200.0 * 0.1079;
        assert!((fwd - want).abs() < 450.0 * 5e-5 + 1e-9, "{fwd} vs {want}");
        assert_eq!(modelled_resistance(&[0.1, -0.1, 0.3, -0.3], 120.0, &fz, -1.0, &c), -fwd);
        // no slip: the bridge takes eq. 4 to zero (docs/method.md §8)
        assert_eq!(modelled_resistance(&[0.0; 4], 120.0, &fz, 1.0, &c), 0.0);
    }

    /// A payload (true mass rho m, the wheels' inertia unchanged, the torque constant right): eq. TC
    /// with the inertia term scaled by 1 / rho gives y = k x - b exactly with k = 1 / rho, b = F_MR /
    /// rho; read as the torque constant's (inertia_scale 1) it does not.
    #[test]
    fn the_split_balance_holds_under_a_payload() {
        let (rho, f_mr, a, od) = (1.25, 25.0, 0.7, 11.2);
        let torque = (rho * BODY.mass * a + f_mr) * BODY.wheel_radius + BODY.wheel_inertia * od;
        let (x, y) = longitudinal_balance_split(a, od, torque, None, 1.0 / rho, &BODY);
        assert!((x / rho - f_mr / rho - y).abs() < 1e-12);
        let (x, y) = longitudinal_balance(a, od, torque, None, &BODY);
        assert!((x / rho - f_mr / rho - y).abs() > 0.1);
        assert_eq!(
            longitudinal_balance_split(a, od, torque, Some(3.0), 1.0, &BODY),
            longitudinal_balance(a, od, torque, Some(3.0), &BODY)
        );
    }

    #[test]
    fn a_bad_body_is_refused() {
        assert!(Body::new(0.0, 0.1, 0.2).unwrap_err().contains("mass"));
        assert!(Body::new(10.0, f64::NAN, 0.2).unwrap_err().contains("wheel_inertia"));
    }
}
