//! `soilocp._core.CurveBank`: the wheel-curve learners of N vehicles (crate::curve), one call per
//! sample of one vehicle.  Floats in and out: the OCP publisher, which runs it, loads no numpy.

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
    /// N learners with the settings of `soilocp.estimation.curve_config.CurveConfig`.
    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (n_vehicles, window, change_window, change_shift, change_pairs, slip_min, slip_max, min_pairs, min_beyond, peak_span, interval))]
    fn new(
        n_vehicles: usize,
        window: f64,
        change_window: f64,
        change_shift: f64,
        change_pairs: usize,
        slip_min: f64,
        slip_max: f64,
        min_pairs: usize,
        min_beyond: usize,
        peak_span: f64,
        interval: f64,
    ) -> PyResult<Self> {
        let checks = [
            ("window", window > 0.0),
            ("change_window", change_window > 0.0),
            ("change_shift", change_shift > 0.0),
            ("slip_min", slip_min >= 0.0),
            ("slip_max", slip_max > slip_min),
            ("interval", interval >= 0.0),
            ("peak_span", peak_span > 0.0),
        ];
        if let Some((name, _)) = checks.iter().find(|(_, ok)| !ok) {
            return Err(PyValueError::new_err(format!("curve setting {name} is out of range")));
        }
        let params = Params {
            window,
            change_window,
            change_shift,
            change_pairs,
            slip_min,
            slip_max,
            min_pairs,
            min_beyond,
            peak_span,
            interval,
        };
        Ok(CurveBank {
            learners: vec![CurveLearner::new(params); n_vehicles],
        })
    }

    /// Vehicle `j`'s sample: stamp (s), slips (4,), net traction (4,), which wheels inform (4,).
    /// Returns the current soil's fit, or None while it has too few pairs or shows no peak.
    fn step(&mut self, j: usize, stamp: f64, slip: [f64; 4], mu: [f64; 4], used: [bool; 4]) -> PyResult<Option<Fit>> {
        let j = self.vehicle(j)?;
        Ok(self.learners[j].step(stamp, &slip, &mu, &used))
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
