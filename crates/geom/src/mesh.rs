//! Triangle meshes (filled by the formats work).
