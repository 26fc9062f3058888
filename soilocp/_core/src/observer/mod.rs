//! The traction observer's filter (paper eqs. 11-15, 26-35 with the corrections of
//! docs/method.md §7, §11-12, §17) for a bank of N vehicles, one call per step.
//!
//! `layout` names the state's indices, `model` builds A, b, H (eq. 33) and the resistance map,
//! `kalman` holds predict (eq. 34), the gated/Huber update (eq. 35, Joseph form) and the
//! conditioning, `numeric` the NaN rules the divergence guard needs and the fused products, `bank` the state of
//! N vehicles (x, P, gate counters, resets with reasons, re-anchoring, divergence guard).
//! Around the filter, `readings` tells which raw readings are new measurements, `wheel_inputs`
//! splits a skid-steer side's torque and leads an interval-mean encoder speed, `latency` measures
//! and leads a late ground speed, `intervals` serves the gross traction of a slow stream's
//! refreshes, `walk` slows the resistance's random walk while the slips spread, and `vehicles` runs all of it for N vehicles, one call per step.  `settings` declares
//! the observer's settings once and resolves them for a layout and a vehicle.

// matrix code indexes rows and columns of several arrays in one loop: index loops read as the equations
#![allow(clippy::needless_range_loop)]

pub mod bank;
pub mod intervals;
pub mod kalman;
pub mod latency;
pub mod layout;
pub mod model;
pub mod numeric;
pub mod readings;
pub mod settings;
pub mod vehicles;
pub mod walk;
pub mod wheel_inputs;
