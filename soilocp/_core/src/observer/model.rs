//! The observer's continuous model (eq. 33) at one sample: A (n x n), b (n), H (7 x n) from
//! eqs. 11-15 and 29 (soilocp.estimation.observer.model), and the resistance map of the `slip`
//! structure (docs/method.md §11).
//!
//! ```text
//!     omega_i_dot = (T_i - R_w (mu_i + mu_xR_i) Fz_i) / I_w      (eqs. 13-15)
//!     V_dot       = sum(mu_i Fz_i) / m + g sin(pitch) - bias       (REP-103 pitch)
//!     psi_ddot    = [d(Fx3 + Fx4) - c(Fx1 + Fx2) - M_zR] / I_z      (eqs. 11-12), Fx_i = mu_i Fz_i
//!     z = [f_x = sum(mu_i Fz_i)/m (eq. 29, docs/method.md §3), psi_dot, omega_1..4, V]
//! ```

use super::layout::{Layout, N_MEAS};
use super::numeric::{nan_max, nan_min};

/// The vehicle's constants the model uses (soilocp.model.vehicle.VehicleParams).
#[derive(Clone, Copy, Debug)]
pub struct Vehicle {
    pub mass: f64,
    pub wheel_radius: f64,
    pub wheel_inertia: f64,
    pub yaw_inertia: f64,
    /// CoM to front axle, rear axle, left track, right track (paper's a, b, c, d)
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub d: f64,
    /// lateral position of each wheel (m, left positive), for each wheel's ground speed
    pub wheel_y: [f64; 4],
}

/// soilocp/data/rover.json's geometry: the vehicle of the kernels' tests and examples.
pub const ROVER: Vehicle = Vehicle {
    mass: 60.0,
    wheel_radius: 0.15,
    wheel_inertia: 0.1,
    yaw_inertia: 6.0,
    a: 0.27,
    b: 0.23,
    c: 0.25,
    d: 0.25,
    wheel_y: [0.25, 0.25, -0.25, -0.25],
};

/// The travel direction of each wheel, smoothed over `travel_speed` (§11): clip(v / s, -1, 1).
#[inline]
pub fn smoothed_direction(v_wheel: f64, travel_speed: f64) -> f64 {
    nan_min(nan_max(v_wheel / travel_speed, -1.0), 1.0)
}

/// The resistance map M (4 x n_res, row-major) at state x (ObserverBank.maps): for `slip`,
/// mu_xR_i = d_i (r0 min(|S_i| / bridge, 1) + r1 |S_i|) with S_i of eq. 1 (floor 0.05 m/s) taken
/// from the state (the prior, so that the model stays linear) and d_i the travel direction;
/// `shared`: ones; `per_wheel`: the identity; `none`: empty.
pub fn resistance_map(l: &Layout, v: &Vehicle, x: &[f64], travel_speed: f64, bridge: f64, out: &mut [f64]) {
    match l.n_res {
        2 => {
            let (om, ground0, psi) = (l.omega(), x[l.v()], x[l.psi()]);
            for i in 0..4 {
                let rim = x[om + i] * v.wheel_radius;
                let ground = ground0 - psi * v.wheel_y[i];
                let slip = crate::slip::slip(rim, ground, 0.05);
                let d = smoothed_direction(ground, travel_speed);
                let a = slip.abs();
                out[2 * i] = if bridge > 0.0 { d * nan_min(a / bridge, 1.0) } else { d };
                out[2 * i + 1] = a * d;
            }
        }
        1 => out[..4].fill(1.0),
        4 => {
            out[..16].fill(0.0);
            for i in 0..4 {
                out[5 * i] = 1.0;
            }
        }
        _ => {}
    }
}

