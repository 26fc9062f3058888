//! What a wheel's readings mean to the observer (docs/method.md §14): the skid-steer torque split
//! (one motor, one speed and one torque per side, two chained wheels) and the lag of an encoder
//! speed that is a count difference over its interval.

/// omega_dot of one wheel from two consecutive encoder readings, (now - prev) / interval: each is
/// the mean speed over its interval, so this is the acceleration about one interval ago.  Held
/// readings (not `fresh`), a first reading and intervals beyond `max_gap` give 0 (no inertia
/// term, no lead).  From the readings and not from the filter's state, so that no filter output
/// feeds back into its own inputs.
#[inline]
pub fn wheel_acceleration(prev: f64, now: f64, interval: f64, fresh: bool, max_gap: f64) -> f64 {
    if fresh && interval > 0.0 && interval <= max_gap && prev.is_finite() {
        (now - prev) / interval
    } else {
        0.0
    }
}

/// Per-wheel torque of a skid-steer robot: each side's motor torque T_s (logged as half on each of
/// its wheels, 1+2 left, 3+4 right) shared by its two chained wheels so that both see the same
/// gross traction coefficient g in eq. 13.  Eq. 13 for the pair (one speed):
/// 2 I_w omega_dot = T_s - R_w g (Fz_a + Fz_b), and for wheel a alone
/// T_a = I_w omega_dot + R_w g Fz_a, hence
/// T_a = T_s Fz_a / (Fz_a + Fz_b) + I_w omega_dot (1 - 2 Fz_a / (Fz_a + Fz_b)),
/// with `inertia_torque` I_w omega_dot per wheel (the side's mean is used).  Without the inertia
/// term the split hands an unloaded wheel a share of the inertia torque in proportion to its small
/// load under a hard acceleration, and its g comes out ~0.1-0.3 low (docs/method.md §14).
pub fn split_side_torque(torque: &[f64; 4], fz: &[f64; 4], inertia_torque: &[f64; 4]) -> [f64; 4] {
    let mut out = [0.0; 4];
    for (a, b) in [(0, 1), (2, 3)] {
        let side = torque[a] + torque[b];
        let total = fz[a] + fz[b];
        let (share_a, share_b) = (fz[a] / total, fz[b] / total);
        let inert = 0.5 * (inertia_torque[a] + inertia_torque[b]);
        out[a] = side * share_a + inert * (1.0 - 2.0 * share_a);
        out[b] = side * share_b + inert * (1.0 - 2.0 * share_b);
    }
    out
}

/// What to add to an encoder wheel speed (vehicle `wheel_speed_reading` "interval_mean") to read
/// it as the speed at its stamp: a count difference over the interval tau since the previous
/// reading is the mean speed over that interval, omega(t - tau/2) + O(tau^2), so it lags by
/// omega_dot tau / 2.  At 0.01 s and the ~50 rad/s^2 of a hard skid-steer acceleration that is
/// 0.23 rad/s, a slip error of ~0.02 at 1.5 m/s (docs/method.md §14).
#[inline]
pub fn encoder_lead(interval: f64, omega_rate: f64) -> f64 {
    0.5 * interval * omega_rate
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_split_gives_both_wheels_of_a_side_one_gross_traction() {
        // docs/method.md §14: wheels a, b of one side, Fz 100 and 300 N, side torque 20 N m,
        // I_w omega_dot = 0.5 N m: g = (T - I_w omega_dot) / (R_w Fz) the same on both
        let (r, inert) = (0.15, 0.5);
        let t = split_side_torque(&[10.0, 10.0, 5.0, 5.0], &[100.0, 300.0, 200.0, 200.0], &[inert; 4]);
        let g = |i: usize, fz: f64| (t[i] - inert) / (r * fz);
        assert!((g(0, 100.0) - g(1, 300.0)).abs() < 1e-12);
        assert!((t[0] + t[1] - 20.0).abs() < 1e-12 && t[2] == 5.0 && t[3] == 5.0);
    }

    #[test]
    fn the_lead_reads_an_interval_mean_at_its_stamp() {
        // omega = 2 t^2: the mean over [t - tau, t] led by omega_dot(t - tau) tau / 2 ~ omega(t)
        let (t, tau) = (1.0, 0.01);
        let mean = |a: f64, b: f64| 2.0 * (b * b * b - a * a * a) / 3.0 / (b - a);
        let (now, prev) = (mean(t - tau, t), mean(t - 2.0 * tau, t - tau));
        let rate = wheel_acceleration(prev, now, tau, true, 0.5);
        assert!((now + encoder_lead(tau, rate) - 2.0 * t * t).abs() < 1e-3);
        assert_eq!(wheel_acceleration(prev, now, tau, false, 0.5), 0.0);
        assert_eq!(wheel_acceleration(f64::NAN, now, tau, true, 0.5), 0.0);
    }
}
