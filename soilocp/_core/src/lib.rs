//! soilocp's compiled core: the per-sample equations, each written once, for one vehicle or a
//! bank of N.  The kernels (`constants`, `traction`, `ocp`, `normal_force`, `observer`, `soil`) are plain Rust over
//! f64; `py` binds them to Python as `soilocp._core` (arrays in, arrays out, one call per step).
//! Nothing here imports the Python package above it.

pub mod codes;
pub mod constants;
pub mod curve;
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

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<constants::Constants>()?;
    m.add_function(wrap_pyfunction!(py::codes::status_codes, m)?)?;
    m.add_function(wrap_pyfunction!(py::codes::reason_codes, m)?)?;
    m.add_function(wrap_pyfunction!(py::settings::settings_schema, m)?)?;
    m.add_class::<py::normal_force::NormalForceSolver>()?;
    m.add_function(wrap_pyfunction!(py::traction::traction_curve, m)?)?;
    m.add_function(wrap_pyfunction!(py::traction::traction_value, m)?)?;
    m.add_function(wrap_pyfunction!(py::traction::tractive_efficiency, m)?)?;
    m.add_function(wrap_pyfunction!(py::ocp::ocp_bank, m)?)?;
    m.add_function(wrap_pyfunction!(py::ocp::ocp_one, m)?)?;
    // the soil-grid update
    m.add_class::<py::soil::SoilGridBank>()?;
    // the slip gate, eq. 1 and the wheels' usability codes
    m.add_class::<py::soil::SlipGateBank>()?;
    m.add_function(wrap_pyfunction!(py::soil::soil_classes, m)?)?;
    m.add_function(wrap_pyfunction!(py::slip::slip_ratio, m)?)?;
    m.add_function(wrap_pyfunction!(py::slip::travel_slip, m)?)?;
    m.add_function(wrap_pyfunction!(py::slip::wheel_usability, m)?)?;
    // the observer: its filter bank
    m.add_class::<py::observer::ObserverCore>()?;
    // the torque scale: its bank, eq. TC and eq. 20 for the offline fit
    m.add_class::<py::torque_scale::TorqueScaleCore>()?;
    m.add_function(wrap_pyfunction!(py::torque_scale::longitudinal_balance, m)?)?;
    m.add_function(wrap_pyfunction!(py::torque_scale::modelled_resistance, m)?)?;
    m.add_function(wrap_pyfunction!(py::normal_force::gravity_from_attitude, m)?)?;
    // the whole chain of a bank in one call per step: the offline path, the batched service
    m.add_class::<py::chain::ChainCore>()?;
    // the wheel's own traction curve, learnt where the drive shows it
    m.add_class::<py::curve::CurveBank>()?;
    m.add_class::<curve::Fit>()?;
    Ok(())
}
