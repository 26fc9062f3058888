//! `soilocp._core.slip_ratio` / `travel_slip`: eq. 1 (crate::slip) over arrays, for the Python
//! functions of the same names (soilocp.model.slip, soilocp.estimation.wheel_usability) and their
//! callers off the soil stage (the control loop, the torque scale, the simulator's checks).

use numpy::ndarray::ArrayD;
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use crate::slip;

use super::args::{map_broadcast, part};

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

/// The two halves of an array of pairs, as two C-ordered arrays of its shape.
fn unzip<'py>(py: Python<'py>, pairs: ArrayD<(f64, f64)>) -> (Arr<'py>, Arr<'py>) {
    (
        part(&pairs, |p| p.0).into_pyarray(py),
        part(&pairs, |p| p.1).into_pyarray(py),
    )
}

/// Eq. 1 with the floor of docs/method.md §10 (crate::slip::slip) from wheel speeds omega (rad/s),
/// the ground speeds V (m/s; the two broadcast) and the wheel radius R_w (m): (S, max(|R_w omega|,
/// |V|)), the second the measure of §6's deadband.
#[pyfunction]
pub fn slip_ratio<'py>(
    py: Python<'py>,
    wheel_speed: PyReadonlyArrayDyn<'py, f64>,
    ground_speed: PyReadonlyArrayDyn<'py, f64>,
    wheel_radius: f64,
    floor: f64,
) -> PyResult<(Arr<'py>, Arr<'py>)> {
    let pairs = map_broadcast(("wheel_speed", "ground_speed"), &wheel_speed, &ground_speed, |w, v| {
        let rim = w * wheel_radius;
        (slip::slip(rim, v, floor), slip::scale(rim, v))
    })?;
    Ok(unzip(py, pairs))
}

/// Eq. 1 in each wheel's direction of travel (docs/method.md §17, crate::slip::travel_slip) from rim
/// speeds R_w omega and the ground speeds under the wheels (m/s; the two broadcast): (d S, d).
#[pyfunction]
pub fn travel_slip<'py>(
    py: Python<'py>,
    rim: PyReadonlyArrayDyn<'py, f64>,
    ground: PyReadonlyArrayDyn<'py, f64>,
    floor: f64,
) -> PyResult<(Arr<'py>, Arr<'py>)> {
    let pairs = map_broadcast(("rim", "ground"), &rim, &ground, |r, g| slip::travel_slip(r, g, floor))?;
    Ok(unzip(py, pairs))
}
