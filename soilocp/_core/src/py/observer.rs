//! `soilocp._core.ObserverCore`: the whole observer step of N vehicles (`observer::vehicles`),
//! for k of them in one call: the logged samples in, every output array out.  The Python bank
//! (soilocp.estimation.observer_bank.ObserverBank) words the reset reasons from the codes and
//! wraps the arrays in its dataclass.

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use std::collections::HashMap;

use super::args;
use crate::observer::bank::{FilterBank, Settings as FilterSettings, RESET_REASONS};
use crate::observer::intervals::IntervalSettings;
use crate::observer::layout::{Layout, N_MEAS};
use crate::observer::model::{build, init, resistance_map, Vehicle};
use crate::observer::settings::ObserverSettings;
use crate::observer::vehicles::{
    Estimate, ObserverBank, Raw, Reading, BOOL_FLAT_NAMES, BOOL_QUAD_NAMES, FLAT_NAMES, LIFT_OFF_FORCE, QUAD_NAMES,
};
use crate::settings::Value;

/// One step's samples of k vehicles, read by attribute from
/// soilocp.estimation.observer_bank.ObserverInputs: (k,) stamp, specific force x, yaw rate, pitch,
/// ground speed (NaN: none); (k, 4) wheel speeds, wheel torques (as logged) and normal forces.
/// The observer's clock (dt, dt^3, the latency fit's exponentials) is the core's own.
#[derive(FromPyObject)]
pub(crate) struct Inputs<'py> {
    stamp: PyReadonlyArray1<'py, f64>,
    specific_force_x: PyReadonlyArray1<'py, f64>,
    yaw_rate: PyReadonlyArray1<'py, f64>,
    pitch: PyReadonlyArray1<'py, f64>,
    wheel_speed: PyReadonlyArray2<'py, f64>,
    wheel_torque: PyReadonlyArray2<'py, f64>,
    ground_speed: PyReadonlyArray1<'py, f64>,
    normal_force: PyReadonlyArray2<'py, f64>,
}

#[pyclass(module = "soilocp._core")]
pub struct ObserverCore {
    inner: ObserverBank,
}

fn fixed<const K: usize>(name: &str, v: &[f64]) -> PyResult<[f64; K]> {
    v.try_into()
        .map_err(|_| PyValueError::new_err(format!("{name} must have {K} entries, got {}", v.len())))
}

pub(crate) type StepOut<'py> = (
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray3<bool>>,
    Bound<'py, PyArray2<bool>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<u8>>,
);

type Model<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
);

/// Vehicle `j`'s column of a per-wheel block (block row, vehicle, wheel) and of a per-vehicle one.
fn put_vehicle<T: Copy>(quads: &mut Array3<T>, flats: &mut Array2<T>, j: usize, q: &[[T; 4]], f: &[T]) {
    for (r, row) in q.iter().enumerate() {
        for (w, &v) in row.iter().enumerate() {
            quads[[r, j, w]] = v;
        }
    }
    for (r, &v) in f.iter().enumerate() {
        flats[[r, j]] = v;
    }
}

/// The step's output blocks (module doc of `step`) of the vehicles' estimates, in their order.
pub(crate) fn blocks<'py>(py: Python<'py>, out: &[Estimate]) -> StepOut<'py> {
    let k = out.len();
    let mut quads = Array3::<f64>::zeros((QUAD_NAMES.len(), k, 4));
    let mut flats = Array2::<f64>::zeros((FLAT_NAMES.len(), k));
    let mut bquads = Array3::<bool>::from_elem((BOOL_QUAD_NAMES.len(), k, 4), false);
    let mut bflats = Array2::<bool>::from_elem((BOOL_FLAT_NAMES.len(), k), false);
    let mut rejected = Array1::<i64>::zeros(k);
    let mut codes = Array1::<u8>::zeros(k);
    for (j, o) in out.iter().enumerate() {
        put_vehicle(&mut quads, &mut flats, j, &o.quads(), &o.flats());
        put_vehicle(&mut bquads, &mut bflats, j, &o.bool_quads(), &o.bool_flats());
        rejected[j] = o.rejected;
        codes[j] = o.reset;
    }
    (
        quads.into_pyarray(py),
        flats.into_pyarray(py),
        bquads.into_pyarray(py),
        bflats.into_pyarray(py),
        rejected.into_pyarray(py),
        codes.into_pyarray(py),
    )
}

