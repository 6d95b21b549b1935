//! Registration for trimctl: ICP on a kd-tree, the Umeyama similarity, a regional registration of
//! contour paths on a smooth deformation field, and the six-point datum fit.
//!
//! Frames are in names, `b_from_a` (see trim-geom). Millimetres and radians throughout.
//!
//! - [`umeyama`]: closed-form similarity between paired points (Umeyama 1991).
//! - [`point_to_plane`]: the linearised point-to-plane / point-to-point normal equations.
//! - [`icp`]: ICP (point-to-point, point-to-plane; rigid or scaled; robust; pyramid).
//! - [`kernel`]: robust kernels.
//! - [`regional`]: the regional registration of a path and its quality report (DESIGN.md
//!   "Registration").
//! - [`field`]: the quadratic B-spline deformation field; [`banded`]: its banded solve.
//! - [`sampling`]: scan thinning and CAD visibility culling.
//! - [`datum`]: the six-point datum fit (thesis §3.5.2).
//! - [`paper`]: the paper's method, the baseline of the accuracy evaluation; [`eval`]: scoring.
//! - [`reduce`]: deterministic parallel sums.

pub mod banded;
pub mod datum;
pub mod deformation;
pub mod error;
pub mod eval;
pub mod icp;
pub mod kdtree;
pub mod kernel;
pub mod point_to_plane;
pub mod reduce;
pub mod regional;
pub mod sampling;
pub mod scaled_icp_baseline;
pub mod umeyama;

pub use error::{RegisterError, Result};
pub use icp::{IcpMethod, IcpResult, IcpSettings, IcpTarget, PyramidLevel, icp, icp_pyramid};
pub use kernel::RobustKernel;
pub use regional::{QualityReport, RegisterSettings, Registration, register};
pub use umeyama::{UmeyamaFit, umeyama, umeyama_weighted};
