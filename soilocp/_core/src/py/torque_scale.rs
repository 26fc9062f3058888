//! `soilocp._core.TorqueScaleCore`: the torque scales of N vehicles (crate::torque_scale), which the
//! chain (crate::py::chain) steps with the observer and feeds the soil's K back to; this binding
//! holds the bank between the chain's calls and reads its state.
//! `longitudinal_balance` and `modelled_resistance`: eq. TC and eq. 4 summed over arrays, for the
//! offline fit (`soilocp calibrate-torque`) and the tests.

use std::collections::HashMap;

use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::constants::Constants;
use crate::torque_scale::balance::{self, Body};
use crate::torque_scale::bank;
use crate::torque_scale::params::{Derived, Params, Settings};

use super::args::{check_len, column, quads, to_column, to_rows, vehicles};

type Pair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// The torque scales of N vehicles (docs/method.md §15).
#[pyclass(module = "soilocp._core")]
pub struct TorqueScaleCore {
    inner: bank::TorqueScaleBank,
}

impl TorqueScaleCore {
    /// The bank inside (the chain, crate::py::chain, steps it with the other stages).
    pub(crate) fn bank_mut(&mut self) -> &mut bank::TorqueScaleBank {
        &mut self.inner
    }
}

#[pymethods]
impl TorqueScaleCore {
    /// The bank of `n_vehicles` from the traction law's `constants`, the vehicle's mass (kg), one
    /// wheel's inertia (kg m^2) and radius (m), the torque scale's `settings` (by the names of
    /// crate::torque_scale::params::Settings; a missing one takes its default) and the numbers
    /// derived from other settings (crate::torque_scale::params::Derived).
    #[new]
    #[pyo3(signature = (constants, n_vehicles, mass, wheel_inertia, wheel_radius, settings, *, state_sigma,
                        prior_sigma, k_default, slip_floor, gravity, model_resistance))]
    #[allow(clippy::too_many_arguments)]
    fn py_new(
        constants: Constants,
        n_vehicles: usize,
        mass: f64,
        wheel_inertia: f64,
        wheel_radius: f64,
        settings: HashMap<String, f64>,
        state_sigma: f64,
        prior_sigma: f64,
        k_default: f64,
        slip_floor: f64,
        gravity: f64,
        model_resistance: bool,
    ) -> PyResult<Self> {
        let body = Body::new(mass, wheel_inertia, wheel_radius).map_err(PyValueError::new_err)?;
        let settings = Settings::from_map(&settings).map_err(PyValueError::new_err)?;
        let derived = Derived {
            state_sigma,
            prior_sigma,
            k_default,
            slip_floor,
            gravity,
            model_resistance,
        };
        let params = Params::new(&settings, derived).map_err(PyValueError::new_err)?;
        let inner = bank::TorqueScaleBank::new(params, body, constants, n_vehicles).map_err(PyValueError::new_err)?;
        Ok(TorqueScaleCore { inner })
    }

    /// k's mean and 1-sigma for the vehicles `idx`.
    fn scale<'py>(&self, py: Python<'py>, idx: PyReadonlyArray1<'py, i64>) -> PyResult<Pair<'py>> {
        let ix = vehicles(Some(&idx), self.inner.len())?;
        let (m, sd): (Vec<f64>, Vec<f64>) = ix.iter().map(|&i| self.inner.scale(i)).unzip();
        Ok((m.into_pyarray(py), sd.into_pyarray(py)))
    }

    /// k's 1-sigma for K's band from posterior 1-sigmas `sd` (crate::torque_scale::bank's
    /// `band_sigma`).
    fn band_sigma<'py>(&self, py: Python<'py>, sd: PyReadonlyArray1<'py, f64>) -> Bound<'py, PyArray1<f64>> {
        sd.as_array().mapv(|v| self.inner.band_sigma(v)).into_pyarray(py)
    }

    /// (k, F_MR) of every vehicle, (N, 2).
    #[getter]
    fn theta<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let theta = |i: usize| self.inner.state(i).theta;
        to_rows(py, (0..self.inner.len()).map(|i| [theta(i)[0], theta(i)[1]]))
    }

    /// Their covariances, (N, 2, 2).
    #[getter]
    fn p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        let n = self.inner.len();
        Array3::from_shape_fn((n, 2, 2), |(i, j, l)| self.inner.state(i).p[j][l]).into_pyarray(py)
    }

    /// The soil's K each vehicle's modelled resistance uses now, (N,).
    #[getter]
    fn soil_k<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        to_column(py, (0..self.inner.len()).map(|i| self.inner.soil_k(i)))
    }
}

/// Eq. TC, the longitudinal force balance of docs/method.md §15 (crate::torque_scale::balance::longitudinal_balance),
/// over 1-D arrays of one length (the caller broadcasts): (x, y) in N.  `resistance` None: b is the whole F_MR.
#[pyfunction]
#[pyo3(signature = (f_x, omega_dot_sum, torque_sum, mass, wheel_inertia, wheel_radius, resistance=None))]
#[allow(clippy::too_many_arguments)]
pub fn longitudinal_balance<'py>(
    py: Python<'py>,
    f_x: PyReadonlyArray1<'py, f64>,
    omega_dot_sum: PyReadonlyArray1<'py, f64>,
    torque_sum: PyReadonlyArray1<'py, f64>,
    mass: f64,
    wheel_inertia: f64,
    wheel_radius: f64,
    resistance: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<Pair<'py>> {
    let body = Body::new(mass, wheel_inertia, wheel_radius).map_err(PyValueError::new_err)?;
    let (f, od, t) = (f_x.as_array(), omega_dot_sum.as_array(), torque_sum.as_array());
    let n = f.len();
    check_len("omega_dot_sum", od.len(), n)?;
    check_len("torque_sum", t.len(), n)?;
    let res = resistance.as_ref().map(|a| a.as_array());
    if let Some(a) = &res {
        check_len("resistance", a.len(), n)?;
    }
    let (x, y): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|j| balance::longitudinal_balance(f[j], od[j], t[j], res.as_ref().map(|a| a[j]), &body))
        .unzip();
    Ok((x.into_pyarray(py), y.into_pyarray(py)))
}

/// F_MR,model: eq. 4's motion resistance summed over the wheels, even in slip with the wheel's direction
/// of travel (docs/method.md §11, §17; crate::torque_scale::balance::modelled_resistance) per row: slips and normal
/// forces (k, 4), soil strength and direction of travel (k,); returns (k,) in N.
#[pyfunction]
pub fn modelled_resistance<'py>(
    py: Python<'py>,
    slip: PyReadonlyArray2<'py, f64>,
    soil_strength: PyReadonlyArray1<'py, f64>,
    normal_force: PyReadonlyArray2<'py, f64>,
    direction: PyReadonlyArray1<'py, f64>,
    constants: &Constants,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let k = soil_strength.as_array();
    let n = k.len();
    let s = quads("slip", &slip, n)?;
    let fz = quads("normal_force", &normal_force, n)?;
    let d = column("direction", &direction, n)?;
    let out: Vec<f64> = (0..n)
        .map(|j| balance::modelled_resistance(&s[j], k[j], &fz[j], d[j], constants))
        .collect();
    Ok(out.into_pyarray(py))
}