impl Inputs<'_> {
    /// A step's vehicles of a bank of `n_vehicles` (`idx`, None: all in order; distinct, in range)
    /// and their samples, every input checked (shape, finite; ValueError naming the field) before
    /// any vehicle's state changes.
    pub(crate) fn raws(
        &self,
        idx: Option<&PyReadonlyArray1<'_, i64>>,
        n_vehicles: usize,
    ) -> PyResult<(Vec<usize>, Vec<Raw>)> {
        let stamp = self.stamp.as_array();
        let k = stamp.len();
        let vehicles = args::vehicles(idx, n_vehicles)?;
        let (fx, yaw, pitch, gs) = (
            self.specific_force_x.as_array(),
            self.yaw_rate.as_array(),
            self.pitch.as_array(),
            self.ground_speed.as_array(),
        );
        args::check_finite_column("stamp", &stamp, k, false)?;
        args::check_finite_column("specific_force_x", &fx, k, false)?;
        args::check_finite_column("yaw_rate", &yaw, k, false)?;
        args::check_finite_column("pitch", &pitch, k, false)?;
        args::check_finite_column("ground_speed", &gs, k, true)?;
        let (ws, tq, fz) = (
            self.wheel_speed.as_array(),
            self.wheel_torque.as_array(),
            self.normal_force.as_array(),
        );
        args::check_finite_quads("wheel_speed", &ws, k)?;
        args::check_finite_quads("wheel_torque", &tq, k)?;
        args::check_finite_quads("normal_force", &fz, k)?;
        // after the fields, which are checked against the stamp's length: a field of another length is named
        if k != vehicles.len() {
            return Err(PyValueError::new_err(format!(
                "inputs hold {k} samples for {} vehicle indices",
                vehicles.len()
            )));
        }
        let raws = (0..k)
            .map(|j| Raw {
                stamp: stamp[j],
                specific_force_x: fx[j],
                yaw_rate: yaw[j],
                pitch: pitch[j],
                wheel_speed: args::row(&ws, j),
                wheel_torque: args::row(&tq, j),
                ground_speed: gs[j],
                normal_force: args::row(&fz, j),
            })
            .collect();
        Ok((vehicles, raws))
    }
}

impl ObserverCore {
    /// The bank inside (the chain, crate::py::chain, steps it with the other stages).
    pub(crate) fn bank_mut(&mut self) -> &mut ObserverBank {
        &mut self.inner
    }

    /// A step's vehicles (`idx`, None: all in order) and their samples, checked ([`Inputs::raws`]).
    pub(crate) fn raws(
        &self,
        idx: Option<&PyReadonlyArray1<'_, i64>>,
        inputs: &Inputs<'_>,
    ) -> PyResult<(Vec<usize>, Vec<Raw>)> {
        inputs.raws(idx, self.inner.filter.n_vehicles)
    }
}

#[pymethods]
impl ObserverCore {
    /// The observers of `n_vehicles` vehicles of one kind.  `vehicle`: (mass, wheel_radius,
    /// wheel_inertia, yaw_inertia, a, b, c, d); `wheel_y`: the wheels' lateral positions;
    /// `settings`: the observer's settings by name (crate::observer::settings, ObserverConfig's
    /// fields; a missing one at its default, an unknown or invalid one a ValueError naming it);
    /// `per_side` / `interval_mean`: the vehicle's drive and encoder reading; `bridge_slip`: the
    /// traction model's zero-slip bridge.
    #[new]
    #[pyo3(signature = (n_vehicles, vehicle, wheel_y, settings, *, per_side, interval_mean, bridge_slip))]
    fn py_new(
        n_vehicles: usize,
        vehicle: Vec<f64>,
        wheel_y: Vec<f64>,
        settings: HashMap<String, Value>,
        per_side: bool,
        interval_mean: bool,
        bridge_slip: f64,
    ) -> PyResult<Self> {
        let s = ObserverSettings::from_map(&settings).map_err(PyValueError::new_err)?;
        let layout = s.layout();
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
        let filter_settings = FilterSettings::of(&s, &layout, per_side, bridge_slip).map_err(PyValueError::new_err)?;
        let filter = FilterBank::new(layout, vehicle, filter_settings, n_vehicles).map_err(PyValueError::new_err)?;
        Ok(ObserverCore {
            inner: ObserverBank::new(
                filter,
                Reading::of(&s, per_side, interval_mean),
                IntervalSettings::of(&s, wheel_inertia, wheel_radius),
            ),
        })
    }

