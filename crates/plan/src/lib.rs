//! Zone-layered planning for trimctl (DESIGN.md "Algorithms", paper §2).
//!
//! - [`job`]: the Job model, the planner's output.

pub mod job;

pub use job::{Frame, GalvoSettings, Job, JobSettings, Layer, LayerKey, Polyline, Pose, Zone};
