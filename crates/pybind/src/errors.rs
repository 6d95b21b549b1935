//! One exception hierarchy for every Rust error that reaches Python.
//!
//! ```text
//! TrimError(Exception)
//! ├── FileFormatError      a file could not be read or parsed (names the file and line)
//! ├── RegistrationError    registration failed (no overlap, degenerate, too few points)
//! ├── PlanningError        planning refused the input or found no valid plan
//! └── InternalError        a bug: please report it
//! ```
//! Wrong argument shapes, dtypes, non-finite values and out-of-range options raise the
//! built-in `ValueError` instead, naming the argument. What the library warns of (a text file
//! whose last line has no line end) is a `TrimWarning(UserWarning)`, through `warnings.warn`.

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use trim_cell::ScansError;
use trim_geom::GeomError;
use trim_register::RegisterError;

create_exception!(
    trimctl,
    TrimError,
    PyException,
    "Base class of every trimctl error."
);
create_exception!(
    trimctl,
    FileFormatError,
    TrimError,
    "A file could not be read, parsed or written."
);
create_exception!(
    trimctl,
    RegistrationError,
    TrimError,
    "Registration failed."
);
create_exception!(
    trimctl,
    PlanningError,
    TrimError,
    "Planning refused the input or found no valid plan."
);
create_exception!(
    trimctl,
    InternalError,
    TrimError,
    "An internal error (a bug): please report it."
);

create_exception!(
    trimctl,
    TrimWarning,
    PyUserWarning,
    "What trimctl warns of: the work went on (a text file read whose last line has no line end)."
);

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("TrimError", py.get_type::<TrimError>())?;
    m.add("FileFormatError", py.get_type::<FileFormatError>())?;
    m.add("RegistrationError", py.get_type::<RegistrationError>())?;
    m.add("PlanningError", py.get_type::<PlanningError>())?;
    m.add("InternalError", py.get_type::<InternalError>())?;
    m.add("TrimWarning", py.get_type::<TrimWarning>())?;
    Ok(())
}

/// A `ValueError` naming the argument.
pub fn value_error(name: &str, message: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("{name}: {message}"))
}

/// Maps a geometry error: file problems to `FileFormatError`, bad values to `ValueError`.
pub fn geom_error(e: GeomError) -> PyErr {
    match e {
        GeomError::Io { .. }
        | GeomError::Parse { .. }
        | GeomError::UnsupportedFormat { .. }
        | GeomError::NoPoints { .. } => FileFormatError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// Maps a registration error: bad settings and values to `ValueError`, file problems to
/// `FileFormatError`, the rest to `RegistrationError`.
pub fn register_error(e: RegisterError) -> PyErr {
    match e {
        RegisterError::Geom(g) => geom_error(g),
        RegisterError::InvalidSetting { .. }
        | RegisterError::NonFinite { .. }
        | RegisterError::LengthMismatch { .. } => PyValueError::new_err(e.to_string()),
        other => RegistrationError::new_err(other.to_string()),
    }
}

/// Maps an error of scans at poses: a poses or scan file that cannot be read or parsed to
/// `FileFormatError`, bad scans and poses given in memory to `ValueError`. The message keeps
/// its cause (`scans[1] through [calibration] at its pose: transformed point 3 is not finite`).
pub fn scans_error(e: ScansError) -> PyErr {
    let mut message = e.to_string();
    let mut cause = std::error::Error::source(&e);
    while let Some(c) = cause {
        message.push_str(&format!(": {c}"));
        cause = c.source();
    }
    match e {
        ScansError::ReadPoses { .. }
        | ScansError::EmptyPoses { .. }
        | ScansError::PosesHeader { .. }
        | ScansError::PosesColumns { .. }
        | ScansError::PosesValue { .. }
        | ScansError::PosesScan { .. }
        | ScansError::ReadScan { .. } => FileFormatError::new_err(message),
        _ => PyValueError::new_err(message),
    }
}

/// Refuses the keywords a function does not take (its `**renamed`) with `TypeError`, naming
/// the new name of one that was renamed (`voxel` → `voxel_mm`: options carry their unit). The
/// Python package's `_refuse_renamed` says the same.
pub fn refuse_renamed(
    function: &str,
    given: Option<&Bound<'_, pyo3::types::PyDict>>,
    renamed: &[(&str, &str)],
) -> PyResult<()> {
    let Some(key) = given.and_then(|g| g.keys().into_iter().next()) else {
        return Ok(());
    };
    let key: String = key.extract()?;
    let message = match renamed.iter().find(|(old, _)| *old == key) {
        Some((_, new)) => {
            format!("{function}(): {key}= was renamed {new}= (the unit is in the name)")
        }
        None => format!("{function}() got an unexpected keyword argument '{key}'"),
    };
    Err(pyo3::exceptions::PyTypeError::new_err(message))
}
