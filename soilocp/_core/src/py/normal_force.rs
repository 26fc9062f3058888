//! `soilocp._core.NormalForceSolver`: the zero-warp normal forces (eqs. 16-25, docs/method.md
//! §2-3) of one vehicle for a bank of specific forces in one call; `gravity_from_attitude`: eq. 20
//! over arrays of roll and pitch.

use numpy::ndarray::{ArrayD, Axis, IxDyn};
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyReadonlyArray2, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyType;

use crate::normal_force::{self, NormalForceMap};

/// The solver of one vehicle: F = f M, M (3 x 4) prepared by the caller once per vehicle.
#[pyclass(frozen, module = "soilocp._core")]
pub struct NormalForceSolver {
    inner: NormalForceMap,
}

#[pymethods]
impl NormalForceSolver {
    #[new]
    fn py_new(map: PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let m = map.as_array();
        if m.shape() != [3, 4] {
            return Err(PyValueError::new_err(format!(
                "map must have shape (3, 4), got {:?}",
                m.shape()
            )));
        }
        let rows: [[f64; 4]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| m[[i, j]]));
        let inner = NormalForceMap::new(rows).map_err(PyValueError::new_err)?;
        Ok(NormalForceSolver { inner })
    }

    /// Pickle / deepcopy support (a stage travels to a worker process with its solver).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> (Bound<'py, PyType>, (Bound<'py, PyArray2<f64>>,)) {
        (slf.get_type(), (Self::map(slf.get(), slf.py()),))
    }

    /// F_z per wheel (N; wheels 1 LR, 2 LF, 3 RF, 4 RR) for specific forces of shape (..., 3)
    /// in m/s^2: shape (..., 4).  ValueError if the last axis is not 3 or a value is not finite.
    fn solve<'py>(
        &self,
        py: Python<'py>,
        specific_force: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let f = specific_force.as_array();
        let shape = f.shape();
        if shape.last() != Some(&3) {
            return Err(PyValueError::new_err(format!(
                "specific_force must have shape (..., 3), got shape {shape:?}"
            )));
        }
        if !f.iter().all(|v| v.is_finite()) {
            return Err(PyValueError::new_err("specific_force must be finite"));
        }
        let mut out_shape = shape.to_vec();
        *out_shape.last_mut().unwrap() = 4;
        if let Some(flat) = f.as_slice() {
            // the usual case, a C-contiguous (N, 3): one pass over the memory
            let mut out = Vec::with_capacity(flat.len() / 3 * 4);
            for row in flat.chunks_exact(3) {
                out.extend_from_slice(&self.inner.solve([row[0], row[1], row[2]]));
            }
            let out = ArrayD::from_shape_vec(IxDyn(&out_shape), out).expect("4 per row");
            return Ok(out.into_pyarray(py));
        }
        let mut out = ArrayD::<f64>::zeros(IxDyn(&out_shape));
        let last = Axis(shape.len() - 1);
        for (row_in, mut row_out) in f.lanes(last).into_iter().zip(out.lanes_mut(last)) {
            let fz = self.inner.solve([row_in[0], row_in[1], row_in[2]]);
            for j in 0..4 {
                row_out[j] = fz[j];
            }
        }
        Ok(out.into_pyarray(py))
    }

    /// The (3, 4) matrix M with F = f @ M.
    #[getter]
    fn map<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let rows: Vec<Vec<f64>> = self.inner.map.iter().map(|r| r.to_vec()).collect();
        PyArray2::from_vec2(py, &rows).expect("3 rows of 4")
    }
}

/// Eq. 20 (docs/method.md §3): the gravity reaction in the body frame (m/s^2), shape (..., 3), for
/// roll and pitch arrays of one shape (rad; the caller broadcasts and checks them) and gravity g.
#[pyfunction]
pub fn gravity_from_attitude<'py>(
    py: Python<'py>,
    roll: PyReadonlyArrayDyn<'py, f64>,
    pitch: PyReadonlyArrayDyn<'py, f64>,
    g: f64,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (roll, pitch) = (roll.as_array(), pitch.as_array());
    if roll.shape() != pitch.shape() {
        return Err(PyValueError::new_err(format!(
            "roll (shape {:?}) and pitch (shape {:?}) must have one shape",
            roll.shape(),
            pitch.shape()
        )));
    }
    let mut shape = roll.shape().to_vec();
    let mut out = Vec::with_capacity(roll.len() * 3);
    // both in logical (C) order, whatever their memory layout
    for (&al, &th) in roll.iter().zip(pitch.iter()) {
        out.extend_from_slice(&normal_force::gravity_from_attitude(al, th, g));
    }
    shape.push(3);
    let out = ArrayD::from_shape_vec(IxDyn(&shape), out).expect("3 per attitude");
    Ok(out.into_pyarray(py))
}
