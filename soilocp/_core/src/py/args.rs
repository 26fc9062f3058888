//! Argument checks the bindings share: a step's vehicle indices, a (k,) or a (k, 4) array of its k
//! vehicles (and, for the observer's inputs, every entry finite), two arrays that broadcast together,
//! refused with a ValueError that names the argument and what it came with; and the other way, the
//! numpy arrays the bindings return of their vehicles' (or samples') numbers, one row each.

use numpy::ndarray::{Array1, Array2, ArrayD, ArrayView1, ArrayView2, ArrayViewD, IxDyn, Zip};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// The vehicles of a step of a bank of `n` from `idx` (None: all, in order): distinct indices in
/// [0, n) (crate::index::vehicles), else a ValueError naming them.
pub fn vehicles(idx: Option<&PyReadonlyArray1<'_, i64>>, n: usize) -> PyResult<Vec<usize>> {
    match idx {
        None => Ok((0..n).collect()),
        Some(idx) => crate::index::vehicles(&idx.as_array().to_vec(), n).map_err(PyValueError::new_err),
    }
}

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

/// Row `j` of a (k, 4) array (its shape checked by the caller), one entry per wheel.
pub fn row(a: &ArrayView2<'_, f64>, j: usize) -> [f64; 4] {
    [a[[j, 0]], a[[j, 1]], a[[j, 2]], a[[j, 3]]]
}

/// The entries of a (k,) array.
pub fn column<T: Copy + numpy::Element>(name: &str, a: &PyReadonlyArray1<'_, T>, k: usize) -> PyResult<Vec<T>> {
    let v = a.as_array();
    check_len(name, v.len(), k)?;
    Ok(v.to_vec())
}

/// A (k,) input of the observer's step: its shape, and every entry finite (`nan_ok`: or NaN, "none");
/// the message is the Python side's (soilocp.estimation.observer_bank.ObserverInputs.check).
pub fn check_finite_column(name: &str, a: &ArrayView1<'_, f64>, k: usize, nan_ok: bool) -> PyResult<()> {
    let ok = a.iter().all(|v| v.is_finite() || (nan_ok && v.is_nan()));
    if a.len() != k || !ok {
        return Err(PyValueError::new_err(format!(
            "inputs.{name} must be a finite array of shape ({k},), got {a}"
        )));
    }
    Ok(())
}

/// A (k, 4) input of the observer's step: its shape, and every entry finite.
pub fn check_finite_quads(name: &str, a: &ArrayView2<'_, f64>, k: usize) -> PyResult<()> {
    if a.shape() != [k, 4] || !a.iter().all(|v| v.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "inputs.{name} must be a finite array of shape ({k}, 4), got {a}"
        )));
    }
    Ok(())
}

/// Both arrays as views of their common shape (numpy's broadcasting), or an error naming them.
pub fn broadcast<'a>(
    names: (&str, &str),
    a: &'a ArrayViewD<'_, f64>,
    b: &'a ArrayViewD<'_, f64>,
) -> PyResult<(ArrayViewD<'a, f64>, ArrayViewD<'a, f64>)> {
    let (sa, sb) = (a.shape(), b.shape());
    let n = sa.len().max(sb.len());
    let dim = |s: &[usize], i: usize| if i + s.len() >= n { s[i + s.len() - n] } else { 1 };
    let fail = || {
        PyValueError::new_err(format!(
            "{} (shape {sa:?}) and {} (shape {sb:?}) do not broadcast together",
            names.0, names.1
        ))
    };
    let shape: Vec<usize> = (0..n)
        .map(|i| match (dim(sa, i), dim(sb, i)) {
            (x, y) if x == y || y == 1 => Ok(x),
            (1, y) => Ok(y),
            _ => Err(fail()),
        })
        .collect::<PyResult<_>>()?;
    let shape = IxDyn(&shape);
    Ok((
        a.broadcast(shape.clone()).ok_or_else(fail)?,
        b.broadcast(shape).ok_or_else(fail)?,
    ))
}

/// `f` of every pair of two arrays that broadcast together (`names`: theirs, for the error), in
/// their common shape: the elementwise bindings (eq. 1, the traction law) over numpy's rules.
pub fn map_broadcast<R>(
    names: (&str, &str),
    a: &PyReadonlyArrayDyn<'_, f64>,
    b: &PyReadonlyArrayDyn<'_, f64>,
    f: impl Fn(f64, f64) -> R,
) -> PyResult<ArrayD<R>> {
    let (a, b) = (a.as_array(), b.as_array());
    let (a, b) = broadcast(names, &a, &b)?;
    Ok(Zip::from(&a).and(&b).map_collect(|&a, &b| f(a, b)))
}

/// One part `part` of every entry of `a`, as a C-ordered array of its shape: how the bindings with
/// several outputs per pair (eq. 1's slip and scale, a curve's value and derivatives) return each.
pub fn part<T>(a: &ArrayD<T>, part: impl Fn(&T) -> f64) -> ArrayD<f64> {
    ArrayD::from_shape_vec(a.raw_dim(), a.iter().map(part).collect()).expect("one value per entry")
}

/// One number per item (a vehicle, a sample) as a (k,) array.
pub fn to_column<'py, E: numpy::Element>(py: Python<'py>, items: impl Iterator<Item = E>) -> Bound<'py, PyArray1<E>> {
    Array1::from_iter(items).into_pyarray(py)
}

/// One row of `M` numbers per item (a vehicle's four wheels, a step's statistics) as a (k, M) array.
pub fn to_rows<'py, E: numpy::Element, const M: usize>(
    py: Python<'py>,
    items: impl ExactSizeIterator<Item = [E; M]>,
) -> Bound<'py, PyArray2<E>> {
    let k = items.len();
    let flat: Vec<E> = items.flatten().collect();
    Array2::from_shape_vec((k, M), flat)
        .expect("M numbers per row")
        .into_pyarray(py)
}

/// One row of `width` numbers per item (a vehicle's belief over the grid) as a (k, width) array.
pub fn to_rows_of<'a, 'py, E: numpy::Element + Copy + 'a>(
    py: Python<'py>,
    width: usize,
    items: impl ExactSizeIterator<Item = &'a [E]>,
) -> Bound<'py, PyArray2<E>> {
    let k = items.len();
    let flat: Vec<E> = items.flat_map(|r| r[..width].iter().copied()).collect();
    Array2::from_shape_vec((k, width), flat)
        .expect("width numbers per row")
        .into_pyarray(py)
}
