//! The torque scale learnt online (docs/method.md §15): one common scale k of the wheel
//! torques (motor constant x 1 / mass), a slow state per vehicle, from the longitudinal force
//! balance (eq. TC) whenever the robot accelerates or brakes; and eq. TC itself, the one
//! definition that `soilocp calibrate-torque` fits offline and the online state uses.
//!
//! One kind per module: [`balance`] eq. TC and the modelled motion resistance (eq. 4 summed);
//! [`params`] the settings; [`window`] the trapezoid window means; [`kalman`] the (k, F_MR)
//! filter (F_MR = b + c |a|) with its Schmidt update; [`bank`] the state of N vehicles, one call
//! per step.
//! `crate::py::torque_scale` binds the bank to Python.
//!
//! The arithmetic follows the numpy kernel it replaced operation by operation (its einsum orders;
//! sums of four in wheel order), so that the port gives its numbers to the last bit: the torques it
//! scales feed the observer, whose gates turn a 1e-16 difference into a changed status thousands
//! of samples later (docs/core-observer.md).

pub mod balance;
pub mod bank;
pub mod kalman;
pub mod params;
pub mod window;
