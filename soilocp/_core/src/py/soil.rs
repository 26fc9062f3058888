//! `soilocp._core.SoilGridBank`: N vehicles' ln K grid beliefs (crate::soil), one call per step for
//! k selected vehicles, arrays in and arrays / codes out: the records' status and reason codes are
//! made in crate::soil::status; Python (soilocp.estimation.soil_strength) words them.

use std::collections::HashMap;

use super::args::{column, quads, to_column, to_rows, to_rows_of, vehicles};

use numpy::ndarray::{Array1, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::codes::{self, Code, SetBy};
use crate::constants::Constants;
use crate::soil::bank::{self, Sample};
use crate::soil::gate::{self, GateParams};
use crate::soil::grid::Grid;
use crate::soil::params::Params;
use crate::soil::scale::ScaleNodes;
use crate::soil::status::{Report, StatusBank};
use crate::soil::usability::{self, Limits};
use crate::traction::Kind;

/// What `SoilGridBank.step` returns, per selected vehicle (k rows): wheel flags (k, 4) uint8
/// (1 used, 2 gated but undetermined, 4 gated but held), dt (k,), informed (k,), taken (k,),
/// k_report (k,), log_stat (k,), stats (k, 5), scale (k, 3), axle_mismatch (k,), axle (k, 3)
/// (z, ln K front, ln K rear), floor_cdf (k,).
type StepArrays<'py> = (
    Bound<'py, PyArray2<u8>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
);

/// What the slip gate returns, a tuple of soilocp.estimation.soil_state.SoilInputs' fields in order:
/// slip, informative, observed, variance, slip_sigma, gate_slip, gate_sigma, held (k, 4);
/// ground_stale, identifiable, speed (k,); span (k, 4) and slip_ends (k, 4, 2) where any vehicle of
/// the step refreshes a wheel, else None; unusable codes (k, 4).
pub(crate) type GateArrays<'py> = Bound<'py, PyTuple>;

pub(crate) fn gate_arrays<'py>(py: Python<'py>, s: &[Sample]) -> PyResult<GateArrays<'py>> {
    let k = s.len();
    let f = |get: fn(&Sample) -> [f64; 4]| to_rows(py, s.iter().map(get));
    let b = |get: fn(&Sample) -> [bool; 4]| to_rows(py, s.iter().map(get));
    let any_span = s.first().is_some_and(|x| x.span.is_some());
    let items: [Bound<'py, PyAny>; 14] = [
        f(|x| x.slip).into_any(),
        b(|x| x.informative).into_any(),
        f(|x| x.observed).into_any(),
        f(|x| x.variance).into_any(),
        f(|x| x.slip_sigma).into_any(),
        f(|x| x.gate_slip).into_any(),
        f(|x| x.gate_sigma).into_any(),
        b(|x| x.held).into_any(),
        to_column(py, s.iter().map(|x| x.ground_stale)).into_any(),
        to_column(py, s.iter().map(|x| x.identifiable)).into_any(),
        to_column(py, s.iter().map(|x| x.speed)).into_any(),
        if any_span {
            f(|x| x.span.unwrap_or([0.0; 4])).into_any()
        } else {
            py.None().into_bound(py)
        },
        if any_span {
            Array3::from_shape_fn((k, 4, 2), |(j, w, e)| s[j].slip_ends.map_or(0.0, |v| v[w][e]))
                .into_pyarray(py)
                .into_any()
        } else {
            py.None().into_bound(py)
        },
        to_rows(py, s.iter().map(|x| x.unusable)).into_any(),
    ];
    PyTuple::new(py, items)
}

/// The slip gate of N vehicles (docs/method.md §6, §9, §10, §17; crate::soil::gate): its low-pass
/// slip is the state.
#[pyclass(module = "soilocp._core")]
pub struct SlipGateBank {
    pub(crate) inner: gate::SlipGateBank,
}

