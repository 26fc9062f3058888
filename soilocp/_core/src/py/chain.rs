//! `soilocp._core.ChainCore`: the whole estimation chain of a bank of vehicles in one call per
//! step, for the offline path and the batched service: the online torque scale, the observer, the
//! slip gate, the soil-grid update with its records, the scale's feed of K back, and the OCPs
//! (eqs. 7-10).  It holds the stage objects the Python side built (`ObserverCore`,
//! `TorqueScaleCore`, `SlipGateBank`, `SoilGridBank`) and steps their state in place with the same
//! kernels their own calls run, so a stage's calls and the chain's give the same numbers; nothing
//! crosses the boundary between the stages.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::observer::{blocks, Inputs, ObserverCore, StepOut};
use super::soil::{gate_arrays, report_arrays, GateArrays, ReportArrays, SlipGateBank, SoilGridBank};
use super::torque_scale::TorqueScaleCore;
use crate::constants::Constants;
use crate::observer::vehicles::{Estimate, ObserverBank, Raw};
use crate::ocp;
use crate::soil::bank::Sample;
use crate::soil::gate::{self, COLUMNS};
use crate::torque_scale::bank::{Sample as ScaleSample, TorqueScaleBank};

type Arr<'py> = Bound<'py, PyArray1<f64>>;

/// The OCP arrays of the step's vehicles: mu_T, S_T, S_E and TE at S_E (k,) each, as `ocp_bank`.
type OcpArrays<'py> = (Arr<'py>, Arr<'py>, Arr<'py>, Arr<'py>);

/// What `ChainCore.step` returns: the observer's blocks (as `ObserverCore.step`), the slip gate's
/// arrays (as `SlipGateBank.step`), the records (as `SoilGridBank.report`) and the OCPs.
type ChainOut<'py> = (StepOut<'py>, GateArrays<'py>, ReportArrays<'py>, OcpArrays<'py>);

#[pyclass(module = "soilocp._core")]
pub struct ChainCore {
    observer: Py<ObserverCore>,
    gate: Py<SlipGateBank>,
    soil: Py<SoilGridBank>,
    constants: Constants,
    /// None: the torque scale is off (k = 1 and the soil's scale prior as configured)
    scale: Option<Py<TorqueScaleCore>>,
    /// feed each step's K and slips back to the scale (its modelled motion resistance, eq. 4)
    feed_soil: bool,
}

/// The torque scale's sample of an observer input: the logged torques, before the scale.
fn scale_sample(r: &Raw) -> ScaleSample {
    ScaleSample {
        stamp: r.stamp,
        f_x: r.specific_force_x,
        pitch: r.pitch,
        yaw_rate: r.yaw_rate,
        wheel_speed: r.wheel_speed,
        torque: r.wheel_torque,
        ground_speed: r.ground_speed,
        normal_force: Some(r.normal_force),
    }
}

/// One step's stages, borrowed from their Python objects for the step.
struct Stages<'a> {
    observer: &'a mut ObserverBank,
    scale: Option<&'a mut TorqueScaleBank>,
    gate: &'a mut SlipGateBank,
    soil: &'a mut SoilGridBank,
    constants: &'a Constants,
    feed_soil: bool,
}

/// What a step makes, before it becomes arrays.
struct Done {
    estimates: Vec<Estimate>,
    samples: Vec<Sample>,
    used: Vec<[bool; 4]>,
    ocp: Vec<ocp::Ocp>,
}

impl Stages<'_> {
    /// The chain's step of `vehicles` by their checked samples `raws` (`ChainCore.step`).
    fn step(mut self, vehicles: &[usize], mut raws: Vec<Raw>) -> PyResult<Done> {
        let mut scale_sigma: Option<Vec<f64>> = None;
        if let Some(bank) = self.scale.as_deref_mut() {
            let stepped: Vec<(f64, f64)> = vehicles
                .iter()
                .zip(&raws)
                .map(|(&g, r)| bank.step(g, &scale_sample(r)))
                .collect();
            if let Some(scaled) = bank.scaled(&stepped) {
                for (r, &(m, _)) in raws.iter_mut().zip(&scaled) {
                    r.wheel_torque = r.wheel_torque.map(|t| t * m);
                }
                scale_sigma = Some(scaled.iter().map(|&(_, s)| s).collect());
            }
        }
        let estimates: Vec<Estimate> = vehicles
            .iter()
            .zip(&raws)
            .map(|(&g, r)| self.observer.step(g, r))
            .collect();
        // what the stages' ObserverOutput message refuses (its numbers must be finite), the chain refuses too
        let bad = estimates
            .iter()
            .zip(vehicles)
            .find_map(|(e, &g)| e.first_non_finite().map(|n| (g, n)));
        if let Some((g, name)) = bad {
            return Err(PyValueError::new_err(format!(
                "observer output {name} of vehicle {g} is not finite"
            )));
        }
        let rows: Vec<[f64; COLUMNS]> = estimates.iter().map(gate::row_of).collect();
        let rows: Vec<&[f64]> = rows.iter().map(|r| &r[..]).collect();
        let stamps = raws.iter().map(|r| r.stamp).collect();
        let (samples, pending) = self.gate.run_rows(vehicles.to_vec(), stamps, &rows)?;
        let (samples, used) = self
            .soil
            .gated(&mut self.gate.inner, samples, pending, scale_sigma.as_deref())?;
        let ks: Vec<f64> = self
            .soil
            .reports()
            .iter()
            .map(|r| r.k.map_or(f64::NAN, |v| v[0]))
            .collect();
        if let (true, Some(bank)) = (self.feed_soil, self.scale) {
            for ((&g, &k), s) in vehicles.iter().zip(&ks).zip(&samples) {
                bank.feed_soil(g, k, Some(s.slip));
            }
        }
        let ocp = ocp::bank(&ks, self.constants).map_err(PyValueError::new_err)?;
        Ok(Done {
            estimates,
            samples,
            used,
            ocp,
        })
    }
}

