//! `soilocp._core.ocp_bank`: the OCPs (eqs. 7-10) of a bank of soil strengths in one call;
//! `ocp_one`: the same for one K, as Python floats (the OCP publisher loads no numpy).

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
    let ks = soil_strength.as_array().to_vec();
    let o = ocp::bank(&ks, constants).map_err(PyValueError::new_err)?;
    let col = |f: fn(&ocp::Ocp) -> f64| o.iter().map(f).collect::<Vec<f64>>();
    let (mu_t, s_t, s_e, te) = (col(|x| x.mu_t), col(|x| x.s_t), col(|x| x.s_e), col(|x| x.te_at_s_e));
    Ok((
        mu_t.into_pyarray(py),
        s_t.into_pyarray(py),
        s_e.into_pyarray(py),
        te.into_pyarray(py),
    ))
}

/// (mu_T, S_T, S_E, TE at S_E) of one K, as [`ocp_bank`] gives them for a bank of one (the same
/// `ocp::ocp`); NaN for NaN (no estimate).  Floats in and out: the OCP publisher's path, which
/// loads no numpy.  ValueError for a K the model cannot evaluate.
#[pyfunction]
pub fn ocp_one(soil_strength: f64, constants: &Constants) -> PyResult<(f64, f64, f64, f64)> {
    if !ocp::evaluable(soil_strength, constants) {
        return Err(PyValueError::new_err(format!(
            "soil_strength = {soil_strength} is not a K the model can evaluate (finite, > 0, C5 / K finite)"
        )));
    }
    let o = ocp::ocp(soil_strength, constants);
    Ok((o.mu_t, o.s_t, o.s_e, o.te_at_s_e))
}

/// (mu_T's, S_T's) 1-sigma carried from K's band through the curve ([`ocp::band`]): what K's
/// uncertainty means for the OCPs a controller acts on.  NaN for a missing K or band.
#[pyfunction]
pub fn ocp_band(soil_strength: f64, log_k_std: f64, constants: &Constants) -> (f64, f64) {
    let [mu, s] = ocp::band(soil_strength, log_k_std, constants);
    (mu, s)
}
