//! trim-io (filled by its issue).