#[pymethods]
impl ChainCore {
    /// The chain over the stage objects of one bank of N vehicles: the `observer`, the slip `gate`,
    /// the `soil` bank (its records' settings given: `set_status`), the traction law's `constants`
    /// (the OCPs'), the torque `scale` (None: off) and whether K is fed back to it (`feed_soil`).
    #[new]
    #[pyo3(signature = (observer, gate, soil, constants, scale=None, feed_soil=false))]
    fn py_new(
        py: Python<'_>,
        observer: Py<ObserverCore>,
        gate: Py<SlipGateBank>,
        soil: Py<SoilGridBank>,
        constants: Constants,
        scale: Option<Py<TorqueScaleCore>>,
        feed_soil: bool,
    ) -> PyResult<Self> {
        let n = observer.bind(py).try_borrow_mut()?.bank_mut().filter.n_vehicles;
        let mut sizes = vec![
            ("gate", gate.bind(py).try_borrow()?.inner.lp.len()),
            ("soil", soil.bind(py).try_borrow()?.bank_len()),
        ];
        if let Some(s) = &scale {
            sizes.push(("scale", s.bind(py).try_borrow_mut()?.bank_mut().len()));
        }
        if let Some((name, m)) = sizes.iter().find(|(_, m)| *m != n) {
            return Err(PyValueError::new_err(format!(
                "{name} holds {m} vehicles, the observer {n}: the chain's stages must be one bank"
            )));
        }
        if !soil.bind(py).try_borrow()?.has_status() {
            return Err(PyValueError::new_err(
                "soil: its records' settings are not given (SoilGridBank.set_status): the chain makes records",
            ));
        }
        Ok(ChainCore {
            observer,
            gate,
            soil,
            constants,
            scale,
            feed_soil,
        })
    }

    /// One step of the vehicles `idx` (None: all, in order), with the observer's inputs
    /// (`ObserverCore.step`'s ObserverInputs, the logged torques): the torque scale steps on them and the
    /// observer takes the torques times k's mean; the gate packs the observer's estimates; the soil
    /// update takes the gate's samples with k's relative 1-sigma; K goes back to the scale; the OCPs
    /// of K.  Every input is checked (ValueError naming the field) before any state changes.  An
    /// observer output that is not finite (which the stages' ObserverOutput message refuses) or a
    /// sample the soil update refuses raises after the scale and the observer have stepped, and
    /// leaves the gate as it was (the observer's clock is the core's: `ObserverCore.last_stamp`).
    fn step<'py>(
        &self,
        py: Python<'py>,
        idx: Option<PyReadonlyArray1<'py, i64>>,
        inputs: Inputs<'py>,
    ) -> PyResult<ChainOut<'py>> {
        // try_: a stage object another thread holds now is a RuntimeError, not a panic
        let mut obs = self.observer.bind(py).try_borrow_mut()?;
        let (vehicles, raws) = obs.raws(idx.as_ref(), &inputs)?;
        let mut scale = self.scale.as_ref().map(|s| s.bind(py).try_borrow_mut()).transpose()?;
        let mut gate = self.gate.bind(py).try_borrow_mut()?;
        let mut soil = self.soil.bind(py).try_borrow_mut()?;
        let stages = Stages {
            observer: obs.bank_mut(),
            scale: scale.as_mut().map(|s| s.bank_mut()),
            gate: &mut gate,
            soil: &mut soil,
            constants: &self.constants,
            feed_soil: self.feed_soil,
        };
        // the GIL is released for the step: a Zenoh callback can hand over the next samples meanwhile (the
        // stage objects stay borrowed: another thread that reads one of them now gets a RuntimeError, not a
        // half-stepped state)
        let done = py.detach(move || stages.step(&vehicles, raws))?;
        let col = |f: fn(&ocp::Ocp) -> f64| done.ocp.iter().map(f).collect::<Vec<f64>>().into_pyarray(py);
        Ok((
            blocks(py, &done.estimates),
            gate_arrays(py, &done.samples)?,
            report_arrays(py, soil.reports(), &done.used),
            (col(|x| x.mu_t), col(|x| x.s_t), col(|x| x.s_e), col(|x| x.te_at_s_e)),
        ))
    }
}
