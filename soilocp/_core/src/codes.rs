//! The statuses and reason codes of a soil / OCP record, each once: its code (the index in its
//! table), its name (what a record carries), who sets it and a one-line meaning.  The Python
//! schemas, the reason texts, the next steps and the docs take their names from these tables
//! (`soilocp._core.status_codes()`, `soilocp._core.reason_codes()`).

/// Who sets a status or reason code: the soil stage (this crate's `soil::status`), the live
/// publisher (inputs stopped) or the OCP stage (where the OCPs' traction curve comes from).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SetBy {
    Soil,
    Publisher,
    Ocp,
}

impl SetBy {
    /// The name the Python side sees.
    pub const fn name(self) -> &'static str {
        match self {
            SetBy::Soil => "soil",
            SetBy::Publisher => "publisher",
            SetBy::Ocp => "ocp",
        }
    }
}

/// One status or reason code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Code {
    pub name: &'static str,
    pub set_by: SetBy,
    pub meaning: &'static str,
}

/// A table of codes: a module with one `u8` constant per code (its index) and `TABLE`, the codes
/// in order, written once.
macro_rules! code_table {
    ($(#[$doc:meta])* $module:ident { $($konst:ident = $name:literal, $by:ident, $meaning:literal;)+ }) => {
        $(#[$doc])*
        pub mod $module {
            use super::{Code, SetBy};

            #[allow(clippy::upper_case_acronyms, non_camel_case_types)]
            #[repr(u8)]
            enum Index {
                $($konst),+
            }

            $(
                #[doc = $meaning]
                pub const $konst: u8 = Index::$konst as u8;
            )+

            /// Every code, in the order of the constants.
            pub const TABLE: &[Code] = &[$(Code { name: $name, set_by: SetBy::$by, meaning: $meaning }),+];

            /// The name of code `c`.
            pub fn name(c: u8) -> &'static str {
                TABLE[c as usize].name
            }
        }
    };
}

code_table! {
    /// The status of a record.
    status {
        OK = "ok", Soil, "K is confirmed: within +-30 % at 2 sigma, and every model check vouches for it";
        UNCERTAIN = "uncertain", Soil, "K is reported with a wide band; the reason says why";
        HOLDING = "holding", Soil, "nothing informs K now: the last estimate is held, with its age";
        NO_ESTIMATE = "no_estimate", Soil, "no K: none yet, or withdrawn";
        NOT_OBSERVABLE = "not_observable", Soil, "the data do not determine K now";
        MODEL_MISMATCH = "model_mismatch", Soil,
            "the model does not explain the data: the traction curve, or the axles read different soils";
        STALE = "stale", Publisher, "live publisher: the inputs stopped";
    }
}

code_table! {
    /// The machine-readable reason of a record (the record's `reason` words it with its numbers).
    reason {
        NONE = "none", Soil, "no reason: the estimate is ok (or a record written before reason codes existed)";
        NOT_YET = "not_yet", Soil, "slip has not been informative yet: no K so far";
        STAMP_BACKWARDS = "stamp_backwards", Soil, "the stamps went backwards (source restarted): estimate withdrawn";
        WITHDRAWN = "withdrawn", Soil,
            "slip uninformative for longer than hold_after + expire_after: estimate withdrawn";
        HOLDING = "holding", Soil, "slip uninformative now: the last K is held";
        WIDE = "wide", Soil, "K's band is wider than uncertain_log_sigma: K poorly determined";
        SYSTEMATIC_SCALE = "systematic_scale", Soil, "K's band is mostly the torque constant's uncertainty";
        SYSTEMATIC_SCALE_CALIBRATE = "systematic_scale_calibrate", Soil,
            "K's band is mostly the torque constant's, and the data suggest a wrong constant";
        SYSTEMATIC_RADIUS = "systematic_radius", Soil,
            "K's band is mostly the wheel radius's uncertainty at these small slips";
        NOT_IDENTIFIABLE = "not_identifiable", Soil,
            "no independent ground speed (or a log that cannot identify K): slip and K not identifiable";
        AXLES = "axles", Soil,
            "the front and rear axles read different soils (normal forces or an axle's torque constant off)";
        NIS = "nis", Soil, "the traction curve does not explain the (slip, traction) pairs at any K";
        BELOW_FLOOR = "below_floor", Soil,
            "traction below what the weakest soil gives at this slip (torque scale or units?): no K";
        GROUND_STALE = "ground_stale", Soil, "slip is informative but the ground speed reading is stale: the last K held, or none";
        READINGS_HELD = "readings_held", Soil,
            "slip is informative but the wheel speed / torque readings are held (refresh too slow): the last K held, or none";
        UNDETERMINED = "undetermined", Soil,
            "slip is informative but the torque balance does not determine gross traction: the last K held, or none";
        LEANS = "leans", Soil,
            "the data lean to another torque scale, which a drive at constant speed cannot tell from K";
        AXLE_WINDOW = "axle_window", Soil, "the axles read different soils for most of the evidence window";
        EVIDENCE = "evidence", Soil, "K from too few seconds of informative slip for the model checks: not yet ok";
        OUT_SKID = "out_skid", Soil,
            "wheels in a skid turn (outside the longitudinal model): no K while it lasts";
        OUT_NO_WHEEL = "out_no_wheel", Soil,
            "no wheel inside the longitudinal model (stall, slip beyond eq. 1, stopped unpowered)";
        OUT_HOLDING = "out_holding", Soil, "no wheel inside the longitudinal model: the last K is held";
        OUT_OTHERS = "out_others", Soil, "some wheels outside the longitudinal model: K from the others";
        STALE = "stale", Publisher, "live publisher: no input for longer than stale_timeout_s";
        CURVE_UNCHECKED = "curve_unchecked", Ocp,
            "OCP record: the OCPs rest on the paper's traction curve, which nobody checked for this wheel";
        CURVE_LEARNT = "curve_learnt", Ocp,
            "OCP record: the OCPs are the traction curve this drive showed, not checked by a calibration";
        CURVE_EXTRAPOLATED = "curve_extrapolated", Ocp,
            "OCP record: K is beyond the soils the wheel's calibration was fitted over";
        OCP_WIDE = "ocp_wide", Ocp,
            "OCP record: K's band carries into mu_T or S_T wider than the controller's tolerance (curve.ok_mu_t, ok_s_t)";
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn names_are_unique_words_and_meanings_one_line() {
        for table in [status::TABLE, reason::TABLE] {
            let names: HashSet<_> = table.iter().map(|c| c.name).collect();
            assert_eq!(names.len(), table.len());
            for c in table {
                assert!(
                    c.name.chars().all(|ch| ch.is_ascii_lowercase() || ch == '_'),
                    "{}",
                    c.name
                );
                assert!(!c.meaning.is_empty() && !c.meaning.contains('\n'), "{}", c.name);
            }
        }
    }

    #[test]
    fn constants_index_their_rows_and_the_soil_codes_come_first() {
        assert_eq!(status::name(status::MODEL_MISMATCH), "model_mismatch");
        assert_eq!(reason::name(reason::OUT_OTHERS), "out_others");
        assert_eq!(reason::name(reason::NONE), "none");
        // the soil stage's codes are a prefix of each table: its records index them directly
        for table in [status::TABLE, reason::TABLE] {
            let first_other = table.iter().position(|c| c.set_by != SetBy::Soil).unwrap();
            assert!(table[first_other..].iter().all(|c| c.set_by != SetBy::Soil));
        }
    }
}
