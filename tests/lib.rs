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

/// The real data the tests read, in the repository (`tests/data`, see its README).
#[must_use]
pub fn test_data() -> PathBuf {
    workspace_root().join("tests/data")
}
