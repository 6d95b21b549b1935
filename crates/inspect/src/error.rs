//! The error type of trim-inspect: every variant says what was wrong and where.

use trim_geom::{ContourId, GeomError};

/// Result alias for trim-inspect.
pub type Result<T, E = InspectError> = std::result::Result<T, E>;

/// Everything that can go wrong in an inspection. Bad input is refused, never measured as if
/// it were good.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InspectError {
    /// A cloud that must hold points is empty.
    #[error("{what} holds no points")]
    Empty {
        /// Which input ("scan", "CAD mesh").
        what: String,
    },
    /// An input value is NaN or infinite.
    #[error("{what}: point {index} is not finite ({value})")]
    NonFinite {
        /// Which input ("scan", "path contour 3").
        what: String,
        /// The point's index in that input.
        index: usize,
        /// The offending point, as printed.
        value: String,
    },
    /// A setting is out of range.
    #[error("setting `{name}`: {message}")]
    InvalidSetting {
        /// The setting's key (`band_mm`, `tolerance_um`, …).
        name: &'static str,
        /// What is wrong and what is accepted.
        message: String,
    },
    /// A contour cannot be measured.
    #[error("contour {contour}: {message}")]
    Contour {
        /// The contour's id.
        contour: ContourId,
        /// What is wrong.
        message: String,
    },
    /// The registration does not describe the path inspected.
    #[error("the registration's quality report has no contour {contour}")]
    MissingBound {
        /// The contour's id.
        contour: ContourId,
    },
    /// A geometry error (a mesh or a contour trim-geom refused).
    #[error(transparent)]
    Geom(#[from] GeomError),
}
