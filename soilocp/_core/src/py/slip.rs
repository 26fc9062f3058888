//! `soilocp._core.slip_ratio`: eq. 1 (crate::slip) over arrays, for soilocp.model.slip's functions
//! and their callers off the soil stage (the control loop, the simulator's checks).

use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use crate::slip;

use super::args::{map_broadcast, part};

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

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
    Ok((
        part(&pairs, |p| p.0).into_pyarray(py),
        part(&pairs, |p| p.1).into_pyarray(py),
    ))
}
