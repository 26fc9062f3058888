//! What a vehicle's soil record says after a step (docs/method.md §9, §11-13, §16-17): K and its
//! band from the bank's step, held between informative samples and withdrawn after
//! `expire_after` (never a drifting number), and the status with the code of its reason.  The
//! reason text stays in Python (soilocp.estimation.soil_strength), made from the code and the
//! numbers of [`Report::args`].

use crate::codes::reason;
use crate::codes::status::{HOLDING, MODEL_MISMATCH, NOT_OBSERVABLE, NO_ESTIMATE, OK, UNCERTAIN};
use crate::soil::bank::{Sample, SoilGridBank, Step, HELD, UNDETERMINED, USED};
use crate::soil::params::Params;

/// The settings the status reads (crate::soil::params), and the grid's ln K span.
#[derive(Clone, Debug, PartialEq)]
pub struct StatusParams {
    pub p: Params,
    /// ln K span of the grid: the band's cap ("undetermined")
    pub span: f64,
}

/// One vehicle's record state: the last informative update's stamp, the estimate then (K, its
/// 1-sigma, ln K's), and since when the data lean to a torque scale the state does not assume.
#[derive(Clone, Copy, Debug)]
pub struct Hold {
    pub last_update: Option<f64>,
    pub held: Option<[f64; 3]>,
    pub lean_since: f64,
}

impl Default for Hold {
    fn default() -> Self {
        Hold {
            last_update: None,
            held: None,
            lean_since: f64::NAN,
        }
    }
}

/// A step's record of one vehicle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Report {
    pub status: u8,
    pub reason: u8,
    pub args: [f64; 4],
    /// K, its 1-sigma and ln K's, if K is reported
    pub k: Option<[f64; 3]>,
    pub last_update: Option<f64>,
}

/// What the status reads of a sample besides the bank's step.
#[derive(Clone, Copy, Debug)]
pub struct Seen {
    pub stamp: f64,
    pub ground_stale: bool,
    pub identifiable: bool,
    pub unusable: [i64; 4],
    /// the axle check's window: time over the threshold, all the judged time
    pub axle_window: (f64, f64),
    /// the torque scale's 1-sigma now
    pub scale_prior: f64,
}

impl StatusParams {
    /// The held / withdrawn / uncertain logic of the record (§9: hold, flagged; never drift):
    /// (status, reason, args, (K, K 1-sigma, ln K 1-sigma) if any).
    fn hold(&self, h: &mut Hold, stamp: f64, k: f64, k_std: f64, log_std: f64) -> (u8, u8, [f64; 4], Option<[f64; 3]>) {
        let Some(last) = h.last_update else {
            return (NO_ESTIMATE, reason::NOT_YET, [0.0; 4], None);
        };
        let age = stamp - last;
        if age < 0.0 {
            // stamps went backwards (a restarted source): the old update time means nothing
            h.last_update = None;
            h.held = None;
            return (NO_ESTIMATE, reason::STAMP_BACKWARDS, [0.0; 4], None);
        }
        if age > self.p.hold_after + self.p.expire_after {
            return (NO_ESTIMATE, reason::WITHDRAWN, [age, 0.0, 0.0, 0.0], None);
        }
        let (mut k, mut k_std, mut log_std) = (k, k_std, log_std);
        match h.held {
            Some(held) if age != 0.0 => {
                // no information this sample: the last informed estimate, with a band never
                // narrower than the soil's own drift since the update allows (q_log_k per sqrt(s))
                k = held[0];
                log_std = log_std.max(held[2].hypot(self.p.q_log_k * age.sqrt()));
                k_std = k_std.max(held[1]).max(k * log_std.sinh());
            }
            _ => h.held = Some([k, k_std, log_std]),
        }
        let est = Some([k, k_std, log_std]);
        if age > self.p.hold_after {
            return (HOLDING, reason::HOLDING, [age, 0.0, 0.0, 0.0], est);
        }
        if log_std > self.p.uncertain_log_sigma {
            return (UNCERTAIN, reason::WIDE, [log_std, 0.0, 0.0, 0.0], est);
        }
        (OK, reason::NONE, [0.0; 4], est)
    }

