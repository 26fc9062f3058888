//! `soilocp._core.ChainCore`: the estimation chain of a bank of vehicles, assembled here once.
//!
//! Its stage steps are `observe` (the online torque scale and the observer), `update` (the slip
//! gate, a map prior's informing wheels and the soil-grid update with its records) and `feed` (K
//! and the slips back to the torque scale); its whole step `step` is those in order, then the OCPs
//! (eqs. 7-10).  The offline path and the batched service call `step`; the live services call the
//! stage steps one each (the observer service `observe` and `feed`, the soil-strength service
//! `update`), passing the messages between them, so every path runs the same code in the same order.
//! It holds the stage objects the Python side built (`ObserverCore`, `TorqueScaleCore`,
//! `SlipGateBank`, `SoilGridBank`) and steps their state in place.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::args::{self, column, quads};
use super::observer::{blocks, Inputs, ObserverCore, StepOut};
use super::soil::{gate_arrays, report_arrays, GateArrays, PendingGate, ReportArrays, SlipGateBank, SoilGridBank};
use super::torque_scale::TorqueScaleCore;
use crate::observer::vehicles::{Estimate, ObserverBank, Raw};
use crate::ocp;
use crate::soil::bank::Sample;
use crate::soil::gate::{self, COLUMNS};
use crate::torque_scale::bank::TorqueScaleBank;

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
    /// None: the torque scale is off (k = 1 and the soil's scale prior as configured)
    scale: Option<Py<TorqueScaleCore>>,
    /// feed each step's K and slips back to the scale (its modelled motion resistance, eq. 4)
    feed_soil: bool,
}

/// The observer stage's output: the estimates and, once the torque scale has left its prior, each
/// vehicle's (k's mean, its relative 1-sigma for K's band).
type Observed = (Vec<Estimate>, Option<Vec<(f64, f64)>>);

/// The soil stage's output: the gate's samples as updated, their used wheels and K (NaN: none).
type Updated = (Vec<Sample>, Vec<[bool; 4]>, Vec<f64>);

/// One step's stages, borrowed from their Python objects for the step.
struct Stages<'a> {
    observer: &'a mut ObserverBank,
    scale: Option<&'a mut TorqueScaleBank>,
    gate: &'a mut SlipGateBank,
    soil: &'a mut SoilGridBank,
    feed_soil: bool,
}

/// The stage objects of a chain, borrowed from Python for one call (`try_`: a stage object another
/// thread holds now is a RuntimeError, not a panic).
struct Held<'py> {
    observer: PyRefMut<'py, ObserverCore>,
    scale: Option<PyRefMut<'py, TorqueScaleCore>>,
    gate: PyRefMut<'py, SlipGateBank>,
    soil: PyRefMut<'py, SoilGridBank>,
}

impl Held<'_> {
    /// The stages of the held objects, for one call.
    fn stages(&mut self, feed_soil: bool) -> Stages<'_> {
        Stages {
            observer: self.observer.bank_mut(),
            scale: self.scale.as_mut().map(|s| s.bank_mut()),
            gate: &mut self.gate,
            soil: &mut self.soil,
            feed_soil,
        }
    }
}

/// What a step makes, before it becomes arrays.
struct Done {
    estimates: Vec<Estimate>,
    samples: Vec<Sample>,
    used: Vec<[bool; 4]>,
    ocp: Vec<ocp::Ocp>,
}

