//! trim-register (filled by its issue).
