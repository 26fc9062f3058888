//! `soilocp._core.NormalForceSolver`: the zero-warp normal forces (eqs. 16-25, docs/method.md
//! §2-3) of one vehicle, its map built from the geometry, for one specific force (floats) or a bank
//! in one call; `gravity_from_attitude`: eq. 20 over arrays of roll and pitch.

use numpy::ndarray::{ArrayD, Axis, IxDyn};
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyType;

use crate::normal_force::{self, NormalForceMap};

/// (a, b, c, d, h, mass): what rebuilds a solver.
type Geometry = (f64, f64, f64, f64, f64, f64);

/// The solver of one vehicle: F = f M, M (3 x 4) computed once from its geometry and mass
/// ([`normal_force::zero_warp_map`], the one definition of M).
#[pyclass(frozen, module = "soilocp._core")]
pub struct NormalForceSolver {
    inner: NormalForceMap,
    /// (a, b, c, d, h, mass), for pickling
    geometry: [f64; 6],
}

#[pymethods]
impl NormalForceSolver {
    /// From the vehicle's a, b, c, d, h (m) and mass (kg); ValueError naming a value that is not
    /// finite and > 0.
    #[new]
    fn py_new(a: f64, b: f64, c: f64, d: f64, h: f64, mass: f64) -> PyResult<Self> {
        let inner = NormalForceMap::for_vehicle(a, b, c, d, h, mass).map_err(PyValueError::new_err)?;
        Ok(NormalForceSolver {
            inner,
            geometry: [a, b, c, d, h, mass],
        })
    }

    /// Pickle / deepcopy support (a stage travels to a worker process with its solver).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> (Bound<'py, PyType>, Geometry) {
        let [a, b, c, d, h, m] = slf.get().geometry;
        (slf.get_type(), (a, b, c, d, h, m))
    }

    /// F_z per wheel (N; wheels 1 LR, 2 LF, 3 RF, 4 RR) for one specific force (f_x, f_y, f_z) in
    /// m/s^2, as four floats: the N = 1 call of a stage service, no numpy.  ValueError naming
    /// specific_force and its value if one is not finite.
    fn solve_one(&self, fx: f64, fy: f64, fz: f64) -> PyResult<(f64, f64, f64, f64)> {
        if !(fx.is_finite() && fy.is_finite() && fz.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "specific_force must be finite, got ({fx:?}, {fy:?}, {fz:?})"
            )));
        }
        let [f1, f2, f3, f4] = self.inner.solve([fx, fy, fz]);
        Ok((f1, f2, f3, f4))
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
