//! End-to-end tests across the trimctl crates live in `tests/*.rs`; this library holds helpers
//! they share.

use std::path::PathBuf;

/// The workspace root.
#[must_use]
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(PathBuf::from)
        .unwrap_or_default()
}

/// The shared real-data folder (`../shared/data` beside the checkout).
#[must_use]
pub fn shared_data() -> PathBuf {
    workspace_root().join("../shared/data")
}