impl SlipGateBank {
    /// The step of the vehicles `idx` at `stamp` from their packed observer outputs `rows`: the
    /// samples, and a [`PendingGate`] to commit once the caller has accepted them.
    pub(crate) fn run(
        &self,
        idx: &PyReadonlyArray1<'_, i64>,
        stamp: &PyReadonlyArray1<'_, f64>,
        rows: &Bound<'_, PyAny>,
    ) -> PyResult<(Vec<Sample>, PendingGate)> {
        let idx = vehicles(Some(idx), self.inner.memory.len())?;
        let k = idx.len();
        let stamp = column("stamp", stamp, k)?;
        let shape_error = |got: String| {
            PyValueError::new_err(format!(
                "rows (the packed observer outputs) must have shape ({k}, {}), got {got}",
                gate::COLUMNS
            ))
        };
        // an array (k, COLUMNS), or one message's numbers as a flat sequence (no numpy array to make)
        let flat: Vec<f64> = if let Ok(a) = rows.extract::<PyReadonlyArray2<'_, f64>>() {
            let v = a.as_array();
            if v.shape() != [k, gate::COLUMNS] {
                return Err(shape_error(format!("{:?}", v.shape())));
            }
            v.iter().copied().collect()
        } else {
            let v: Vec<f64> = rows.extract().map_err(|_| {
                shape_error(format!(
                    "a {} (need a float array or a sequence of numbers)",
                    rows.get_type()
                ))
            })?;
            if v.len() != k * gate::COLUMNS {
                return Err(shape_error(format!("{} numbers", v.len())));
            }
            v
        };
        let rows: Vec<&[f64]> = flat.chunks_exact(gate::COLUMNS).collect();
        self.run_rows(idx, stamp, &rows)
    }

    /// The gate's samples of vehicles `idx` at `stamp` from their packed observer outputs `rows`
    /// (crate::soil::gate::COLUMNS numbers each), and the [`PendingGate`] to commit.
    pub(crate) fn run_rows(
        &self,
        idx: Vec<usize>,
        stamp: Vec<f64>,
        rows: &[&[f64]],
    ) -> PyResult<(Vec<Sample>, PendingGate)> {
        let (samples, lps) = self.inner.samples(&idx, &stamp, rows).map_err(PyValueError::new_err)?;
        Ok((samples, PendingGate { idx, stamp, lps }))
    }
}

/// A gate step computed and not yet kept: kept only once its samples are accepted, so that a refused
/// step (a non-finite sample, a bad scale sigma) leaves the low-pass slips as they were.
pub(crate) struct PendingGate {
    pub(crate) idx: Vec<usize>,
    pub(crate) stamp: Vec<f64>,
    pub(crate) lps: Vec<crate::soil::gate::Memory>,
}

#[pymethods]
impl SlipGateBank {
    /// The gate of `n_vehicles`: each wheel's lateral position `wheel_y` (4,) m, whether the soil
    /// update compares `gross` traction (else net), and the numbers of `params` (names of
    /// crate::soil::gate::GateParams but wheel_y, gross, soil and limits; the soil settings and the
    /// usability limits by the names of crate::soil::params::Params and crate::soil::usability::Limits,
    /// a missing one at its default).
    #[new]
    fn py_new(n_vehicles: usize, wheel_y: [f64; 4], gross: bool, params: HashMap<String, f64>) -> PyResult<Self> {
        const NAMES: [&str; 7] = [
            "wheel_radius",
            "half_track",
            "static_load",
            "shared",
            "lift_off_force",
            "slip_deadband",
            "slip_floor",
        ];
        let limit = |k: &str| Limits::SPECS.iter().any(|s| s.name == k);
        let soil = |k: &str| Params::SPECS.iter().any(|s| s.name == k);
        if let Some(k) = params
            .keys()
            .find(|k| !NAMES.contains(&k.as_str()) && !limit(k) && !soil(k))
        {
            return Err(PyValueError::new_err(format!("gate params: unknown field {k:?}")));
        }
        let get = |name: &str| -> PyResult<f64> {
            match params.get(name) {
                None => Err(PyValueError::new_err(format!("gate params: missing field {name:?}"))),
                Some(v) if !v.is_finite() => Err(PyValueError::new_err(format!(
                    "gate params: {name} = {v} must be finite"
                ))),
                Some(v) => Ok(*v),
            }
        };
        if !wheel_y.iter().all(|v| v.is_finite()) {
            return Err(PyValueError::new_err(format!("wheel_y {wheel_y:?} must be finite")));
        }
        // the entries one settings struct declares (`declared`), for its own from_map
        let only = |declared: &dyn Fn(&str) -> bool| -> HashMap<String, f64> {
            params
                .iter()
                .filter(|(k, _)| declared(k))
                .map(|(k, v)| (k.clone(), *v))
                .collect()
        };
        let cfg = GateParams {
            wheel_radius: get("wheel_radius")?,
            wheel_y,
            half_track: get("half_track")?,
            static_load: get("static_load")?,
            shared: get("shared")?,
            gross,
            lift_off_force: get("lift_off_force")?,
            slip_deadband: get("slip_deadband")?,
            slip_floor: get("slip_floor")?,
            soil: Params::from_map(&only(&soil)).map_err(PyValueError::new_err)?,
            limits: Limits::from_map(&only(&limit)).map_err(PyValueError::new_err)?,
        };
        let inner = gate::SlipGateBank::new(cfg, n_vehicles).map_err(PyValueError::new_err)?;
        Ok(SlipGateBank { inner })
    }

