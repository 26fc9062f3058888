//! Which wheels the longitudinal model describes now (docs/method.md §17): the unusable code of a
//! wheel, 0 where it may inform K.  The names and the reason text of the codes stay in Python
//! (soilocp.estimation.wheel_usability.REASONS, EXPLAIN, describe).

use crate::observer::numeric::nan_min;
use crate::settings::settings_struct;

/// The longitudinal model describes the wheel.
pub const USABLE: i8 = 0;
/// |S| > 1: the rim and the ground under it move in opposite directions (beyond eq. 1).
pub const SLIP_BEYOND_EQ1: i8 = 1;
/// The body moves, the wheel stands and no torque acts on it.
pub const STOPPED_UNPOWERED: i8 = 2;
/// The ground speed is near zero while a torque acts.
pub const STALL: i8 = 3;
/// The vehicle turns about a point within its track: the wheels slide sideways (eq. 12).
pub const SKID_TURN: i8 = 4;

/// The codes' names, code -> name ("" for usable): soilocp.estimation.wheel_usability.REASONS takes them.
pub const NAMES: [&str; 5] = ["", "slip_beyond_eq1", "stopped_unpowered", "stall", "skid_turn"];

settings_struct! {
    /// Thresholds of [`codes`] (soilocp.estimation.wheel_usability.UsabilityLimits is built from
    /// these declarations).  Whether the body moves is the pipeline's slip deadband, passed to
    /// [`codes`] by the caller.
    pub struct Limits("usability") {
        /// |V| below this with a torque is a stall.
        stall_speed: Float = 0.1, Internal, "m/s", [ge 0.0];
        /// |gross traction| at most this: no torque acts on the wheel.
        gross_idle: Float = 0.05, Internal, "", [ge 0.0];
        /// A rim slower than this stands.
        rim_stopped: Float = 0.02, Internal, "m/s", [ge 0.0];
        /// A side's rim turns when faster than this (a skid turn turns the sides oppositely).
        rim_turning: Float = 0.05, Internal, "m/s", [ge 0.0];
        /// A yaw rate above this about a point within the track is a skid turn.
        yaw_turning: Float = 0.1, Internal, "rad/s", [ge 0.0];
    }
}

/// The unusable code per wheel (docs/method.md §17, the first that applies of skid turn, |S| > 1,
/// stopped unpowered, stall) from the travel-frame slip (eq. 1 with §17's direction), the rim
/// speeds R_w omega and the ground speeds under the wheels (m/s), the body's ground speed (m/s),
/// yaw rate (rad/s), each wheel's gross traction (eq. 13's F_GT / W), the half-track (c + d) / 2
/// (m) and the slip deadband (m/s: above it the body moves).  Wheels 1 LR, 2 LF (left side), 3 RF, 4 RR (right side).
#[allow(clippy::too_many_arguments)]
pub fn codes(
    slip: &[f64; 4],
    rim: &[f64; 4],
    ground: &[f64; 4],
    body_speed: f64,
    yaw_rate: f64,
    gross: &[f64; 4],
    half_track: f64,
    lim: &Limits,
    deadband: f64,
) -> [i8; 4] {
    // each side's mean rim speed
    let (left, right) = ((rim[0] + rim[1]) / 2.0, (rim[2] + rim[3]) / 2.0);
    let (yaw, v) = (yaw_rate.abs(), body_speed.abs());
    let skid = (left * right < 0.0 && nan_min(left.abs(), right.abs()) > lim.rim_turning)
        || (yaw > lim.yaw_turning && v < yaw * half_track);
    let mut code = [USABLE; 4];
    for w in 0..4 {
        let powered = gross[w].abs() > lim.gross_idle;
        // the later conditions take precedence: a skid turn explains the rest (an in-place turn is
        // also V ~ 0 under torque)
        if v < lim.stall_speed && powered {
            code[w] = STALL;
        }
        if rim[w].abs() < lim.rim_stopped && !powered && ground[w].abs() > deadband {
            code[w] = STOPPED_UNPOWERED;
        }
        if slip[w].abs() > 1.0 {
            code[w] = SLIP_BEYOND_EQ1;
        }
        if skid {
            code[w] = SKID_TURN;
        }
    }
    code
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_the_codes() {
        let codes = [
            (USABLE, ""),
            (SLIP_BEYOND_EQ1, "slip_beyond_eq1"),
            (STOPPED_UNPOWERED, "stopped_unpowered"),
            (STALL, "stall"),
            (SKID_TURN, "skid_turn"),
        ];
        assert_eq!(codes.len(), NAMES.len());
        for (c, name) in codes {
            assert_eq!(NAMES[c as usize], name);
        }
    }

    /// docs/method.md §17's vectors (half-track 0.3 m) and a Husky's skid turns (0.25 m): in place,
    /// the sides' rims at +-0.19 m/s and yaw -0.21 rad/s, and creeping at 0.12 m/s with yaw -0.6
    /// rad/s; an arc at speed (the robustness drive's S-turns, 0.3 rad/s at 1 m/s) is no skid turn.
    #[test]
    fn vectors() {
        // the pipeline's slip deadband (soilocp.model.constants.DEFAULT_DEADBAND)
        let (lim, deadband) = (Limits::default(), 0.15);
        let (spin, husky) = ([0.9, 0.9, -0.9, -0.9], [0.19, 0.19, -0.19, -0.19]);
        // slip, rim speed, ground speed under the wheels, body speed, yaw rate, gross traction, half-track: codes
        #[rustfmt::skip]
        let cases = [
            ([1.2, 0.1, 0.1, 0.1], [0.5; 4], [0.5; 4], 0.5, 0.0, [0.3; 4], 0.3, [SLIP_BEYOND_EQ1, 0, 0, 0]),
            ([-1.0, -1.0, 0.02, 0.02], [0.0, 0.0, 0.34, 0.34], [0.33; 4], 0.33, 0.0, [0.0, 0.0, 0.3, 0.3], 0.3,
             [STOPPED_UNPOWERED, STOPPED_UNPOWERED, 0, 0]),
            ([0.8; 4], [0.25; 4], [0.05; 4], 0.05, 0.0, [0.5; 4], 0.3, [STALL; 4]),
            (spin, [0.3, 0.3, -0.3, -0.3], [0.0; 4], 0.0, 2.0, [0.5; 4], 0.3, [SKID_TURN; 4]),
            ([0.0; 4], [0.0; 4], [0.0; 4], 0.0, 0.0, [0.0; 4], 0.3, [USABLE; 4]),
            (spin, husky, [0.0; 4], 0.0, -0.21, [0.3; 4], 0.25, [SKID_TURN; 4]),
            ([0.5, 0.5, -0.5, -0.5], husky, [0.12; 4], 0.12, -0.6, [0.3; 4], 0.25, [SKID_TURN; 4]),
            ([0.1; 4], [1.1; 4], [1.0; 4], 1.0, 0.3, [0.3; 4], 0.25, [USABLE; 4]),
        ];
        for (i, (slip, rim, ground, v, yaw, gross, half_track, want)) in cases.into_iter().enumerate() {
            assert_eq!(
                codes(&slip, &rim, &ground, v, yaw, &gross, half_track, &lim, deadband),
                want,
                "case {i}"
            );
        }
    }
}
