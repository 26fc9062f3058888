//! The traction observer's filter (paper eqs. 11-15, 26-35 with the corrections of
//! docs/method.md §7, §11-12, §17) for a bank of N vehicles, one call per step.
//!
//! `layout` names the state's indices, `model` builds A, b, H (eq. 33) and the resistance map,
//! `kalman` holds predict (eq. 34), the gated/Huber update (eq. 35, Joseph form) and the
//! conditioning, `numeric` numpy's NaN and summation rules the kernels mirror, `bank` the state of
//! N vehicles (x, P, gate counters, resets with reasons, re-anchoring, divergence guard).
//! The readings clock, the refresh intervals and the ground-speed latency stay in Python
//! (soilocp.estimation.readings, refresh_traction, ground_speed_latency): the bank takes their
//! results (which readings are new, the led ground speed) as inputs.

// matrix code indexes rows and columns of several arrays in one loop: index loops read as the equations
#![allow(clippy::needless_range_loop)]

pub mod bank;
pub mod kalman;
pub mod layout;
pub mod model;
pub mod numeric;