    /// One sample per vehicle in `idx` (k distinct indices): stamp (k,) s and the packed observer
    /// outputs `rows` (k, `columns`).  Returns the arrays of `GateArrays` (module doc).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        idx: PyReadonlyArray1<'py, i64>,
        stamp: PyReadonlyArray1<'py, f64>,
        rows: Bound<'py, PyAny>,
    ) -> PyResult<GateArrays<'py>> {
        let (samples, pending) = self.run(&idx, &stamp, &rows)?;
        check_finite(&samples)?; // before the state moves: a refused step leaves the low-pass as it was
        self.inner.commit(&pending.idx, &pending.stamp, &pending.lps);
        gate_arrays(py, &samples)
    }

    /// Numbers per vehicle in a packed row.
    #[classattr]
    fn columns() -> usize {
        gate::COLUMNS
    }

    /// The names of a packed row's per-wheel fields, in order (four columns each).
    #[classattr]
    fn quad_fields() -> Vec<&'static str> {
        gate::quad_names()
    }

    /// The names of a packed row's per-vehicle fields, in order, after the quads.
    #[classattr]
    fn scalar_fields() -> Vec<&'static str> {
        gate::SCALAR_NAMES.to_vec()
    }

    #[getter]
    fn n_vehicles(&self) -> usize {
        self.inner.memory.len()
    }

    /// The low-pass slips (N, 4).
    #[getter]
    fn lp<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        to_rows(py, self.inner.memory.iter().map(|m| m.lp))
    }

    /// The stamp each vehicle's low-pass was last stepped at (N,) (NaN: never).
    #[getter]
    fn lp_stamp<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        to_column(py, self.inner.lp_stamp.iter().copied())
    }
}

/// The names of the codes the soil stage sets (the first rows of a table of crate::codes).
fn soil_names(table: &[Code]) -> Vec<&'static str> {
    table
        .iter()
        .take_while(|c| c.set_by == SetBy::Soil)
        .map(|c| c.name)
        .collect()
}

/// The grid Bayes soil filters of N vehicles (docs/method.md §9, §11, §16).
#[pyclass(module = "soilocp._core")]
pub struct SoilGridBank {
    inner: bank::SoilGridBank,
    /// the records' state, once `set_status` gave its settings
    status: Option<StatusBank>,
    /// the last step's records (its vehicles in order)
    reports: Vec<Report>,
}

/// What `report` returns per vehicle of the last step: codes (k, 3) int64 (status, reason, K
/// reported 0 / 1), numbers (k, 8) (K, its 1-sigma, ln K's, the last informative update's stamp
/// (NaN: none), the reason's 4 numbers) and the used wheels (k, 4) bool.
pub(crate) type ReportArrays<'py> = (
    Bound<'py, PyArray2<i64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<bool>>,
);

pub(crate) fn report_arrays<'py>(py: Python<'py>, reports: &[Report], used: &[[bool; 4]]) -> ReportArrays<'py> {
    let codes = reports
        .iter()
        .map(|r| [r.status as i64, r.reason as i64, i64::from(r.k.is_some())]);
    let nums = reports.iter().map(|r| {
        // K, its 1-sigma, ln K's (NaN: none), the last update's stamp, the reason's numbers
        let mut row = [r.last_update.unwrap_or(f64::NAN); 8];
        row[..3].copy_from_slice(&r.k.unwrap_or([f64::NAN; 3]));
        row[4..].copy_from_slice(&r.args);
        row
    });
    (to_rows(py, codes), to_rows(py, nums), to_rows(py, used.iter().copied()))
}

fn finite(name: &str, rows: &[[f64; 4]]) -> PyResult<()> {
    if rows.iter().flatten().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!("{name} must be finite, got {rows:?}")))
    }
}

