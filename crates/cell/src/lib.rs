//! The cell model and the Job contract of trimctl (DESIGN.md "Frames and the calibration chain",
//! "Data contracts"): the vocabulary that planning, execution, calibration and the simulators
//! share, without the planner's algorithms.
//!
//! - [`beam`]: beam optics (waist, Rayleigh length, fluence, focus processing length, spot) and
//!   the laser source's limits.
//! - [`cell_model`]: the calibrated cell: rotary axis lines, scanner pose, lens calibration.
//! - [`frame`]: local zone frames (paper Eq. 11–13, right-handed).
//! - [`lens`]: where a galvo command lands: the height term and the field correction.
//! - [`kinematics`]: machine poses (LinuxCNC xyzac-trt, xyzbc-trt, fixed head).
//! - [`galvo_timing`]: the galvo's time model (list composition, `[timing]` terms): what a
//!   layer's list takes.
//! - [`process`]: job.toml `[process]`, the ablation figures (depth per pass, kerf width).
//! - [`job`]: the Job model, the planner's output and the executor's input.
//! - [`truth`]: job.toml `[sim.truth]`, the true cell the digital twin carries.
//! - [`scans_at_poses`]: poses.csv and scans taken at several machine poses merged into one
//!   cloud in the work-piece frame ([`ScansError`]).
//! - [`error`]: the settings error, [`CellError`] (a field correction file fails with
//!   [`lens::LensError`], poses.csv and scans at poses with [`ScansError`]).

pub mod beam;
pub mod cell_model;
pub mod error;
pub mod frame;
pub mod galvo_timing;
pub mod job;
pub mod kinematics;
pub mod lens;
pub mod plan_settings;
pub mod process;
pub mod scans_at_poses;
pub mod truth;

pub use beam::{Beam, BeamReport, LaserLimits};
pub use error::CellError;
pub use galvo_timing::{ListComposition, TimingSettings};
pub use job::{Frame, GalvoSettings, Job, JobSettings, Layer, LayerKey, Polyline, Pose, Zone};
pub use kinematics::{AxisPose, KinematicsKind, MachineSettings, MoveModel, PoseMode};
pub use process::ProcessSettings;
pub use scans_at_poses::ScansError;
