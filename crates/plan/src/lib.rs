//! Zone-layered planning for trimctl (DESIGN.md "Algorithms", paper §2). The cell it plans for
//! and the Job it writes are trim-cell's.
//!
//! - [`piece`]: contours as pieces (contours split where their feature vectors spread).
//! - [`zoning`]: k-means zoning with the incidence limit and automatic k.
//! - [`cover`]: zoning as covering: few poses (axis + field centre) checked with the real ray.
//! - [`hatch`]: surface hatching: equal-spacing tracks on a scanned freeform surface.
//! - [`kerf`]: kerf compensation: each contour's material side and the offset out of it.
//! - [`layer`]: layers by paper Eq. 14 and the galvo projection.
//! - [`field`]: scan-field sections and the lens ray angle.
//! - [`order`]: zone ordering (nearest neighbour + 2-opt).
//! - [`partition`]: validation's check that a Job's polylines mark each contour once.
//! - [`planner`]: [`plan`], validation and the time estimate.
//! - [`svg`]: SVG plots of a job.
//! - [`error`]: the error type, [`PlanError`].

pub mod cover;
pub mod error;
pub mod hatch;
pub mod kerf;
pub mod layer;
pub mod order;
pub mod partition;
pub mod piece;
pub mod planner;
pub mod scan_field;
pub mod svg;
#[cfg(test)]
pub(crate) mod test_shapes;
pub mod zoning;

pub use error::PlanError;
pub use layer::LayerSettings;
pub use planner::{PlanOutput, PlanSettings, ZoneRow, plan, plan_with_report, plan_with_sides};
pub use scan_field::LensSettings;
pub use zoning::{ZoningMethod, ZoningSettings};