impl Stages<'_> {
    /// The observer stage of `vehicles` by their checked samples `raws`: the torque scale steps on
    /// the logged torques, the observer takes them times k's mean.  Returns the estimates and, once
    /// the scale has left its prior, each vehicle's (k's mean, its relative 1-sigma for K's band).
    fn observe(&mut self, vehicles: &[usize], mut raws: Vec<Raw>) -> PyResult<Observed> {
        let mut scaled = None;
        if let Some(bank) = self.scale.as_deref_mut() {
            let stepped: Vec<(f64, f64)> = vehicles.iter().zip(&raws).map(|(&g, r)| bank.step(g, r)).collect();
            scaled = bank.scaled(&stepped);
            if let Some(sc) = &scaled {
                for (r, &(m, _)) in raws.iter_mut().zip(sc) {
                    r.wheel_torque = r.wheel_torque.map(|t| t * m);
                }
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
        Ok((estimates, scaled))
    }

    /// The soil stage: the gate's `samples` (their low-pass slips `pending`), each wheel's
    /// `informing` flag of a map prior (false: the wheel stands on the ground the belief was not
    /// started for, and does not inform it) and the scale's relative 1-sigma, into the soil-grid
    /// update and its records.  Returns the samples as updated, their used wheels and K (NaN: none).
    fn update(
        &mut self,
        mut samples: Vec<Sample>,
        pending: PendingGate,
        scale_sigma: Option<&[f64]>,
        informing: Option<&[[bool; 4]]>,
    ) -> PyResult<Updated> {
        if let Some(on) = informing {
            for (s, on) in samples.iter_mut().zip(on) {
                for (f, &o) in s.informative.iter_mut().zip(on) {
                    *f &= o;
                }
            }
        }
        let (samples, used) = self.soil.gated(&mut self.gate.inner, samples, pending, scale_sigma)?;
        let ks = self
            .soil
            .reports()
            .iter()
            .map(|r| r.k.map_or(f64::NAN, |v| v[0]))
            .collect();
        Ok((samples, used, ks))
    }

    /// K and the slips of the soil stage back to the torque scale (its modelled motion resistance of
    /// the next samples, eq. 4), when the chain feeds it.
    fn feed(&mut self, vehicles: &[usize], ks: &[f64], slips: &[[f64; 4]]) {
        if let (true, Some(bank)) = (self.feed_soil, self.scale.as_deref_mut()) {
            for ((&g, &k), s) in vehicles.iter().zip(ks).zip(slips) {
                bank.feed_soil(g, k, *s);
            }
        }
    }

    /// The chain's whole step of `vehicles` by their checked samples `raws` (`ChainCore.step`): the
    /// stage steps in order, each stage's output the next one's input.
    fn step(mut self, vehicles: &[usize], raws: Vec<Raw>, informing: Option<&[[bool; 4]]>) -> PyResult<Done> {
        let stamps: Vec<f64> = raws.iter().map(|r| r.stamp).collect();
        let (estimates, scaled) = self.observe(vehicles, raws)?;
        let scale_sigma: Option<Vec<f64>> = scaled.map(|s| s.iter().map(|&(_, sd)| sd).collect());
        let rows: Vec<[f64; COLUMNS]> = estimates.iter().map(gate::row_of).collect();
        let rows: Vec<&[f64]> = rows.iter().map(|r| &r[..]).collect();
        let (samples, pending) = self.gate.run_rows(vehicles.to_vec(), stamps, &rows)?;
        let (samples, used, ks) = self.update(samples, pending, scale_sigma.as_deref(), informing)?;
        let slips: Vec<[f64; 4]> = samples.iter().map(|s| s.slip).collect();
        self.feed(vehicles, &ks, &slips);
        // the OCPs of the traction law the soil update inverts
        let ocp = ocp::bank(&ks, self.soil.constants()).map_err(PyValueError::new_err)?;
        Ok(Done {
            estimates,
            samples,
            used,
            ocp,
        })
    }
}

impl ChainCore {
    /// Its stage objects, borrowed for one call.
    fn hold<'py>(&self, py: Python<'py>) -> PyResult<Held<'py>> {
        Ok(Held {
            observer: self.observer.bind(py).try_borrow_mut()?,
            scale: self.scale.as_ref().map(|s| s.bind(py).try_borrow_mut()).transpose()?,
            gate: self.gate.bind(py).try_borrow_mut()?,
            soil: self.soil.bind(py).try_borrow_mut()?,
        })
    }
}