    /// One observer step of the vehicles `idx` (k,; each at most once; None: all N, in order), in
    /// one call, on their samples `inputs` ([`Inputs`]: ObserverInputs).
    /// Returns the blocks (17, k, 4) and (4, k) of floats, (3, k, 4) and (2, k) of bools (named by
    /// quad_fields, flat_fields, bool_quad_fields, bool_flat_fields), the (k,) rejected rows and
    /// the (k,) reset codes (0: none, else reset_reasons[code - 1]).  Every input is checked (shape,
    /// finite; ValueError naming the field) before any vehicle's state changes.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        idx: Option<PyReadonlyArray1<'py, i64>>,
        inputs: Inputs<'py>,
    ) -> PyResult<StepOut<'py>> {
        let (vehicles, raws) = self.raws(idx.as_ref(), &inputs)?;
        let out: Vec<Estimate> = vehicles
            .iter()
            .zip(&raws)
            .map(|(&g, r)| self.inner.step(g, r))
            .collect();
        Ok(blocks(py, &out))
    }

    /// A (n, n), b (n), H (7, n) of eq. 33 (the core's `observer::model`) at the state `x` (n,)
    /// (its resistance map), normal forces `fz` (4,; N), wheel torques (4,; N m) and pitch (rad).
    fn model<'py>(
        &self,
        py: Python<'py>,
        x: Vec<f64>,
        fz: Vec<f64>,
        torque: Vec<f64>,
        pitch: f64,
    ) -> PyResult<Model<'py>> {
        let f = &self.inner.filter;
        let (l, n) = (f.layout, f.layout.n());
        if x.len() != n {
            return Err(PyValueError::new_err(format!(
                "x must have {n} entries, got {}",
                x.len()
            )));
        }
        let (fz, torque) = (fixed::<4>("fz", &fz)?, fixed::<4>("torque", &torque)?);
        let (mut a, mut b, mut h) = (vec![0.0; n * n], vec![0.0; n], vec![0.0; N_MEAS * n]);
        let mut m = [0.0; 16];
        init(&l, &mut a, &mut b, &mut h);
        resistance_map(
            &l,
            &f.vehicle,
            &x,
            f.settings.s.travel_speed,
            f.settings.bridge_slip,
            &mut m,
        );
        build(
            &l,
            &f.vehicle,
            &fz,
            &torque,
            f.settings.s.gravity * pitch.sin(),
            &m,
            &mut a,
            &mut b,
            &mut h,
        );
        Ok((
            Array2::from_shape_vec((n, n), a).expect("n x n").into_pyarray(py),
            Array1::from_vec(b).into_pyarray(py),
            Array2::from_shape_vec((N_MEAS, n), h).expect("7 x n").into_pyarray(py),
        ))
    }

    /// The names of the rows of the step's four output blocks, in order: floats per wheel, floats per
    /// vehicle, bools per wheel, bools per vehicle.
    #[classattr]
    fn block_fields() -> [Vec<&'static str>; 4] {
        [
            QUAD_NAMES.to_vec(),
            FLAT_NAMES.to_vec(),
            BOOL_QUAD_NAMES.to_vec(),
            BOOL_FLAT_NAMES.to_vec(),
        ]
    }

    /// N: below this normal force a wheel is lifted off (its force is clamped to it).
    #[classattr]
    fn lift_off_force() -> f64 {
        LIFT_OFF_FORCE
    }

    /// Each vehicle's last stamp (N,) (NaN: none yet), as the core's clock has it (a copy): the Python
    /// bank's mirror of it is set from here when a step that moved the clock raised.
    #[getter]
    fn last_stamp<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.last_stamp.clone().into_pyarray(py)
    }

    /// The states (N, n) (a copy).
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.inner.filter.layout.n();
        Array2::from_shape_vec((self.inner.filter.n_vehicles, n), self.inner.filter.x.clone())
            .expect("N x n")
            .into_pyarray(py)
    }

    /// The covariances (N, n, n) (a copy).
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        let n = self.inner.filter.layout.n();
        Array3::from_shape_vec((self.inner.filter.n_vehicles, n, n), self.inner.filter.p.clone())
            .expect("N x n x n")
            .into_pyarray(py)
    }

    /// Consecutive gate rejections of each measurement row (N, 7) (a copy).
    #[getter]
    fn rejections<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        Array2::from_shape_vec(
            (self.inner.filter.n_vehicles, N_MEAS),
            self.inner.filter.rejections.clone(),
        )
        .expect("N x 7")
        .into_pyarray(py)
    }

    /// Resets so far, by reason (in reset_reasons' order).
    #[getter]
    fn resets(&self) -> Vec<u64> {
        self.inner.filter.resets.to_vec()
    }

    /// Wheel-speed states re-anchored to their reading at low speed so far.
    #[getter]
    fn anchored(&self) -> u64 {
        self.inner.filter.anchored
    }

    /// The reset reasons, code - 1 -> name.
    #[classattr]
    fn reset_reasons() -> Vec<&'static str> {
        RESET_REASONS.to_vec()
    }
}

/// The observer's state layout of `structure` (crate::observer::layout, its one definition): the
/// first index and the length of each block (mu, res, lat, omega: 4 each or the structure's count;
/// v, psi, bias: one each), and n, the state's size.
#[pyfunction]
pub fn observer_layout(structure: &str) -> PyResult<Vec<(&'static str, usize, usize)>> {
    let l = Layout::of(structure).map_err(PyValueError::new_err)?;
    Ok(vec![
        ("mu", Layout::MU, 4),
        ("res", l.res(), l.n_res),
        ("lat", l.lat(), l.n_lat),
        ("omega", l.omega(), 4),
        ("v", l.v(), 1),
        ("psi", l.psi(), 1),
        ("bias", l.bias(), 1),
        ("n", 0, l.n()),
    ])
}
