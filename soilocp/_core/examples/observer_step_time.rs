//! Wall time of one observer step without Python, the filter alone (FilterBank::step, slip
//! structure) and the whole step around it (vehicles::ObserverBank::step: readings clock, latency
//! fit, refresh pairs), on a drive whose speeds, torques and forces keep changing (constant inputs
//! let P decay into subnormal numbers, each a slow operation):
//! `cargo run --release --example observer_step_time [STEPS]`.
use _core::observer::bank::{FilterBank, Sample, Settings};
use _core::observer::intervals::IntervalSettings;
use _core::observer::model::ROVER;
use _core::observer::settings::ObserverSettings;
use _core::observer::vehicles::{ObserverBank, Raw, Reading};

fn main() {
    let settings = ObserverSettings::default();
    let l = settings.layout();
    let v = ROVER;
    let s = Settings::of(&settings, &l, false, 0.005).unwrap();
    let mut bank = FilterBank::new(l, v, s.clone(), 1).unwrap();
    let mut sample = Sample {
        dt: f64::NAN,
        dt_cubed: f64::NAN,
        specific_force_x: 0.1,
        yaw_rate: 0.0,
        pitch: 0.0,
        wheel_speed: [5.0; 4],
        ground_speed: 0.7,
        wheel_speed_z: [5.0; 4],
        ground_speed_z: 0.7,
        torque: [3.0; 4],
        normal_force: [150.0; 4],
        fresh: [true; 5],
    };
    bank.step(0, &sample);
    sample.dt = 0.01;
    sample.dt_cubed = 1e-6;
    let steps: usize = std::env::args().nth(1).map_or(100_000, |s| s.parse().unwrap());
    let t = std::time::Instant::now();
    for i in 0..steps {
        let d = drive(i);
        (sample.wheel_speed_z, sample.torque, sample.normal_force) = (d.wheel_speed, d.wheel_torque, d.normal_force);
        sample.wheel_speed = sample.wheel_speed_z;
        sample.ground_speed_z = d.ground_speed;
        sample.specific_force_x = d.specific_force_x;
        std::hint::black_box(bank.step(0, &sample));
    }
    println!(
        "filter: {:.2} us per step",
        t.elapsed().as_secs_f64() / steps as f64 * 1e6
    );

    let reading = Reading::of(&settings, false, false);
    let refresh = IntervalSettings::of(&settings, v.wheel_inertia, v.wheel_radius);
    let mut whole = ObserverBank::new(FilterBank::new(l, v, s, 1).unwrap(), reading, refresh);
    let mut raw = Raw {
        stamp: 0.0,
        specific_force_x: 0.1,
        yaw_rate: 0.0,
        pitch: 0.0,
        wheel_speed: [5.0; 4],
        wheel_torque: [3.0; 4],
        ground_speed: 0.7,
        normal_force: [150.0; 4],
    };
    let t = std::time::Instant::now();
    for i in 0..steps {
        let held = raw.wheel_torque;
        raw = drive(i);
        // a torque stream held for 5 samples (a slow driver): the refresh pairs run
        if i % 5 != 0 {
            raw.wheel_torque = held;
        }
        std::hint::black_box(whole.step(0, &raw));
    }
    println!(
        "whole step: {:.2} us per step",
        t.elapsed().as_secs_f64() / steps as f64 * 1e6
    );
}

/// Step `i` of the drive (100 Hz): speeds, torques and forces that keep changing, with a little noise.
fn drive(i: usize) -> Raw {
    let t = i as f64 * 0.01;
    let noise = |k: usize| (((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0 - 0.5) * 0.06;
    let wheel = |w: usize, f: fn(f64) -> f64, rate: f64| f(rate * t + w as f64);
    Raw {
        stamp: t,
        specific_force_x: 0.06 * (0.3 * t).cos() + noise(6),
        yaw_rate: 0.0,
        pitch: 0.0,
        wheel_speed: std::array::from_fn(|w| 5.0 + 1.5 * wheel(w, f64::sin, 0.3) + noise(w)),
        wheel_torque: std::array::from_fn(|w| 3.0 + 2.0 * wheel(w, f64::cos, 0.5)),
        ground_speed: 0.7 + 0.2 * (0.3 * t).sin() + noise(5) / 3.0,
        normal_force: std::array::from_fn(|w| 150.0 + 20.0 * wheel(w, f64::sin, 0.2)),
    }
}