impl SoilGridBank {
    /// The update with the slip gate's `samples` (crate::soil::gate::SlipGateBank::samples, its low-pass
    /// slips `pending`) and the online torque scale's relative 1-sigma (`scale_sigma`, one per sample;
    /// None: the prior), and the records: the samples as updated, and each one's used wheels.  The
    /// gate keeps its new low-pass slips only once the update has taken the samples.
    pub(crate) fn gated(
        &mut self,
        gate: &mut gate::SlipGateBank,
        mut samples: Vec<Sample>,
        pending: PendingGate,
        scale_sigma: Option<&[f64]>,
    ) -> PyResult<(Vec<Sample>, Vec<[bool; 4]>)> {
        if self.status.is_none() {
            return Err(PyValueError::new_err(
                "soil: call set_status first (the records' settings)",
            ));
        }
        if let Some(sig) = scale_sigma {
            for (s, &v) in samples.iter_mut().zip(sig) {
                s.scale_sigma = Some(v);
            }
        }
        check_finite(&samples)?;
        let out = self.step_samples(&samples)?;
        gate.commit(&pending.idx, &pending.stamp, &pending.lps);
        let used = out.iter().map(|s| s.wheel.map(|f| f & bank::USED != 0)).collect();
        Ok((samples, used))
    }

    /// Whether the records' settings were given (`set_status`).
    pub(crate) fn has_status(&self) -> bool {
        self.status.is_some()
    }

    /// The traction law's constants the grid's curves are of.
    pub(crate) fn constants(&self) -> &Constants {
        &self.inner.grid.c
    }

    /// The number of vehicles of the bank.
    pub(crate) fn bank_len(&self) -> usize {
        self.inner.vehicles.len()
    }

    /// The records of the last step's vehicles, in order.
    pub(crate) fn reports(&self) -> &[Report] {
        &self.reports
    }

    /// The bank's step of the samples and, where `set_status` configured them, their records.
    fn step_samples(&mut self, samples: &[Sample]) -> PyResult<Vec<bank::Step>> {
        let out = self.inner.step(samples).map_err(PyValueError::new_err)?;
        self.reports = match self.status.as_mut() {
            Some(st) => st.report(&self.inner, samples, &out),
            None => Vec::new(),
        };
        Ok(out)
    }

    /// The update of the samples' vehicles, refused with a ValueError (naming the field) where a
    /// number the update needs is not finite.
    fn run<'py>(&mut self, py: Python<'py>, samples: &[Sample]) -> PyResult<StepArrays<'py>> {
        check_finite(samples)?;
        let out = self.step_samples(samples)?;
        let col = |f: fn(&bank::Step) -> f64| to_column(py, out.iter().map(f));
        let flag = |f: fn(&bank::Step) -> bool| to_column(py, out.iter().map(f));
        let rows = |f: fn(&bank::Step) -> [f64; 3]| to_rows(py, out.iter().map(f));
        Ok((
            to_rows(py, out.iter().map(|s| s.wheel)),
            col(|s| s.dt),
            flag(|s| s.informed),
            flag(|s| s.taken),
            col(|s| s.k_report),
            col(|s| s.log_stat),
            to_rows(py, out.iter().map(|s| s.stats)),
            rows(|s| s.scale),
            flag(|s| s.axle.mismatch),
            rows(|s| [s.axle.z, s.axle.theta_front, s.axle.theta_rear]),
            col(|s| s.floor_cdf),
        ))
    }
}

/// The numbers the update needs must be finite: a ValueError naming the field otherwise.
fn check_finite(samples: &[Sample]) -> PyResult<()> {
    for (name, get) in [
        ("slip", (|s: &Sample| s.slip) as fn(&Sample) -> [f64; 4]),
        ("observed", |s: &Sample| s.observed),
        ("variance", |s: &Sample| s.variance),
        ("slip_sigma", |s: &Sample| s.slip_sigma),
    ] {
        let rows: Vec<[f64; 4]> = samples.iter().map(get).collect();
        finite(name, &rows)?;
    }
    for s in samples {
        if !s.stamp.is_finite() {
            return Err(PyValueError::new_err(format!("stamp {}: must be finite", s.stamp)));
        }
    }
    Ok(())
}

