//! The soil stage's per-sample update (docs/method.md §6, §9, §11, §16, §17): the slip gate and
//! the wheels' usability codes, then a grid (histogram) Bayes
//! filter over ln K per vehicle, its no-change belief, the window statistics of the band and the
//! mismatch check, the scale profile and the front/rear axle check.  Plain Rust over f64, one
//! kind per module; `crate::py::soil` binds the bank to Python.
//!
//! The arithmetic mirrors the numpy reference operation by operation (numpy's pairwise sums,
//! sequential cumulative sums, `np.interp`), so that the port agrees with it to rounding: the
//! gates of the estimator are chaotic, and a changed summation order shows up as changed
//! statuses thousands of samples later.

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
