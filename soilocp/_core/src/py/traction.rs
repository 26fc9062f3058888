//! `soilocp._core.traction_curve` / `traction_value` / `tractive_efficiency`: the traction law
//! (eqs. 2-6, 9; docs/method.md §8, §11) over arrays that broadcast together (numpy's rules).

use numpy::ndarray::{ArrayD, ArrayViewD, IxDyn, Zip};
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::constants::Constants;
use crate::traction::{self, Kind};

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

fn kind(name: &str) -> PyResult<Kind> {
    Kind::parse(name)
        .ok_or_else(|| PyValueError::new_err(format!("kind must be net, gross or resistance, got {name:?}")))
}

/// The shape numpy's broadcasting gives two shapes, or an error naming both.
fn broadcast_shape(a: &[usize], b: &[usize]) -> PyResult<Vec<usize>> {
    let n = a.len().max(b.len());
    let dim = |s: &[usize], i: usize| if i + s.len() >= n { s[i + s.len() - n] } else { 1 };
    (0..n)
        .map(|i| match (dim(a, i), dim(b, i)) {
            (x, y) if x == y || y == 1 => Ok(x),
            (1, y) => Ok(y),
            _ => Err(PyValueError::new_err(format!(
                "slip (shape {a:?}) and soil_strength (shape {b:?}) do not broadcast together"
            ))),
        })
        .collect()
}

/// Both arrays as views of their common (broadcast) shape.
fn broadcast<'a>(
    s: &'a ArrayViewD<'_, f64>,
    k: &'a ArrayViewD<'_, f64>,
) -> PyResult<(ArrayViewD<'a, f64>, ArrayViewD<'a, f64>)> {
    let shape = IxDyn(&broadcast_shape(s.shape(), k.shape())?);
    let fail = || PyValueError::new_err("slip and soil_strength do not broadcast together");
    Ok((
        s.broadcast(shape.clone()).ok_or_else(fail)?,
        k.broadcast(shape).ok_or_else(fail)?,
    ))
}

/// (value, d/dS, d/dK) of one curve of the traction law (`kind`: net = eq. 6, gross = eq. 2/3,
/// resistance = eq. 4 with |S|) at every (slip, soil_strength) pair.
#[pyfunction]
pub fn traction_curve<'py>(
    py: Python<'py>,
    kind_name: &str,
    slip: PyReadonlyArrayDyn<'py, f64>,
    soil_strength: PyReadonlyArrayDyn<'py, f64>,
    constants: &Constants,
) -> PyResult<(Arr<'py>, Arr<'py>, Arr<'py>)> {
    let kind = kind(kind_name)?;
    let (sa, ka) = (slip.as_array(), soil_strength.as_array());
    let (s, k) = broadcast(&sa, &ka)?;
    let mut value = ArrayD::<f64>::zeros(s.shape());
    let mut d_s = ArrayD::<f64>::zeros(s.shape());
    let mut d_k = ArrayD::<f64>::zeros(s.shape());
    Zip::from(&mut value)
        .and(&mut d_s)
        .and(&mut d_k)
        .and(&s)
        .and(&k)
        .for_each(|v, ds, dk, &s, &k| {
            let c = traction::curve(kind, s, k, constants);
            (*v, *ds, *dk) = (c.value, c.d_s, c.d_k);
        });
    Ok((value.into_pyarray(py), d_s.into_pyarray(py), d_k.into_pyarray(py)))
}

/// The value alone of one curve of the traction law (see `traction_curve`).
#[pyfunction]
pub fn traction_value<'py>(
    py: Python<'py>,
    kind_name: &str,
    slip: PyReadonlyArrayDyn<'py, f64>,
    soil_strength: PyReadonlyArrayDyn<'py, f64>,
    constants: &Constants,
) -> PyResult<Arr<'py>> {
    let kind = kind(kind_name)?;
    let (sa, ka) = (slip.as_array(), soil_strength.as_array());
    let (s, k) = broadcast(&sa, &ka)?;
    let out = Zip::from(&s)
        .and(&k)
        .map_collect(|&s, &k| traction::curve(kind, s, k, constants).value);
    Ok(out.into_pyarray(py))
}

/// Tractive efficiency TE = (mu / g)(1 - S), eq. 9, for driving slips 0 < S < 1 (checked by the
/// caller, which names the bad value).
#[pyfunction]
pub fn tractive_efficiency<'py>(
    py: Python<'py>,
    slip: PyReadonlyArrayDyn<'py, f64>,
    soil_strength: PyReadonlyArrayDyn<'py, f64>,
    constants: &Constants,
) -> PyResult<Arr<'py>> {
    let (sa, ka) = (slip.as_array(), soil_strength.as_array());
    let (s, k) = broadcast(&sa, &ka)?;
    let out = Zip::from(&s)
        .and(&k)
        .map_collect(|&s, &k| traction::tractive_efficiency(s, k, constants));
    Ok(out.into_pyarray(py))
}
