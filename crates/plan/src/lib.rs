//! Zone-layered planning for trimctl (DESIGN.md "Algorithms", paper §2).
//!
//! - [`beam`]: beam optics (waist, Rayleigh length, fluence, focus processing length, spot).
//! - [`cell`]: the calibrated cell: rotary axis lines, scanner pose, lens calibration.
//! - [`piece`]: contours as pieces (contours split where their feature vectors spread).
//! - [`zoning`]: k-means zoning with the incidence limit and automatic k.
//! - [`cover`]: zoning as covering: few poses (axis + field centre) checked with the real ray.
//! - [`hatch`]: surface hatching: equal-spacing tracks on a scanned freeform surface.
//! - [`frame`]: local zone frames (paper Eq. 11–13, right-handed).
//! - [`layer`]: layers by paper Eq. 14 and the galvo projection.
//! - [`field`]: scan-field sections and the lens ray angle.
//! - [`lens`]: where a galvo command lands: the height term and the field correction.
//! - [`kinematics`]: machine poses (LinuxCNC xyzac-trt, xyzbc-trt, fixed head).
//! - [`order`]: zone ordering (nearest neighbour + 2-opt).
//! - [`planner`]: [`plan`], validation and the time estimate.
//! - [`svg`]: SVG plots of a job.
//! - [`timing`]: the cycle-time model beyond moves: list composition, `[timing]` terms.
//! - [`job`]: the Job model, the planner's output.
//! - [`error`]: the error type, [`PlanError`].

pub mod beam;
pub mod cell;
pub mod cover;
pub mod error;
pub mod field;
pub mod frame;
pub mod hatch;
pub mod job;
pub mod kinematics;
pub mod layer;
pub mod lens;
pub mod order;
pub mod piece;
pub mod planner;
pub mod svg;
pub mod timing;
pub mod zoning;

pub use beam::{Beam, BeamReport, LaserLimits};
pub use error::PlanError;
pub use field::LensSettings;
pub use job::{Frame, GalvoSettings, Job, JobSettings, Layer, LayerKey, Polyline, Pose, Zone};
pub use kinematics::{AxisPose, KinematicsKind, MachineSettings, MoveModel, PoseMode};
pub use layer::LayerSettings;
pub use planner::{PlanOutput, PlanSettings, ZoneRow, plan, plan_with_report};
pub use timing::{ListComposition, TimingSettings};
pub use zoning::{ZoningMethod, ZoningSettings};
