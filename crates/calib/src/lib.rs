//! Cell calibration for trimctl (DESIGN.md "Frames and the calibration chain"; thesis §3).
//!
//! - [`sphere`]: robust sphere fits (RANSAC, then least squares with the known radius).
//! - [`cell`]: `trimctl calibrate cell`: the rotary axis lines, the scanner pose and the
//!   sphere's table position from sphere scans at many machine poses, in one nonlinear least
//!   squares problem.
//! - [`field`]: `trimctl calibrate field`: the galvo field correction from a marked grid.
//! - [`timing`]: `trimctl calibrate timing`: the move model and the list terms from recorded runs.
//! - [`least_squares`]: the one nonlinear least-squares solver (MINPACK's Levenberg–Marquardt)
//!   both fits use.
//! - [`error`]: the error type, [`CalibError`].

pub mod artefact;
pub mod cell_calibration;
pub mod error;
pub mod field_correction;
pub mod least_squares;
pub mod sphere;
pub mod timing_fit;

pub use error::CalibError;
