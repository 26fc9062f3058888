//! `soilocp._core.ocp_bank`: the OCPs (eqs. 7-10) of a bank of soil strengths in one call.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::constants::Constants;
use crate::ocp;

type Arr<'py> = Bound<'py, PyArray1<f64>>;

/// (mu_T, S_T, S_E, TE at S_E) for each K of a bank: eq. 8, eq. 7 (sign corrected, docs/method.md
/// §1), eq. 10 (clamped at 0, §5) and eq. 9 at S_E (NaN unless 0 < S_E < 1).  A NaN K (no
/// estimate) gives NaNs; any other K must be finite and > 0 with C5 / K finite, else ValueError
/// naming its index (the caller words the message).
#[pyfunction]
pub fn ocp_bank<'py>(
    py: Python<'py>,
    soil_strength: PyReadonlyArray1<'py, f64>,
    constants: &Constants,
) -> PyResult<(Arr<'py>, Arr<'py>, Arr<'py>, Arr<'py>)> {
    let k = soil_strength.as_array();
    if let Some(i) = k.iter().position(|&k| !ocp::evaluable(k, constants)) {
        return Err(PyValueError::new_err(format!(
            "soil_strength[{i}] = {} is not a K the model can evaluate (finite, > 0, C5 / K finite)",
            k[i]
        )));
    }
    let n = k.len();
    let (mut mu_t, mut s_t, mut s_e, mut te) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for &kk in k.iter() {
        let o = ocp::ocp(kk, constants);
        mu_t.push(o.mu_t);
        s_t.push(o.s_t);
        s_e.push(o.s_e);
        te.push(o.te_at_s_e);
    }
    Ok((
        mu_t.into_pyarray(py),
        s_t.into_pyarray(py),
        s_e.into_pyarray(py),
        te.into_pyarray(py),
    ))
}
