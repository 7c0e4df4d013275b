//! `strata slice`: run the core slicer on the host and write contours.
//!
//! PLACEHOLDER: being implemented (issue 3).

use std::path::PathBuf;

/// Options of `strata slice`.
#[derive(Debug, clap::Args)]
pub struct SliceArgs {
    /// The STL model.
    pub model: PathBuf,
    /// Write the contours of every layer as JSON (mm).
    #[arg(long)]
    pub contours_json: Option<PathBuf>,
    /// Write one SVG per layer into this directory.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

/// Runs `strata slice`.
pub fn run(_args: &SliceArgs) -> Result<(), String> {
    Err("slice: not implemented yet".into())
}
