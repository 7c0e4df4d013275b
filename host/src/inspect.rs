//! `strata inspect`: format, counts, bounding box and closedness of a model.
//!
//! PLACEHOLDER: being implemented (issue 2).

use std::path::Path;

/// Runs `strata inspect MODEL [--json]`.
pub fn run(_model: &Path, _json: bool) -> Result<(), String> {
    Err("inspect: not implemented yet".into())
}
