//! The error type of trim-geom: every variant says what was wrong and where.

use std::fmt;
use std::path::PathBuf;

/// Result alias for trim-geom.
pub type Result<T, E = GeomError> = std::result::Result<T, E>;

/// Where in a file a problem is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Location {
    /// A 1-based text line.
    Line(usize),
    /// A 0-based element (vertex, point, facet) of a binary or text body.
    Element(usize),
    /// The file header.
    Header,
    /// A byte offset from the start of the file.
    Byte(u64),
    /// The end of the file (something was missing).
    End,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(n) => write!(f, "line {n}"),
            Location::Element(n) => write!(f, "element {n}"),
            Location::Header => write!(f, "header"),
            Location::Byte(n) => write!(f, "byte {n}"),
            Location::End => write!(f, "end of file"),
        }
    }
}

/// Everything that can go wrong in trim-geom.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GeomError {
    /// The file could not be opened, read or written.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error (in the message, so not also its `source`: a chain
        /// printed it twice, "No such file or directory (os error 2): No such file or
        /// directory (os error 2)").
        error: std::io::Error,
    },
    /// The file's content is malformed at a known place.
    #[error("{}: {at}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        at: Location,
        /// What was wrong.
        message: String,
    },
    /// The file's format is not one trimctl reads (by extension or by content).
    #[error("{}: unsupported format: {message}", path.display())]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
        /// What was found.
        message: String,
    },
    /// A point-cloud file holds no points (an empty XYZ, a PLY with 0 vertices, a PCD with 0
    /// points): nothing that needs points can use it.
    #[error("{}: no points", path.display())]
    NoPoints {
        /// The file.
        path: PathBuf,
    },
    /// An in-memory value is NaN or infinite.
    #[error("{what} {index} is not finite")]
    NonFinite {
        /// What kind of value (e.g. "point", "normal").
        what: &'static str,
        /// Its 0-based index.
        index: usize,
    },
    /// A vector that must give a direction (a normal) is zero, or too short to normalise.
    #[error("{what} {index} is zero: it gives no direction")]
    ZeroVector {
        /// What kind of value (e.g. "normal").
        what: &'static str,
        /// Its 0-based index.
        index: usize,
    },
    /// Too few points for the operation.
    #[error("{what}: needs at least {needed} points, got {got}")]
    TooFewPoints {
        /// What was being built or computed.
        what: String,
        /// The minimum.
        needed: usize,
        /// What was given.
        got: usize,
    },
    /// Two sequences that must match in length do not.
    #[error("{what}: expected {expected} entries, got {got}")]
    LengthMismatch {
        /// What was being built.
        what: &'static str,
        /// The expected length.
        expected: usize,
        /// The given length.
        got: usize,
    },
    /// A contour is unusable.
    #[error("contour {contour}: {message}")]
    InvalidContour {
        /// The contour id from the input path.
        contour: i64,
        /// What was wrong.
        message: String,
    },
    /// The work was cancelled ([`crate::cancel`]): its caller asked it to stop.
    #[error("cancelled")]
    Cancelled,
    /// An argument is out of its valid range.
    #[error("{name}: {message}")]
    InvalidArgument {
        /// The argument's name.
        name: &'static str,
        /// What was wrong and what is accepted.
        message: String,
    },
}

impl GeomError {
    /// A parse error at a place in a file.
    pub fn parse(path: impl Into<PathBuf>, at: Location, message: impl Into<String>) -> Self {
        GeomError::Parse {
            path: path.into(),
            at,
            message: message.into(),
        }
    }

    /// An I/O error on a file.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        GeomError::Io {
            path: path.into(),
            error: source,
        }
    }

    /// An out-of-range argument.
    pub fn invalid(name: &'static str, message: impl Into<String>) -> Self {
        GeomError::InvalidArgument {
            name,
            message: message.into(),
        }
    }
}
