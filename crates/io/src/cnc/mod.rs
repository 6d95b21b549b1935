//! The five-axis CNC behind the [`Cnc`] trait, so other controls can be added: a LinuxCNC
//! `linuxcncrsh` client ([`linuxcnc::LinuxCnc`]) and a simulator of that protocol ([`sim`]).

pub mod linuxcnc;
pub mod sim;

use std::time::Duration;

use futures::future::BoxFuture;
use trim_plan::job::Pose;

/// The axes the CNC takes, in G-code order (lower case, as in [`Pose`]).
pub const AXES: [&str; 6] = ["x", "y", "z", "a", "b", "c"];

/// Positions read from the CNC.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Positions {
    /// World (tool-tip with TCP kinematics) positions by axis (mm, degrees).
    pub world: Pose,
    /// Joint positions (mm, degrees), joint 0 first.
    pub joints: Vec<f64>,
}

/// A transport failure: the link to the control failed.
#[derive(Debug, Clone, thiserror::Error)]
pub enum CncError {
    /// Could not connect.
    #[error("cnc: cannot connect to {addr}: {reason}")]
    Connect {
        /// The address.
        addr: String,
        /// Why.
        reason: String,
    },
    /// No reply in time.
    #[error("cnc: no reply to {command:?} within {timeout_ms} ms")]
    Timeout {
        /// The command.
        command: String,
        /// The timeout (ms).
        timeout_ms: u64,
    },
    /// The connection closed or failed.
    #[error("cnc: link lost during {command:?}: {reason}")]
    LinkLost {
        /// The command.
        command: String,
        /// Why.
        reason: String,
    },
    /// A reply that does not answer the command.
    #[error("cnc: bad reply to {command:?}: {reply:?}")]
    BadReply {
        /// The command.
        command: String,
        /// The reply.
        reply: String,
    },
}

/// The control's refusal or a machine fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CncFault {
    /// The control refused a command (NAK), with the errors it queued.
    #[error("cnc refused {command:?}: {}", errors.join("; "))]
    Refused {
        /// The command.
        command: String,
        /// The control's error messages.
        errors: Vec<String>,
    },
    /// The move ended away from the commanded pose.
    #[error("cnc not in position: axis {axis} at {actual}, commanded {commanded}")]
    NotInPosition {
        /// The axis.
        axis: String,
        /// Reached (mm or degrees).
        actual: f64,
        /// Commanded (mm or degrees).
        commanded: f64,
    },
    /// A pose the control cannot take (unknown axis, not finite).
    #[error("cnc cannot take the pose: {0}")]
    BadPose(String),
    /// Homing did not finish.
    #[error("cnc homing did not finish: {0}")]
    NotHomed(String),
}

/// A device result: transport error outside, the control's refusal inside.
pub type CncResult<T> = Result<Result<T, CncFault>, CncError>;

/// Largest distance between the commanded and the reached position that counts as in position
/// (mm for linear, degrees for rotary axes).
pub const IN_POSITION_TOLERANCE: f64 = 1e-3;

/// A five-axis CNC control.
pub trait Cnc: Send {
    /// Makes the machine ready: estop off, machine on, homed, TCP kinematics active.
    fn enable(&mut self) -> BoxFuture<'_, CncResult<()>>;
    /// Starts a rapid move to a pose (returns when the control accepted it).
    fn start_move<'a>(&'a mut self, pose: &'a Pose) -> BoxFuture<'a, CncResult<()>>;
    /// Waits until the last move is done and checks the position (within
    /// [`IN_POSITION_TOLERANCE`]); fails after `timeout`.
    fn wait_in_position(&mut self, timeout: Duration) -> BoxFuture<'_, CncResult<Positions>>;
    /// Reads the positions.
    fn positions(&mut self) -> BoxFuture<'_, CncResult<Positions>>;
    /// Stops motion (the machine stays enabled).
    fn abort(&mut self) -> BoxFuture<'_, CncResult<()>>;
    /// Emergency stop.
    fn estop(&mut self) -> BoxFuture<'_, CncResult<()>>;
    /// Pops and returns every queued error message.
    fn errors(&mut self) -> BoxFuture<'_, CncResult<Vec<String>>>;
}
