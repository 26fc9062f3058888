//! `soilocp._core.status_codes()` and `reason_codes()`: the records' statuses and reason codes
//! (crate::codes), the one definition the Python schemas and texts are made from.

use pyo3::prelude::*;

use crate::codes::{reason, status, Code};

fn rows(table: &[Code]) -> Vec<(&'static str, &'static str, &'static str)> {
    table.iter().map(|c| (c.name, c.set_by.name(), c.meaning)).collect()
}

/// The statuses of a record, in code order: (name, set by "soil" | "publisher" | "ocp", meaning).
#[pyfunction]
pub fn status_codes() -> Vec<(&'static str, &'static str, &'static str)> {
    rows(status::TABLE)
}

/// The reason codes of a record, in code order: (name, set by "soil" | "publisher" | "ocp", meaning).
#[pyfunction]
pub fn reason_codes() -> Vec<(&'static str, &'static str, &'static str)> {
    rows(reason::TABLE)
}