/// A step's inputs, read by attribute from soilocp.estimation.soil_state.SoilInputs (its fields, as
/// float64 / bool arrays: SoilInputs.arrays): (k, 4) per wheel, (k,) per vehicle, span (k, 4) and
/// slip_ends (k, 4, 2) or None.  Its `unusable` codes come apart, counted first by the caller.
#[derive(FromPyObject)]
pub(crate) struct Inputs<'py> {
    slip: PyReadonlyArray2<'py, f64>,
    informative: PyReadonlyArray2<'py, bool>,
    observed: PyReadonlyArray2<'py, f64>,
    variance: PyReadonlyArray2<'py, f64>,
    slip_sigma: PyReadonlyArray2<'py, f64>,
    gate_slip: PyReadonlyArray2<'py, f64>,
    gate_sigma: PyReadonlyArray2<'py, f64>,
    held: PyReadonlyArray2<'py, bool>,
    ground_stale: PyReadonlyArray1<'py, bool>,
    identifiable: PyReadonlyArray1<'py, bool>,
    speed: PyReadonlyArray1<'py, f64>,
    span: Option<PyReadonlyArray2<'py, f64>>,
    slip_ends: Option<PyReadonlyArray3<'py, f64>>,
}

#[pymethods]
impl SoilGridBank {
    /// The status codes' names this bank's records carry, code -> name (crate::codes).
    #[classattr]
    fn status_names() -> Vec<&'static str> {
        soil_names(codes::status::TABLE)
    }

    /// The reason codes' names this bank's records carry, code -> name (the Python side words each).
    #[classattr]
    fn reason_names() -> Vec<&'static str> {
        soil_names(codes::reason::TABLE)
    }

    /// The wheels' unusable codes' names, code -> name ("": usable).
    #[classattr]
    fn unusable_names() -> Vec<&'static str> {
        usability::NAMES.to_vec()
    }

    /// The bank of `n_vehicles` from `constants`, the `measurement` ("gross" or "net"), the grid as
    /// numpy made it (theta = ln K nodes, k_grid = e^theta, amp = C1 (1 - e^{-C2 K})), the scale
    /// profile's nodes (z in 1-sigma units, their log prior), the weakest fitted soil's K / 2
    /// (`k_floor`) and the soil settings (`params`, by the names of
    /// crate::soil::params::Params; a missing one takes its default).
    #[new]
    #[allow(clippy::too_many_arguments)]
    fn py_new(
        constants: Constants,
        n_vehicles: usize,
        measurement: &str,
        theta: PyReadonlyArray1<'_, f64>,
        k_grid: PyReadonlyArray1<'_, f64>,
        amp: PyReadonlyArray1<'_, f64>,
        scale_z: PyReadonlyArray1<'_, f64>,
        scale_log_prior: PyReadonlyArray1<'_, f64>,
        k_floor: f64,
        params: HashMap<String, f64>,
    ) -> PyResult<Self> {
        let kind = match measurement {
            "gross" => Kind::Gross,
            "net" => Kind::Net,
            other => {
                return Err(PyValueError::new_err(format!(
                    "measurement {other:?}: need 'gross' or 'net'"
                )))
            }
        };
        if n_vehicles == 0 {
            return Err(PyValueError::new_err("n_vehicles must be >= 1"));
        }
        let grid = Grid::new(
            theta.as_array().to_vec(),
            k_grid.as_array().to_vec(),
            Some(amp.as_array().to_vec()),
            kind,
            constants,
        )
        .map_err(PyValueError::new_err)?;
        let cfg = Params::from_map(&params).map_err(PyValueError::new_err)?;
        let nodes = ScaleNodes {
            z: scale_z.as_array().to_vec(),
            log_prior: scale_log_prior.as_array().to_vec(),
        };
        let inner = bank::SoilGridBank::new(grid, cfg, nodes, k_floor, n_vehicles).map_err(PyValueError::new_err)?;
        Ok(SoilGridBank {
            inner,
            status: None,
            reports: Vec::new(),
        })
    }

    /// One sample per vehicle in `idx` (k distinct indices): stamp (k,) s; the step's [`Inputs`]
    /// (a SoilInputs: slip, observed, variance, slip_sigma, gate_slip, gate_sigma (k, 4); informative,
    /// held (k, 4) bool; ground_stale, identifiable (k,) bool; speed (k,) m/s (NaN: unknown); span
    /// (k, 4) and slip_ends (k, 4, 2) or None); optional unusable (k, 4) int codes and scale_sigma
    /// (k,).  Returns the arrays of `StepArrays` (module doc).
    #[pyo3(signature = (idx, stamp, inputs, unusable=None, scale_sigma=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        idx: PyReadonlyArray1<'py, i64>,
        stamp: PyReadonlyArray1<'py, f64>,
        inputs: Inputs<'py>,
        unusable: Option<PyReadonlyArray2<'py, i64>>,
        scale_sigma: Option<PyReadonlyArray1<'py, f64>>,
    ) -> PyResult<StepArrays<'py>> {
        let Inputs {
            slip,
            informative,
            observed,
            variance,
            slip_sigma,
            gate_slip,
            gate_sigma,
            held,
            ground_stale,
            identifiable,
            speed,
            span,
            slip_ends,
        } = inputs;
        let idx = vehicles(Some(&idx), self.inner.vehicles.len())?;
        let k = idx.len();
        let stamp = column("stamp", &stamp, k)?;
        let (slip, observed, variance, slip_sigma) = (
            quads("slip", &slip, k)?,
            quads("observed", &observed, k)?,
            quads("variance", &variance, k)?,
            quads("slip_sigma", &slip_sigma, k)?,
        );
        let (gate_slip, gate_sigma) = (quads("gate_slip", &gate_slip, k)?, quads("gate_sigma", &gate_sigma, k)?);
        let (informative, held) = (quads("informative", &informative, k)?, quads("held", &held, k)?);
        let ground_stale = column("ground_stale", &ground_stale, k)?;
        let identifiable = column("identifiable", &identifiable, k)?;
        let speed = column("speed", &speed, k)?;
        let span = span.map(|a| quads("span", &a, k)).transpose()?;
        let slip_ends = match slip_ends {
            None => None,
            Some(a) => {
                let v = a.as_array();
                if v.shape() != [k, 4, 2] {
                    return Err(PyValueError::new_err(format!(
                        "slip_ends must have shape ({k}, 4, 2), got {:?}",
                        v.shape()
                    )));
                }
                Some(
                    (0..k)
                        .map(|j| std::array::from_fn(|w| [v[[j, w, 0]], v[[j, w, 1]]]))
                        .collect::<Vec<[[f64; 2]; 4]>>(),
                )
            }
        };
        let unusable = match unusable {
            None => None,
            Some(a) => {
                let v = a.as_array();
                if v.shape() != [k, 4] {
                    return Err(PyValueError::new_err(format!(
                        "unusable must have shape ({k}, 4), got {:?}",
                        v.shape()
                    )));
                }
                Some(
                    v.outer_iter()
                        .map(|r| [r[0], r[1], r[2], r[3]])
                        .collect::<Vec<[i64; 4]>>(),
                )
            }
        };
        let scale_sigma = scale_sigma.map(|a| column("scale_sigma", &a, k)).transpose()?;
        let samples: Vec<Sample> = (0..k)
            .map(|j| Sample {
                vehicle: idx[j],
                stamp: stamp[j],
                slip: slip[j],
                observed: observed[j],
                variance: variance[j],
                slip_sigma: slip_sigma[j],
                gate_slip: gate_slip[j],
                gate_sigma: gate_sigma[j],
                informative: informative[j],
                held: held[j],
                ground_stale: ground_stale[j],
                identifiable: identifiable[j],
                speed: speed[j],
                span: span.as_ref().map(|s| s[j]),
                slip_ends: slip_ends.as_ref().map(|s| s[j]),
                unusable: unusable.as_ref().map_or([0; 4], |u| u[j]),
                scale_sigma: scale_sigma.as_ref().map(|s| s[j]),
            })
            .collect();
        self.run(py, &samples)
    }

    /// Make records from now on: each step also makes its vehicles' records (`report`, the
    /// chain's steps), with the bank's settings and the grid's ln K `span`.
    fn set_status(&mut self, span: f64) -> PyResult<()> {
        let n = self.inner.vehicles.len();
        let bank = StatusBank::new(self.inner.cfg, span, n).map_err(PyValueError::new_err)?;
        self.status = Some(bank);
        Ok(())
    }

    /// The records of the last step's vehicles (the arrays of `ReportArrays`, module doc).
    fn report<'py>(&self, py: Python<'py>, used: PyReadonlyArray2<'py, u8>) -> PyResult<ReportArrays<'py>> {
        let wheel = quads("used", &used, self.reports.len())?;
        let used: Vec<[bool; 4]> = wheel.iter().map(|w| w.map(|f| f & bank::USED != 0)).collect();
        Ok(report_arrays(py, &self.reports, &used))
    }

    /// Start vehicle `i`'s beliefs over from `belief` (G,): the pooled and the no-change one, and
    /// the evidence window (a fleet map's cell, soilocp.map.prior).
    fn start_belief(&mut self, i: usize, belief: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        self.inner
            .start_belief(i, &belief.as_array().to_vec())
            .map_err(PyValueError::new_err)
    }

    /// Vehicle `i`'s axle-check window (soil/axles.rs): the decaying time with the axles' z over
    /// the threshold, and all the judged time, as of its last step (crate::soil::status reads them where
    /// one axle is not informing now; the tests' reference records read them here).
    fn axle_window(&self, i: usize) -> PyResult<(f64, f64)> {
        let b = self
            .inner
            .vehicles
            .get(i)
            .ok_or_else(|| PyValueError::new_err(format!("vehicle index {i} out of range")))?;
        Ok((b.axles.over, b.axles.weight))
    }

    #[getter]
    fn n_vehicles(&self) -> usize {
        self.inner.vehicles.len()
    }

    /// The pooled beliefs (N, G).
    #[getter]
    fn p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        to_rows_of(py, self.inner.grid.len(), self.inner.vehicles.iter().map(|b| &b.p[..]))
    }

    /// The no-change beliefs (N, G).
    #[getter]
    fn p_stay<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        to_rows_of(
            py,
            self.inner.grid.len(),
            self.inner.vehicles.iter().map(|b| &b.p_stay[..]),
        )
    }

    /// The front and rear axle beliefs (N, 2, G).
    #[getter]
    fn axle_p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        let (n, g) = (self.inner.vehicles.len(), self.inner.grid.len());
        Array3::from_shape_fn((n, 2, g), |(i, a, j)| self.inner.vehicles[i].axles.p[a][j]).into_pyarray(py)
    }

    /// P(no change | data) per vehicle (N,).
    #[getter]
    fn w_stay<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        to_column(py, self.inner.vehicles.iter().map(|b| b.w_stay))
    }

    /// The recent log-evidence for no change against the pooled belief (N,).
    #[getter]
    fn stay_llr<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        to_column(py, self.inner.vehicles.iter().map(|b| b.stay_llr))
    }

    /// The window statistics (N, 5): evidence, NIS sum, sum w h_K^2, sum w h_K h, sum w h_K h_S dS.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        to_rows(py, self.inner.vehicles.iter().map(|b| b.stats))
    }

    /// The scale's systematic term of the last informative sample (N, 3): 1-sigma of ln K, c's
    /// mean and 1-sigma.
    #[getter]
    fn scale_sys<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        to_rows(py, self.inner.vehicles.iter().map(|b| b.scale_sys))
    }

    /// The scale's 1-sigma per vehicle (N,): the prior, or the online state's last value.
    #[getter]
    fn scale_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        to_column(py, self.inner.vehicles.iter().map(|b| b.scale_prior))
    }
}

