//! The model constants of the traction law (paper §2.2), the S_E line (eq. 10) and the zero-slip
//! bridge (docs/method.md §8).  [`Constants::PAPER`] is the one definition of their defaults:
//! `soilocp.model.constants.ModelConstants` (the validated, documented configuration a calibration
//! replaces) reads them from `soilocp._core.Constants.PAPER` and builds this struct from its own.

use pyo3::prelude::*;
use pyo3::types::PyType;

/// C1..C6 of eqs. 3-6, alpha and beta of eq. 10, and the half-width of the linear bridge
/// through S = 0 (docs/method.md §8).  Built once per `ModelConstants` by the Python side.
#[pyclass(frozen, get_all, module = "soilocp._core")]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Constants {
    pub c1: f64,
    pub c2: f64,
    pub c3: f64,
    pub c4: f64,
    pub c5: f64,
    pub c6: f64,
    pub alpha: f64,
    pub beta: f64,
    pub bridge_slip: f64,
}

impl Constants {
    /// The paper's constants (§2.2; the bridge: docs/method.md §8), the defaults of
    /// `ModelConstants` and of the Rust tests.
    pub const PAPER: Constants = Constants {
        c1: 1.3,
        c2: 0.01,
        c3: 7.058,
        c4: 0.04,
        c5: -5.0,
        c6: 4.0,
        alpha: 677.4,
        beta: -5242.9,
        bridge_slip: 0.005,
    };
}

#[pymethods]
impl Constants {
    /// The paper's constants ([`Constants::PAPER`]): `ModelConstants`' defaults.
    #[classattr]
    #[pyo3(name = "PAPER")]
    fn paper() -> Constants {
        Constants::PAPER
    }

    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (c1, c2, c3, c4, c5, c6, alpha, beta, bridge_slip))]
    fn py_new(c1: f64, c2: f64, c3: f64, c4: f64, c5: f64, c6: f64, alpha: f64, beta: f64, bridge_slip: f64) -> Self {
        Constants {
            c1,
            c2,
            c3,
            c4,
            c5,
            c6,
            alpha,
            beta,
            bridge_slip,
        }
    }

    /// Pickle / deepcopy support: configs travel to worker processes with their constants.
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> (Bound<'py, PyType>, (f64, f64, f64, f64, f64, f64, f64, f64, f64)) {
        let c = slf.get();
        (
            slf.get_type(),
            (c.c1, c.c2, c.c3, c.c4, c.c5, c.c6, c.alpha, c.beta, c.bridge_slip),
        )
    }

    fn __repr__(&self) -> String {
        format!("{self:?}")
    }
}
