//! `soilocp._core.settings_schema(group)`: a settings struct's declarations (crate::settings), from
//! which the Python side builds its validated, documented pydantic model.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::curve::Params as CurveParams;
use crate::observer::settings::ObserverSettings;
use crate::settings::{Audience, Kind, Spec};
use crate::soil::params::Params as SoilParams;
use crate::soil::usability::Limits;
use crate::torque_scale::params::Settings as TorqueScaleSettings;

/// One declaration as Python sees it: (name, "float" | "int" | "choice", default (a choice's: its
/// index in the choices), {"gt" | "ge" | "lt" | "le": bound}, unit, "user" | "internal",
/// description, the choices (empty for a number)).
type Row = (
    &'static str,
    &'static str,
    f64,
    Vec<(&'static str, f64)>,
    &'static str,
    &'static str,
    String,
    Vec<&'static str>,
);

fn row(s: &Spec) -> Row {
    let b = s.bounds;
    let bounds = [("gt", b.gt), ("ge", b.ge), ("lt", b.lt), ("le", b.le)]
        .into_iter()
        .filter_map(|(k, v)| v.map(|v| (k, v)))
        .collect();
    let kind = match s.kind {
        Kind::Float => "float",
        Kind::Int => "int",
        Kind::Choice => "choice",
    };
    let audience = match s.audience {
        Audience::User => "user",
        Audience::Internal => "internal",
    };
    let doc = s.doc.split_whitespace().collect::<Vec<_>>().join(" ");
    (
        s.name,
        kind,
        s.default,
        bounds,
        s.unit,
        audience,
        doc,
        s.choices.to_vec(),
    )
}

/// The declarations of the settings group `group` ("soil", "torque_scale", "usability", "curve",
/// "observer"), in order.
#[pyfunction]
pub fn settings_schema(group: &str) -> PyResult<Vec<Row>> {
    let specs: &[Spec] = match group {
        SoilParams::GROUP => SoilParams::SPECS,
        TorqueScaleSettings::GROUP => TorqueScaleSettings::SPECS,
        Limits::GROUP => Limits::SPECS,
        CurveParams::GROUP => CurveParams::SPECS,
        ObserverSettings::GROUP => ObserverSettings::SPECS,
        other => {
            return Err(PyValueError::new_err(format!(
                "no settings group {other:?} (have: soil, torque_scale, usability, curve, observer)"
            )))
        }
    };
    Ok(specs.iter().map(row).collect())
}
