//! `soilocp._core.slip_ratio` / `travel_slip` / `wheel_usability`: eq. 1 (crate::slip) and the
//! wheels' usability codes (crate::soil::usability) over arrays, for the Python functions of the
//! same names (soilocp.model.slip, soilocp.estimation.wheel_usability) and their callers off the
//! soil stage (the control loop, the torque scale, the simulator's checks).

use numpy::ndarray::{Array2, ArrayD};
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::collections::HashMap;

use crate::slip;
use crate::soil::usability::{self, Limits};

use super::args::{map_broadcast, part, quads};

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

/// The unusable code (k, 4) per wheel (docs/method.md §17, crate::soil::usability::codes) from the
/// travel-frame slip, rim speeds and ground speeds under the wheels (k, 4), the body's ground speed
/// and yaw rate (k,), the gross traction (k, 4), the half-track (m), the usability `limits` (by the
/// names of crate::soil::usability::Limits; a missing one takes its default) and the slip `deadband` (m/s).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
pub fn wheel_usability<'py>(
    py: Python<'py>,
    slip: PyReadonlyArray2<'py, f64>,
    rim: PyReadonlyArray2<'py, f64>,
    ground: PyReadonlyArray2<'py, f64>,
    body_speed: PyReadonlyArray1<'py, f64>,
    yaw_rate: PyReadonlyArray1<'py, f64>,
    gross: PyReadonlyArray2<'py, f64>,
    half_track: f64,
    limits: HashMap<String, f64>,
    deadband: f64,
) -> PyResult<Bound<'py, PyArray2<i8>>> {
    let k = slip.as_array().nrows();
    let (s, r, g, gr) = (
        quads("slip", &slip, k)?,
        quads("rim", &rim, k)?,
        quads("ground", &ground, k)?,
        quads("gross", &gross, k)?,
    );
    let (v, y) = (body_speed.as_array(), yaw_rate.as_array());
    if v.len() != k || y.len() != k {
        return Err(PyValueError::new_err(format!(
            "body_speed and yaw_rate must have shape ({k},), got ({},) and ({},)",
            v.len(),
            y.len()
        )));
    }
    let lim = Limits::from_map(&limits).map_err(PyValueError::new_err)?;
    let mut out = Array2::<i8>::zeros((k, 4));
    for j in 0..k {
        let c = usability::codes(&s[j], &r[j], &g[j], v[j], y[j], &gr[j], half_track, &lim, deadband);
        for w in 0..4 {
            out[[j, w]] = c[w];
        }
    }
    Ok(out.into_pyarray(py))
}