/// What `soil_classes` returns: each belief's class index and its probability.
type Classes<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<f64>>);

/// The most probable soil class of each belief ln K ~ N(`log_k`, `log_k_std`^2) (n,) and its
/// probability (crate::soil::classes) between the boundaries `edges` (m + 1,): (index (n,), p (n,)).
#[pyfunction]
pub fn soil_classes<'py>(
    py: Python<'py>,
    log_k: PyReadonlyArray1<'py, f64>,
    log_k_std: PyReadonlyArray1<'py, f64>,
    edges: PyReadonlyArray1<'py, f64>,
) -> PyResult<Classes<'py>> {
    let (l, s, e) = (log_k.as_array(), log_k_std.as_array(), edges.as_array());
    if l.len() != s.len() {
        return Err(PyValueError::new_err(format!(
            "log_k ({},) and log_k_std ({},) must have one length",
            l.len(),
            s.len()
        )));
    }
    let e = e.to_vec();
    if e.len() < 2 {
        return Err(PyValueError::new_err("edges: need at least two class boundaries"));
    }
    let (idx, p): (Vec<i64>, Vec<f64>) = l
        .iter()
        .zip(s.iter())
        .map(|(&l, &s)| {
            let (i, p) = crate::soil::classes::classify(l, s, &e);
            (i as i64, p)
        })
        .unzip();
    Ok((
        Array1::from_vec(idx).into_pyarray(py),
        Array1::from_vec(p).into_pyarray(py),
    ))
}
