//! Python bindings (filled by the bindings issue).
