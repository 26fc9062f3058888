//! Argument checks the bindings share: a (k,) or a (k, 4) array of a step's k vehicles, refused
//! with a ValueError that names the argument and the shape it came with.

use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// `len` entries where the step has `k` vehicles.
pub fn check_len(name: &str, len: usize, k: usize) -> PyResult<()> {
    if len != k {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape ({k},), got ({len},)"
        )));
    }
    Ok(())
}

/// A `shape` of (k, 4): a row of four (one per wheel) per vehicle.
pub fn check_quads(name: &str, shape: &[usize], k: usize) -> PyResult<()> {
    if shape != [k, 4] {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape ({k}, 4), got {shape:?}"
        )));
    }
    Ok(())
}

/// The rows of four of a (k, 4) array.
pub fn quads<T: Copy + numpy::Element>(name: &str, a: &PyReadonlyArray2<'_, T>, k: usize) -> PyResult<Vec<[T; 4]>> {
    let v = a.as_array();
    check_quads(name, v.shape(), k)?;
    Ok(v.outer_iter().map(|r| [r[0], r[1], r[2], r[3]]).collect())
}

/// The entries of a (k,) array.
pub fn column<T: Copy + numpy::Element>(name: &str, a: &PyReadonlyArray1<'_, T>, k: usize) -> PyResult<Vec<T>> {
    let v = a.as_array();
    check_len(name, v.len(), k)?;
    Ok(v.to_vec())
}
