//! The soil stage's per-sample update (docs/method.md §6, §9, §11, §16, §17): the slip gate and
//! the wheels' usability codes, then a grid (histogram) Bayes
//! filter over ln K per vehicle, its no-change belief, the window statistics of the band and the
//! mismatch check, the scale profile and the front/rear axle check.  Plain Rust over f64, one
//! kind per module; `crate::py::soil` binds the bank to Python.
//!
//! The arithmetic is plain f64: the grid's sums in eight lanes ([`numeric::grid_sum`]), cumulative
//! sums in order, linear interpolation from the last node at or below x.  The tests hold it to the
//! numpy reference it replaced (tests/reference_soil.py) within a relative 1e-9: the rounding of a
//! sum's order, not a difference of method.

pub mod axles;
pub mod bank;
pub mod classes;
pub mod gate;
pub mod grid;
pub mod numeric;
pub mod params;
pub mod scale;
pub mod status;
pub mod usability;
