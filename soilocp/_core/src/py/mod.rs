//! The Python side of the kernels: each function takes arrays (a bank of N vehicles or a grid),
//! runs the pure-Rust kernel once per element and returns arrays; one call per step.

pub mod args;
pub mod chain;
pub mod codes;
pub mod curve;
pub mod normal_force;
pub mod observer;
pub mod ocp;
pub mod settings;
pub mod slip;
pub mod soil;
pub mod torque_scale;
pub mod traction;
