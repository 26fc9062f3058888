//! `soilocp._core.traction_curve` / `traction_value` / `tractive_efficiency`: the traction law
//! (eqs. 2-6, 9; docs/method.md §8, §11) over arrays that broadcast together (numpy's rules).

use numpy::ndarray::ArrayD;
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::constants::Constants;
use crate::traction::{self, Kind};

use super::args::{map_broadcast, part};

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

fn kind(name: &str) -> PyResult<Kind> {
    Kind::parse(name)
        .ok_or_else(|| PyValueError::new_err(format!("kind must be net, gross or resistance, got {name:?}")))
}

/// `f` of every (slip, soil_strength) pair of two arrays that broadcast together.
fn map_pairs<R>(
    slip: &PyReadonlyArrayDyn<'_, f64>,
    soil_strength: &PyReadonlyArrayDyn<'_, f64>,
    f: impl Fn(f64, f64) -> R,
) -> PyResult<ArrayD<R>> {
    map_broadcast(("slip", "soil_strength"), slip, soil_strength, f)
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
    let curves = map_pairs(&slip, &soil_strength, |s, k| traction::curve(kind, s, k, constants))?;
    Ok((
        part(&curves, |c| c.value).into_pyarray(py),
        part(&curves, |c| c.d_s).into_pyarray(py),
        part(&curves, |c| c.d_k).into_pyarray(py),
    ))
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
    let values = map_pairs(&slip, &soil_strength, |s, k| {
        traction::curve(kind, s, k, constants).value
    })?;
    Ok(values.into_pyarray(py))
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
    let values = map_pairs(&slip, &soil_strength, |s, k| {
        traction::tractive_efficiency(s, k, constants)
    })?;
    Ok(values.into_pyarray(py))
}
