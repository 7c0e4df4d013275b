//! Helpers shared by the integration tests.

use std::path::PathBuf;

/// The shared test models (`../shared/models` beside the checkout, described by its README.md).
///
/// `None` when the folder is absent, so tests can skip with a message; with the environment
/// variable `CI` set the models are required and their absence panics.
#[allow(dead_code)] // not every test crate that includes this module uses every helper
pub fn shared_models() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/models");
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var_os("CI").is_some() {
        panic!("CI is set but the shared test models are missing at {}", dir.display());
    }
    eprintln!("skipping: shared test models not found at {}", dir.display());
    None
}
