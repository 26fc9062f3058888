//! `soilocp._core.ObserverCore`: the traction filters of N vehicles (`observer::bank`), stepped
//! for k of them in one call: arrays in, arrays out.  The Python bank
//! (soilocp.estimation.observer_bank.ObserverBank) runs the readings clock, the torque split, the
//! encoder lead and the ground-speed latency, and words the reset reasons from the codes.

use numpy::ndarray::{Array1, Array2, Array3, ArrayView1, ArrayView2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::observer::bank::{FilterBank, Sample, Settings, RESET_REASONS};
use crate::observer::layout::{Layout, N_MEAS};
use crate::observer::model::Vehicle;

#[pyclass(module = "soilocp._core")]
pub struct ObserverCore {
    inner: FilterBank,
}

fn fixed<const K: usize>(name: &str, v: &[f64]) -> PyResult<[f64; K]> {
    v.try_into()
        .map_err(|_| PyValueError::new_err(format!("{name} must have {K} entries, got {}", v.len())))
}

fn check_1d(name: &str, a: &ArrayView1<'_, f64>, k: usize) -> PyResult<()> {
    if a.len() != k {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape ({k},), got ({},)",
            a.len()
        )));
    }
    Ok(())
}

fn check_2d<T>(name: &str, a: &ArrayView2<'_, T>, k: usize, m: usize) -> PyResult<()> {
    if a.shape() != [k, m] {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape ({k}, {m}), got {:?}",
            a.shape()
        )));
    }
    Ok(())
}

type StepOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<u8>>,
);