/// Writes the sample-dependent entries of A, b, H (their other entries stay as [`init`] left them):
/// eq. 33 at normal forces `fz` (N, clamped to the lift-off force by the caller), wheel torques
/// (N m), `g_sin_pitch` (m/s^2, the gravity term of the speed equation) and resistance map `m`.
#[allow(clippy::too_many_arguments)]
pub fn build(
    l: &Layout,
    v: &Vehicle,
    fz: &[f64; 4],
    torque: &[f64; 4],
    g_sin_pitch: f64,
    m: &[f64],
    a: &mut [f64],
    b: &mut [f64],
    h: &mut [f64],
) {
    let n = l.n();
    let (om, vi, psi, res, lat) = (l.omega(), l.v(), l.psi(), l.res(), l.lat());
    let yaw_arm = [-v.c, -v.c, v.d, v.d];
    let lat_arm = [v.a, v.b, v.b, v.a];
    let mut lat_sum = 0.0;
    for i in 0..4 {
        let gain = -v.wheel_radius * fz[i] / v.wheel_inertia;
        a[(om + i) * n + i] = gain;
        for j in 0..l.n_res {
            a[(om + i) * n + res + j] = gain * m[i * l.n_res + j];
        }
        b[om + i] = torque[i] / v.wheel_inertia;
        a[vi * n + i] = fz[i] / v.mass;
        a[psi * n + i] = yaw_arm[i] * fz[i] / v.yaw_inertia;
        let lat_i = lat_arm[i] * fz[i];
        if l.n_lat == 1 {
            lat_sum += lat_i; // the four wheels in order
        } else {
            a[psi * n + lat + i] = -lat_i / v.yaw_inertia;
        }
        h[i] = a[vi * n + i];
    }
    if l.n_lat == 1 {
        a[psi * n + lat] = -lat_sum / v.yaw_inertia;
    }
    b[vi] = g_sin_pitch;
}

/// A, b, H with the entries that depend on neither the sample nor the state (ModelBuffers): the
/// bias term of the speed equation (an accelerometer or pitch bias would otherwise integrate into
/// V and bias every slip) and the rows of H that pick a state.
pub fn init(l: &Layout, a: &mut [f64], b: &mut [f64], h: &mut [f64]) {
    let n = l.n();
    a.fill(0.0);
    b.fill(0.0);
    h.fill(0.0);
    a[l.v() * n + l.bias()] = -1.0;
    h[n + l.psi()] = 1.0;
    for i in 0..4 {
        h[(2 + i) * n + l.omega() + i] = 1.0;
    }
    h[(N_MEAS - 1) * n + l.v()] = 1.0;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rover() -> Vehicle {
        ROVER
    }

    #[test]
    fn a_is_nilpotent_and_the_accelerometer_row_is_the_speed_row() {
        let l = Layout::of("slip").unwrap();
        let n = l.n();
        let (mut a, mut b, mut h) = (vec![0.0; n * n], vec![0.0; n], vec![0.0; N_MEAS * n]);
        init(&l, &mut a, &mut b, &mut h);
        let mut x = vec![0.0; n];
        x[l.omega()..l.v()].copy_from_slice(&[10.0, 9.0, 9.0, 10.0]);
        x[l.v()] = 1.2;
        let mut m = [0.0; 8];
        resistance_map(&l, &rover(), &x, 0.05, 0.005, &mut m);
        // wheel 1: rim 1.5, ground 1.2 - 0 = 1.2: S = 0.3 / 1.5 = 0.2, forward travel
        assert!((m[0] - 1.0).abs() < 1e-15 && (m[1] - 0.2).abs() < 1e-15);
        build(&l, &rover(), &[150.0; 4], &[5.0; 4], 0.1, &m, &mut a, &mut b, &mut h);
        let mut aa = vec![0.0; n * n];
        crate::observer::numeric::matmul(&a, &a, &mut aa, n, n, n);
        assert!(aa.iter().all(|&v| v == 0.0), "A @ A = 0 (eq. 34's exact series)");
        assert_eq!(&h[..4], &a[l.v() * n..l.v() * n + 4]);
        assert_eq!(a[l.v() * n], 150.0 / 60.0);
        assert_eq!(b[l.omega()], 50.0);
        // wheel equation: -R Fz / I_w on mu_1 and on r0 through the map
        assert_eq!(a[l.omega() * n], -0.15 * 150.0 / 0.1);
    }
}
