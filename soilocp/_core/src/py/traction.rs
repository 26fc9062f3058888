//! `soilocp._core.traction_curve` / `traction_value` / `tractive_efficiency`: the traction law
//! (eqs. 2-6, 9; docs/method.md §8, §11) over arrays that broadcast together (numpy's rules).

use numpy::ndarray::{ArrayD, Zip};
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::constants::Constants;
use crate::traction::{self, Kind};

use super::args::broadcast;

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

fn kind(name: &str) -> PyResult<Kind> {
    Kind::parse(name)
        .ok_or_else(|| PyValueError::new_err(format!("kind must be net, gross or resistance, got {name:?}")))
}

/// `f` of every (slip, soil_strength) pair of two arrays that broadcast together.
fn map_pairs<'py>(
    py: Python<'py>,
    slip: &PyReadonlyArrayDyn<'py, f64>,
    soil_strength: &PyReadonlyArrayDyn<'py, f64>,
    f: impl Fn(f64, f64) -> f64,
) -> PyResult<Arr<'py>> {
    let (sa, ka) = (slip.as_array(), soil_strength.as_array());
    let (s, k) = broadcast(("slip", "soil_strength"), &sa, &ka)?;
    Ok(Zip::from(&s).and(&k).map_collect(|&s, &k| f(s, k)).into_pyarray(py))
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
    let (s, k) = broadcast(("slip", "soil_strength"), &sa, &ka)?;
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
    map_pairs(py, &slip, &soil_strength, |s, k| {
        traction::curve(kind, s, k, constants).value
    })
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
    map_pairs(py, &slip, &soil_strength, |s, k| {
        traction::tractive_efficiency(s, k, constants)
    })
}
