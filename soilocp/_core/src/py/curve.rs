//! `soilocp._core.CurveBank`: the wheel-curve learners of N vehicles (crate::curve), one call per
//! sample of one vehicle.  Floats in and out: the OCP publisher, which runs it, loads no numpy.

use std::collections::HashMap;

use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;

use crate::curve::{CurveLearner, Fit, Params};

/// A learnt shape mu(S) = a (1 - e^(-c3 S)) - c - b S on the current soil and its OCPs (crate::curve::Fit).
#[pyclass(frozen, get_all, module = "soilocp._core")]
#[derive(Clone, Copy)]
pub struct CurveFit {
    pub a: f64,
    pub c3: f64,
    pub b: f64,
    pub c: f64,
    /// slip of maximum net traction and its 1-sigma
    pub s_t: f64,
    pub s_t_std: f64,
    /// maximum net traction coefficient and its 1-sigma
    pub mu_t: f64,
    pub mu_t_std: f64,
    /// pairs fitted, pairs within peak_span below and above S_T, the largest |S| fitted, rms of the residuals
    pub pairs: usize,
    pub below: usize,
    pub beyond: usize,
    pub slip_top: f64,
    pub rms: f64,
    /// the peak lies inside the fitted slips, not extrapolated
    pub shown: bool,
    /// stamp of the fit, s
    pub stamp: f64,
}

impl From<Fit> for CurveFit {
    fn from(f: Fit) -> Self {
        CurveFit {
            a: f.a,
            c3: f.c3,
            b: f.b,
            c: f.c,
            s_t: f.s_t,
            s_t_std: f.s_t_std,
            mu_t: f.mu_t,
            mu_t_std: f.mu_t_std,
            pairs: f.pairs,
            below: f.below,
            beyond: f.beyond,
            slip_top: f.slip_top,
            rms: f.rms,
            shown: f.shown,
            stamp: f.stamp,
        }
    }
}

/// The wheel-curve learners of N vehicles (docs/method.md §19).
#[pyclass(module = "soilocp._core")]
pub struct CurveBank {
    learners: Vec<CurveLearner>,
}

#[pymethods]
impl CurveBank {
    /// N learners with the curve `settings` (by the names of crate::curve::Params; a missing one
    /// takes its default).
    #[new]
    fn new(n_vehicles: usize, settings: HashMap<String, f64>) -> PyResult<Self> {
        let params = Params::from_map(&settings).map_err(PyValueError::new_err)?;
        if params.slip_max <= params.slip_min {
            return Err(PyValueError::new_err(format!(
                "curve settings: slip_max = {} must exceed slip_min = {}",
                params.slip_max, params.slip_min
            )));
        }
        Ok(CurveBank {
            learners: vec![CurveLearner::new(params); n_vehicles],
        })
    }

    /// Vehicle `j`'s sample: stamp (s), slips (4,), net traction (4,), which wheels inform (4,).
    /// Returns the current soil's fit, or None while it has too few pairs or shows no peak.
    fn step(
        &mut self,
        j: usize,
        stamp: f64,
        slip: [f64; 4],
        mu: [f64; 4],
        used: [bool; 4],
    ) -> PyResult<Option<CurveFit>> {
        let n = self.learners.len();
        let learner = self
            .learners
            .get_mut(j)
            .ok_or_else(|| PyIndexError::new_err(format!("vehicle index {j} out of [0, {n})")))?;
        Ok(learner.step(stamp, &slip, &mu, &used).map(CurveFit::from))
    }

    /// Forget vehicle `j`'s pairs (a restarted chain).
    fn reset(&mut self, j: usize) -> PyResult<()> {
        let n = self.learners.len();
        self.learners
            .get_mut(j)
            .ok_or_else(|| PyIndexError::new_err(format!("vehicle index {j} out of [0, {n})")))?
            .reset();
        Ok(())
    }

    /// Vehicle `j`'s current soil index in its drive: the changes of soil detected so far.
    fn changes(&self, j: usize) -> PyResult<usize> {
        let n = self.learners.len();
        Ok(self
            .learners
            .get(j)
            .ok_or_else(|| PyIndexError::new_err(format!("vehicle index {j} out of [0, {n})")))?
            .changes())
    }

    fn __len__(&self) -> usize {
        self.learners.len()
    }
}