    /// The record of one vehicle after its step `s` (soil/bank.rs), from its sample's `seen`.
    pub fn report(&self, h: &mut Hold, s: &Step, seen: &Seen) -> Report {
        let st = seen.stamp;
        if s.informed {
            h.last_update = Some(st);
        }
        let (log_stat, k_med) = (s.log_stat, s.k_report);
        let [evidence, nis_sum, s_kk, _, s_ks] = s.stats;
        let [sys_scale, c_mean, c_std] = s.scale;
        let prior = seen.scale_prior;
        // how long the data have leant to a wrong torque constant
        if (c_mean - 1.0).abs() <= (2.0 * c_std).max(prior) {
            h.lean_since = f64::NAN;
        } else if h.lean_since.is_nan() || h.lean_since > st {
            h.lean_since = st; // none yet (NaN), or a restarted clock: it starts now
        }
        let sys_radius = if s_kk > 0.0 {
            self.p.radius_sigma * s_ks.abs() / s_kk
        } else {
            0.0
        };
        let axle_off = s.axle.mismatch;
        // axles that disagree: the truth is usually near one of them, so their distance is a
        // systematic term; the band is capped at the grid's whole ln K span ("undetermined")
        let sys_axle = if axle_off {
            (s.axle.theta_front - s.axle.theta_rear).abs()
        } else {
            0.0
        };
        let sys = sys_scale.hypot(sys_radius).hypot(sys_axle).min(self.span);
        // f64::min: a NaN term gives the capped band (undetermined), never a NaN one read as ok
        let log_std = log_stat.hypot(sys).min(self.span);
        let k_std = k_med * log_std.sinh();
        let (mut status, mut why, mut args, est) = self.hold(h, st, k_med, k_std, log_std);
        if status == UNCERTAIN && sys > log_stat && sys_scale >= sys_radius {
            why = if st - h.lean_since >= self.p.evidence_window {
                reason::SYSTEMATIC_SCALE_CALIBRATE
            } else {
                reason::SYSTEMATIC_SCALE
            };
            args = [log_std, prior, c_mean, 0.0];
        } else if status == UNCERTAIN && sys > log_stat {
            why = reason::SYSTEMATIC_RADIUS;
            args = [log_std, 0.0, 0.0, 0.0];
        }
        let nis = if evidence > 0.0 { nis_sum / evidence } else { 0.0 };
        let used = s.wheel.iter().any(|f| f & USED != 0);
        let any_flag = |flag: u8| s.wheel.iter().any(|f| f & flag != 0);
        let since = h.last_update.map_or(f64::NAN, |t| st - t);
        if !seen.identifiable {
            (status, why, args) = (NOT_OBSERVABLE, reason::NOT_IDENTIFIABLE, [0.0; 4]);
        } else if est.is_some() && axle_off {
            (status, why) = (MODEL_MISMATCH, reason::AXLES);
            args = [s.axle.theta_front, s.axle.theta_rear, s.axle.z, 0.0];
        } else if est.is_some() && evidence >= self.p.mismatch_min_evidence && nis > self.p.mismatch_nis {
            (status, why, args) = (MODEL_MISMATCH, reason::NIS, [nis, 0.0, 0.0, 0.0]);
        } else if est.is_some() && s.floor_cdf > 0.5 {
            (status, why, args) = (MODEL_MISMATCH, reason::BELOW_FLOOR, [0.0; 4]);
        } else if (status == NO_ESTIMATE || status == HOLDING) && any_flag(HELD) && !used {
            // slip would inform but its readings are held: a held K stays held (flagged, with its
            // age), naming why nothing updates it; without one the data determine no K now
            status = if status == HOLDING { HOLDING } else { NOT_OBSERVABLE };
            why = if seen.ground_stale {
                reason::GROUND_STALE
            } else {
                reason::READINGS_HELD
            };
            args = [since, 0.0, 0.0, 0.0];
        } else if (status == NO_ESTIMATE || status == HOLDING) && any_flag(UNDETERMINED) && !used {
            status = if status == HOLDING { HOLDING } else { NOT_OBSERVABLE };
            (why, args) = (reason::UNDETERMINED, [0.0; 4]);
        }
        if status == OK {
            (status, why, args) = self.vouch(h, seen, st, evidence, c_mean);
        }
        if seen.identifiable && seen.unusable.iter().any(|&c| c != 0) {
            (status, why, args) = out_of_model(status, why, args, seen, used, est.is_some(), h, st);
        }
        // not observable: the data do not determine K now; below the floor: the posterior is mostly
        // beneath the weakest soil, so its median and spread are those of a truncated belief, not a
        // band that holds the truth: no number either
        let below_floor = status == MODEL_MISMATCH && why == reason::BELOW_FLOOR;
        let k = if status == NOT_OBSERVABLE || below_floor {
            None
        } else {
            est
        };
        Report {
            status,
            reason: why,
            args,
            k,
            last_update: h.last_update,
        }
    }

