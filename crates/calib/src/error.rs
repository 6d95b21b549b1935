//! The error type of trim-calib.

use std::path::PathBuf;

/// What can go wrong while calibrating. Every variant says what and where.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// A file cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line of an input file is wrong.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// Too little data for the fit.
    #[error("{what}: need at least {needed}, got {got}")]
    TooFew {
        /// What is counted.
        what: String,
        /// How many are needed.
        needed: usize,
        /// How many there are.
        got: usize,
    },
    /// The data cannot determine some parameters (e.g. no motion of one axis).
    #[error("degenerate data: {0}")]
    Degenerate(String),
    /// A setting or argument is out of range.
    #[error("{key}: {message}")]
    Invalid {
        /// The setting or argument.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// The data do not agree with the model they are fitted to: a wrong setting or a bad
    /// measurement, not too little data.
    #[error("the data do not fit: {0}")]
    Inconsistent(String),
    /// The fit did not converge.
    #[error("{what} did not converge: {detail}")]
    NotConverged {
        /// Which fit.
        what: String,
        /// Iterations, residuals.
        detail: String,
    },
}