#[pymethods]
impl ChainCore {
    /// The chain over the stage objects of one bank of N vehicles: the `observer`, the slip `gate`,
    /// the `soil` bank (its records' settings given: `set_status`; the OCPs are of its traction
    /// law's constants), the torque `scale` (None: off) and whether K is fed back to it (`feed_soil`).
    #[new]
    #[pyo3(signature = (observer, gate, soil, scale=None, feed_soil=false))]
    fn py_new(
        py: Python<'_>,
        observer: Py<ObserverCore>,
        gate: Py<SlipGateBank>,
        soil: Py<SoilGridBank>,
        scale: Option<Py<TorqueScaleCore>>,
        feed_soil: bool,
    ) -> PyResult<Self> {
        let n = observer.bind(py).try_borrow_mut()?.bank_mut().filter.n_vehicles;
        let mut sizes = vec![
            ("gate", gate.bind(py).try_borrow()?.inner.memory.len()),
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
            scale,
            feed_soil,
        })
    }

    /// One step of the vehicles `idx` (None: all, in order), with the observer's inputs
    /// (`ObserverCore.step`'s ObserverInputs, the logged torques) and, where a map prior holds a wheel
    /// out of the belief it just started, `informing` (k, 4) (False: the wheel does not inform K;
    /// None: every wheel may): the stage steps of `observe`, `update` and `feed` in order, and the
    /// OCPs of K.  Every input is checked (ValueError naming the field) before any state changes.  An
    /// observer output that is not finite (which the stages' ObserverOutput message refuses) or a
    /// sample the soil update refuses raises after the scale and the observer have stepped, and
    /// leaves the gate as it was (the observer's clock is the core's: `ObserverCore.last_stamp`).
    #[pyo3(signature = (idx, inputs, informing=None))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        idx: Option<PyReadonlyArray1<'py, i64>>,
        inputs: Inputs<'py>,
        informing: Option<PyReadonlyArray2<'py, bool>>,
    ) -> PyResult<ChainOut<'py>> {
        let mut held = self.hold(py)?;
        let (vehicles, raws) = held.observer.raws(idx.as_ref(), &inputs)?;
        let informing = informing.map(|a| quads("informing", &a, vehicles.len())).transpose()?;
        let stages = held.stages(self.feed_soil);
        // the GIL is released for the step: a Zenoh callback can hand over the next samples meanwhile (the
        // stage objects stay borrowed: another thread that reads one of them now gets a RuntimeError, not a
        // half-stepped state)
        let done = py.detach(move || stages.step(&vehicles, raws, informing.as_deref()))?;
        let col = |f: fn(&ocp::Ocp) -> f64| done.ocp.iter().map(f).collect::<Vec<f64>>().into_pyarray(py);
        Ok((
            blocks(py, &done.estimates),
            gate_arrays(py, &done.samples)?,
            report_arrays(py, held.soil.reports(), &done.used),
            (col(|x| x.mu_t), col(|x| x.s_t), col(|x| x.s_e), col(|x| x.te_at_s_e)),
        ))
    }

    /// The observer stage of `step` alone (the observer service's): the torque scale and the observer
    /// on the vehicles `idx` (None: all) and their inputs.  Returns the observer's blocks (as
    /// `ObserverCore.step`) and, once the scale has left its prior, k's mean and its relative 1-sigma
    /// (k,) each (None: at the prior, the torques as logged).
    fn observe<'py>(
        &self,
        py: Python<'py>,
        idx: Option<PyReadonlyArray1<'py, i64>>,
        inputs: Inputs<'py>,
    ) -> PyResult<(StepOut<'py>, Option<(Arr<'py>, Arr<'py>)>)> {
        let mut held = self.hold(py)?;
        let (vehicles, raws) = held.observer.raws(idx.as_ref(), &inputs)?;
        let (estimates, scaled) = held.stages(self.feed_soil).observe(&vehicles, raws)?;
        let scaled = scaled.map(|s| {
            let (m, sd): (Vec<f64>, Vec<f64>) = s.into_iter().unzip();
            (m.into_pyarray(py), sd.into_pyarray(py))
        });
        Ok((blocks(py, &estimates), scaled))
    }

    /// The soil stage of `step` alone (the soil-strength service's): the slip gate on the packed
    /// observer outputs `rows` (k, `SlipGateBank.columns`, or one message's numbers) of the vehicles
    /// `idx` at `stamp` (k,), each wheel's map-prior `informing` flag (None: every wheel may inform
    /// K), and the update with the scale's relative 1-sigma (None: the prior).  Returns the gate's
    /// arrays (as `SlipGateBank.step`) and the records (as `SoilGridBank.report`).
    #[pyo3(signature = (idx, stamp, rows, scale_sigma=None, informing=None))]
    fn update<'py>(
        &self,
        py: Python<'py>,
        idx: PyReadonlyArray1<'py, i64>,
        stamp: PyReadonlyArray1<'py, f64>,
        rows: Bound<'py, PyAny>,
        scale_sigma: Option<PyReadonlyArray1<'py, f64>>,
        informing: Option<PyReadonlyArray2<'py, bool>>,
    ) -> PyResult<(GateArrays<'py>, ReportArrays<'py>)> {
        let mut held = self.hold(py)?;
        let (samples, pending) = held.gate.run(&idx, &stamp, &rows)?;
        let k = samples.len();
        let sig = scale_sigma.map(|a| column("scale_sigma", &a, k)).transpose()?;
        let informing = informing.map(|a| quads("informing", &a, k)).transpose()?;
        let (samples, used, _) =
            held.stages(self.feed_soil)
                .update(samples, pending, sig.as_deref(), informing.as_deref())?;
        Ok((
            gate_arrays(py, &samples)?,
            report_arrays(py, held.soil.reports(), &used),
        ))
    }

    /// The soil stage's K (k,) (NaN: none reported, the last is kept) and slips (k, 4) of the vehicles
    /// `idx` back to the torque scale, as `step` feeds them: the next samples' modelled motion
    /// resistance (eq. 4) is at them.  Nothing when the chain does not feed the scale.
    fn feed(
        &self,
        py: Python<'_>,
        idx: PyReadonlyArray1<'_, i64>,
        k: PyReadonlyArray1<'_, f64>,
        slip: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<()> {
        let mut held = self.hold(py)?;
        let vehicles = args::vehicles(Some(&idx), held.observer.bank_mut().filter.n_vehicles)?;
        let n = vehicles.len();
        let ks = column("k", &k, n)?;
        let slips = quads("slip", &slip, n)?;
        held.stages(self.feed_soil).feed(&vehicles, &ks, &slips);
        Ok(())
    }

    /// Whether `step` and `feed` pass K back to the torque scale.
    #[getter]
    fn feeds_soil(&self) -> bool {
        self.feed_soil && self.scale.is_some()
    }
}