    /// Status of an estimate whose band is narrow enough for ok: ok only where its own checks
    /// vouch for it (docs/robustness.md, "ok means ok"), else uncertain naming what they lack (the
    /// data lean to another torque scale; the axles read different soils for most of the window
    /// though one does not inform now; too little evidence since the window restarted).
    fn vouch(&self, h: &Hold, seen: &Seen, st: f64, evidence: f64, c_mean: f64) -> (u8, u8, [f64; 4]) {
        let (over, weight) = seen.axle_window;
        if !h.lean_since.is_nan() && h.lean_since <= st {
            return (UNCERTAIN, reason::LEANS, [c_mean, seen.scale_prior, 0.0, 0.0]);
        }
        let enough = 1.0 - (-self.p.mismatch_min_evidence / self.p.evidence_window).exp();
        if self.p.axle_mismatch_z > 0.0 && weight >= enough && over > 0.5 * weight {
            return (UNCERTAIN, reason::AXLE_WINDOW, [0.0; 4]);
        }
        if evidence < self.p.mismatch_min_evidence {
            return (UNCERTAIN, reason::EVIDENCE, [evidence, 0.0, 0.0, 0.0]);
        }
        (OK, reason::NONE, [0.0; 4])
    }
}

/// A sample with wheels the longitudinal model does not describe (§17): never ok.  A skid turn:
/// not observable while it lasts; no wheel used: the last estimate held, flagged, with its age;
/// other wheels used: uncertain, K from them.  A model mismatch or not observable of other causes
/// keeps its reason, a skid turn aside.
#[allow(clippy::too_many_arguments)]
fn out_of_model(
    status: u8,
    why: u8,
    args: [f64; 4],
    seen: &Seen,
    used: bool,
    have_k: bool,
    h: &Hold,
    st: f64,
) -> (u8, u8, [f64; 4]) {
    if seen.unusable.contains(&(crate::soil::usability::SKID_TURN as i64)) {
        return (NOT_OBSERVABLE, reason::OUT_SKID, [0.0; 4]);
    }
    if status == MODEL_MISMATCH || status == NOT_OBSERVABLE {
        return (status, why, args);
    }
    if !used {
        if !have_k {
            return (NOT_OBSERVABLE, reason::OUT_NO_WHEEL, [0.0; 4]);
        }
        let age = h.last_update.map_or(0.0, |t| st - t);
        return (HOLDING, reason::OUT_HOLDING, [age, 0.0, 0.0, 0.0]);
    }
    if status == OK {
        return (UNCERTAIN, reason::OUT_OTHERS, [0.0; 4]);
    }
    (status, why, args)
}

/// N vehicles' record states and the settings.
#[derive(Clone, Debug)]
pub struct StatusBank {
    pub cfg: StatusParams,
    pub holds: Vec<Hold>,
}

impl StatusBank {
    /// The records' state of `n` vehicles with the settings `p` and the grid's ln K `span`.
    pub fn new(p: Params, span: f64, n: usize) -> Result<StatusBank, String> {
        if !(span.is_finite() && span > 0.0) {
            return Err(format!("status: the grid's ln K span {span} must be finite and > 0"));
        }
        Ok(StatusBank {
            cfg: StatusParams { p, span },
            holds: vec![Hold::default(); n],
        })
    }

    /// The records of a step's vehicles: `steps` are `bank.step(samples)`'s, in order.
    pub fn report(&mut self, bank: &SoilGridBank, samples: &[Sample], steps: &[Step]) -> Vec<Report> {
        samples
            .iter()
            .zip(steps)
            .map(|(smp, step)| {
                let b = &bank.vehicles[smp.vehicle];
                let seen = Seen {
                    stamp: smp.stamp,
                    ground_stale: smp.ground_stale,
                    identifiable: smp.identifiable,
                    unusable: smp.unusable,
                    axle_window: (b.axles.over, b.axles.weight),
                    scale_prior: b.scale_prior,
                };
                self.cfg.report(&mut self.holds[smp.vehicle], step, &seen)
            })
            .collect()
    }
}
