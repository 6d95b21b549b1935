//! Inspection for trimctl (issue 23; thesis §3.6, on-machine inspection): the part is scanned
//! after trimming, the scan is fitted to the CAD with the registration, and every contour of
//! the CAD path is measured and judged against a tolerance with ISO 14253-1's guard bands.
//!
//! Frames: the CAD frame (mm) is where everything is measured; scan points are carried there
//! through the registration, `cad = F⁻¹(cad_from_scan · scan)` with `F` its deformation field
//! ([`placement`]). Distances are signed, positive outside the material.
//!
//! - [`settings`]: what to measure and the decision's parameters, validated by key.
//! - [`placement`]: the fit to the CAD (the registration, or a rigid datum fit) and its
//!   per-contour bound, and the mapping of scan points into the CAD frame.
//! - [`contours`]: where a point lies relative to the path's contours (nearest contour, arc
//!   length, lateral distance).
//! - [`crop`]: the scan points near the registered contours and openings.
//! - [`height`]: the height of excess along a contour, each web's free edge fitted to the
//!   distances and rises of its points (one height per web).
//! - [`inputs`]: the checks that run before anything is sized by the inputs (a contour off the
//!   CAD, a scan too sparse to fit) and which points stand near enough to the part to measure.
//! - [`measure`]: the per-contour measurement (excess, gouge, coverage) and [`inspect`].
//! - [`opening`]: the share of a hole or slot still covered.
//! - [`verdict`]: the uncertainty and the decision rule.
//! - [`error`]: the error type, [`InspectError`].

pub mod contours;
pub mod crop;
#[cfg(test)]
mod draws;
pub mod error;
pub mod height;
pub mod inputs;
pub mod measure;
pub mod opening;
pub mod placement;
pub mod settings;
pub mod verdict;

pub use error::{InspectError, Result};
pub use measure::{
    ContourInspection, ExcessBin, Inspection, SignedMesh, inspect, signed_distances,
};
pub use placement::Placement;
pub use settings::InspectSettings;
pub use verdict::{Verdict, decide, uncertainty_um};
