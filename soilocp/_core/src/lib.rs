//! soilocp's compiled core: the per-sample equations, each written once, for one vehicle or a
//! bank of N.  The kernels (`constants`, `traction`, `ocp`, `normal_force`, `observer`, `soil`) are plain Rust over
//! f64; `py` binds them to Python as `soilocp._core` (arrays in, arrays out, one call per step).
//! Nothing here imports the Python package above it.

pub mod codes;
pub mod constants;
pub mod curve;
pub mod index;
pub mod normal_force;
pub mod observer;
pub mod ocp;
pub mod py;
pub mod settings;
pub mod slip;
pub mod soil;
#[cfg(test)]
mod testing;
pub mod torque_scale;
pub mod traction;

use pyo3::prelude::*;

/// Add each listed item to the module `m`: `class` for a `#[pyclass]`, `fn` for a `#[pyfunction]`,
/// each path written once.
macro_rules! register {
    ($m:ident; $($kind:ident $path:path),+ $(,)?) => {
        $(register!(@one $m, $kind, $path);)+
    };
    (@one $m:ident, class, $path:path) => {
        $m.add_class::<$path>()?
    };
    (@one $m:ident, fn, $path:path) => {
        $m.add_function(wrap_pyfunction!($path, $m)?)?
    };
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    register! {m;
        class constants::Constants,
        fn py::codes::status_codes,
        fn py::codes::reason_codes,
        fn py::settings::settings_schema,
        class py::normal_force::NormalForceSolver,
        fn py::traction::traction_curve,
        fn py::traction::traction_value,
        fn py::traction::tractive_efficiency,
        fn py::ocp::ocp_bank,
        fn py::ocp::ocp_one,
        fn py::ocp::ocp_band,
        // the soil-grid update
        class py::soil::SoilGridBank,
        // the slip gate (with the wheels' usability codes) and eq. 1
        class py::soil::SlipGateBank,
        fn py::soil::soil_classes,
        fn py::slip::slip_ratio,
        // the observer: its filter bank
        class py::observer::ObserverCore,
        fn py::observer::observer_layout,
        // the torque scale: its bank, eq. TC and eq. 20 for the offline fit
        class py::torque_scale::TorqueScaleCore,
        fn py::torque_scale::longitudinal_balance,
        fn py::torque_scale::modelled_resistance,
        fn py::normal_force::gravity_from_attitude,
        // the whole chain of a bank in one call per step: the offline path, the batched service
        class py::chain::ChainCore,
        // the wheel's own traction curve, learnt where the drive shows it
        class py::curve::CurveBank,
        class curve::Fit,
    }
    Ok(())
}
