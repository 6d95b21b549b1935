//! File formats (filled by the formats work).
