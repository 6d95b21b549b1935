//! Zone-layered planning for trimctl (DESIGN.md "Algorithms", paper §2).
//!
//! - [`beam`]: beam optics (waist, Rayleigh length, fluence, focus processing length, spot).
//! - [`piece`]: contours as pieces (contours split where their feature vectors spread).
//! - [`zoning`]: k-means zoning with the incidence limit and automatic k.
//! - [`frame`]: local zone frames (paper Eq. 11–13, right-handed).
//! - [`job`]: the Job model, the planner's output.
//! - [`error`]: [`PlanError`].

pub mod beam;
pub mod error;
pub mod field;
pub mod frame;
pub mod job;
pub mod kinematics;
pub mod layer;
pub mod piece;
pub mod zoning;

pub use beam::{Beam, BeamReport};
pub use error::PlanError;
pub use job::{Frame, GalvoSettings, Job, JobSettings, Layer, LayerKey, Polyline, Pose, Zone};
pub use zoning::ZoningSettings;
