//! `soilocp._core.CurveBank`: the wheel-curve learners of N vehicles (crate::curve), one call per
//! sample of one vehicle.  Floats in and out: the OCP publisher, which runs it, loads no numpy.

use std::collections::HashMap;

use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;

use crate::curve::{CurveLearner, Fit, Params};

/// The wheel-curve learners of N vehicles (docs/method.md §19).
#[pyclass(module = "soilocp._core")]
pub struct CurveBank {
    learners: Vec<CurveLearner>,
}

impl CurveBank {
    /// `j`, a vehicle of the bank, or an IndexError.
    fn vehicle(&self, j: usize) -> PyResult<usize> {
        let n = self.learners.len();
        if j < n {
            Ok(j)
        } else {
            Err(PyIndexError::new_err(format!("vehicle index {j} out of [0, {n})")))
        }
    }
}

#[pymethods]
impl CurveBank {
    /// N learners with the curve `settings` (by the names of crate::curve::Params; a missing one
    /// takes its default), whose traction is read through torques of common scale relative 1-sigma
    /// `scale_sigma` (the soil estimator's `gross_scale_sigma`: the level of the learnt mu_T's band).
    #[new]
    fn new(n_vehicles: usize, settings: HashMap<String, f64>, scale_sigma: f64) -> PyResult<Self> {
        if !(scale_sigma.is_finite() && scale_sigma >= 0.0) {
            return Err(PyValueError::new_err(format!(
                "scale_sigma = {scale_sigma}: the torques' relative 1-sigma must be finite and >= 0 (soil.gross_scale_sigma)"
            )));
        }
        let params = Params::from_map(&settings).map_err(PyValueError::new_err)?;
        if params.slip_max <= params.slip_min {
            return Err(PyValueError::new_err(format!(
                "curve settings: slip_max = {} must exceed slip_min = {}",
                params.slip_max, params.slip_min
            )));
        }
        Ok(CurveBank {
            learners: vec![CurveLearner::new(params, scale_sigma); n_vehicles],
        })
    }

    /// Vehicle `j`'s sample: stamp (s), slips (4,), net traction (4,), which wheels inform (4,), the
    /// ground-speed latency estimate the slips were formed under (s).  Returns the current soil's
    /// fit, or None while it has too few pairs or shows no peak.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &mut self,
        j: usize,
        stamp: f64,
        slip: [f64; 4],
        mu: [f64; 4],
        used: [bool; 4],
        latency: f64,
    ) -> PyResult<Option<Fit>> {
        let j = self.vehicle(j)?;
        Ok(self.learners[j].step(stamp, &slip, &mu, &used, latency))
    }

    /// Forget vehicle `j`'s pairs (a restarted chain).
    fn reset(&mut self, j: usize) -> PyResult<()> {
        let j = self.vehicle(j)?;
        self.learners[j].reset();
        Ok(())
    }

    /// Vehicle `j`'s current soil index in its drive: the changes of soil detected so far.
    fn changes(&self, j: usize) -> PyResult<usize> {
        Ok(self.learners[self.vehicle(j)?].changes())
    }

    fn __len__(&self) -> usize {
        self.learners.len()
    }
}