#[pymethods]
impl ObserverCore {
    /// The filters of `n_vehicles` vehicles of one kind (`structure`: slip | shared | per_wheel |
    /// none).  `vehicle`: (mass, wheel_radius, wheel_inertia, yaw_inertia, a, b, c, d); `r`: the 7
    /// measurement variances; `q`, `p0`, `lower`, `upper`: per state; `speed_limits`: |omega_1..4|
    /// and |V| above which a state has diverged.
    #[new]
    #[pyo3(signature = (structure, n_vehicles, vehicle, wheel_y, gate_sigma, gate_patience, max_gap,
                        anchor_speed, variance_floor, variance_ceiling, travel_speed, bridge_slip,
                        gravity, r, q, p0, lower, upper, speed_limits))]
    #[allow(clippy::too_many_arguments)]
    fn py_new(
        structure: &str,
        n_vehicles: usize,
        vehicle: Vec<f64>,
        wheel_y: Vec<f64>,
        gate_sigma: f64,
        gate_patience: i64,
        max_gap: f64,
        anchor_speed: f64,
        variance_floor: f64,
        variance_ceiling: f64,
        travel_speed: f64,
        bridge_slip: f64,
        gravity: f64,
        r: Vec<f64>,
        q: Vec<f64>,
        p0: Vec<f64>,
        lower: Vec<f64>,
        upper: Vec<f64>,
        speed_limits: Vec<f64>,
    ) -> PyResult<Self> {
        let layout = Layout::of(structure).map_err(PyValueError::new_err)?;
        let [mass, wheel_radius, wheel_inertia, yaw_inertia, a, b, c, d] = fixed::<8>("vehicle", &vehicle)?;
        let vehicle = Vehicle {
            mass,
            wheel_radius,
            wheel_inertia,
            yaw_inertia,
            a,
            b,
            c,
            d,
            wheel_y: fixed::<4>("wheel_y", &wheel_y)?,
        };
        let settings = Settings {
            gate_sigma,
            gate_patience,
            max_gap,
            anchor_speed,
            variance_floor,
            variance_ceiling,
            travel_speed,
            bridge_slip,
            gravity,
            r: fixed::<N_MEAS>("r", &r)?,
            q,
            p0,
            lower,
            upper,
            speed_limits: fixed::<5>("speed_limits", &speed_limits)?,
        };
        let inner = FilterBank::new(layout, vehicle, settings, n_vehicles).map_err(PyValueError::new_err)?;
        Ok(ObserverCore { inner })
    }

    /// One step of the vehicles `idx` (k,), each at most once, in one call.  Per vehicle: dt (s
    /// since its last sample; NaN at its first), dt_cubed (dt**3 as numpy computes it), specific
    /// force x, yaw rate, pitch; (k, 4) raw wheel speeds, (k,) raw ground speed (NaN: none); (k, 4)
    /// wheel speeds as measured (reading + encoder lead), (k,) the led ground speed (NaN: none);
    /// (k, 4) torques and normal forces; (k, 5) bool: which wheel / ground speeds are new readings.
    /// Returns the (k, n) states, (k, 4) mu variances, resistances, gross tractions and their
    /// variances, (k,) rejected rows and (k,) reset codes (0: none, else reset_reasons[code - 1]).
    #[allow(clippy::too_many_arguments)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        idx: PyReadonlyArray1<'py, i64>,
        dt: PyReadonlyArray1<'py, f64>,
        dt_cubed: PyReadonlyArray1<'py, f64>,
        specific_force_x: PyReadonlyArray1<'py, f64>,
        yaw_rate: PyReadonlyArray1<'py, f64>,
        pitch: PyReadonlyArray1<'py, f64>,
        wheel_speed: PyReadonlyArray2<'py, f64>,
        ground_speed: PyReadonlyArray1<'py, f64>,
        wheel_speed_z: PyReadonlyArray2<'py, f64>,
        ground_speed_z: PyReadonlyArray1<'py, f64>,
        torque: PyReadonlyArray2<'py, f64>,
        normal_force: PyReadonlyArray2<'py, f64>,
        fresh: PyReadonlyArray2<'py, bool>,
    ) -> PyResult<StepOut<'py>> {
        let idx = idx.as_array();
        let k = idx.len();
        let n_veh = self.inner.n_vehicles;
        let mut seen = vec![false; n_veh];
        for &g in idx.iter() {
            if g < 0 || g as usize >= n_veh || seen[g as usize] {
                return Err(PyValueError::new_err(format!(
                    "idx must be distinct vehicle indices in [0, {n_veh}), got {idx}"
                )));
            }
            seen[g as usize] = true;
        }
        let (dt, dt3, fx, yaw, pitch, gs, gsz) = (
            dt.as_array(),
            dt_cubed.as_array(),
            specific_force_x.as_array(),
            yaw_rate.as_array(),
            pitch.as_array(),
            ground_speed.as_array(),
            ground_speed_z.as_array(),
        );
        for (name, a) in [
            ("dt", &dt),
            ("dt_cubed", &dt3),
            ("specific_force_x", &fx),
            ("yaw_rate", &yaw),
            ("pitch", &pitch),
            ("ground_speed", &gs),
            ("ground_speed_z", &gsz),
        ] {
            check_1d(name, a, k)?;
        }
        let (ws, wsz, tq, fz, fresh) = (
            wheel_speed.as_array(),
            wheel_speed_z.as_array(),
            torque.as_array(),
            normal_force.as_array(),
            fresh.as_array(),
        );
        for (name, a) in [
            ("wheel_speed", &ws),
            ("wheel_speed_z", &wsz),
            ("torque", &tq),
            ("normal_force", &fz),
        ] {
            check_2d(name, a, k, 4)?;
        }
        check_2d("fresh", &fresh, k, 5)?;
        let n = self.inner.layout.n();
        let mut x = Array2::<f64>::zeros((k, n));
        let mut mu_var = Array2::<f64>::zeros((k, 4));
        let mut res = Array2::<f64>::zeros((k, 4));
        let mut gross = Array2::<f64>::zeros((k, 4));
        let mut gross_var = Array2::<f64>::zeros((k, 4));
        let mut rejected = Array1::<i64>::zeros(k);
        let mut reset = Array1::<u8>::zeros(k);
        let row4 = |a: &ArrayView2<'_, f64>, j: usize| -> [f64; 4] { std::array::from_fn(|w| a[[j, w]]) };
        for j in 0..k {
            let g = idx[j] as usize;
            let s = Sample {
                dt: dt[j],
                dt_cubed: dt3[j],
                specific_force_x: fx[j],
                yaw_rate: yaw[j],
                pitch: pitch[j],
                wheel_speed: row4(&ws, j),
                ground_speed: gs[j],
                wheel_speed_z: row4(&wsz, j),
                ground_speed_z: gsz[j],
                torque: row4(&tq, j),
                normal_force: row4(&fz, j),
                fresh: std::array::from_fn(|w| fresh[[j, w]]),
            };
            let o = self.inner.step(g, &s);
            for (c, v) in self.inner.x[g * n..(g + 1) * n].iter().enumerate() {
                x[[j, c]] = *v;
            }
            for w in 0..4 {
                mu_var[[j, w]] = o.mu_var[w];
                res[[j, w]] = o.resistance[w];
                gross[[j, w]] = o.gross[w];
                gross_var[[j, w]] = o.gross_var[w];
            }
            rejected[j] = o.rejected;
            reset[j] = o.reset;
        }
        Ok((
            x.into_pyarray(py),
            mu_var.into_pyarray(py),
            res.into_pyarray(py),
            gross.into_pyarray(py),
            gross_var.into_pyarray(py),
            rejected.into_pyarray(py),
            reset.into_pyarray(py),
        ))
    }

    /// The states (N, n) (a copy).
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.inner.layout.n();
        Array2::from_shape_vec((self.inner.n_vehicles, n), self.inner.x.clone())
            .expect("N x n")
            .into_pyarray(py)
    }

    /// The covariances (N, n, n) (a copy).
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        let n = self.inner.layout.n();
        Array3::from_shape_vec((self.inner.n_vehicles, n, n), self.inner.p.clone())
            .expect("N x n x n")
            .into_pyarray(py)
    }

    /// Consecutive gate rejections of each measurement row (N, 7) (a copy).
    #[getter]
    fn rejections<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        Array2::from_shape_vec((self.inner.n_vehicles, N_MEAS), self.inner.rejections.clone())
            .expect("N x 7")
            .into_pyarray(py)
    }

    /// Resets so far, by reason (in reset_reasons' order).
    #[getter]
    fn resets(&self) -> Vec<u64> {
        self.inner.resets.to_vec()
    }

    /// Wheel-speed states re-anchored to their reading at low speed so far.
    #[getter]
    fn anchored(&self) -> u64 {
        self.inner.anchored
    }

    /// The reset reasons, code - 1 -> name.
    #[classattr]
    fn reset_reasons() -> Vec<&'static str> {
        RESET_REASONS.to_vec()
    }
}
