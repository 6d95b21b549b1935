//! The five-axis CNC behind the [`Cnc`] trait, so other controls can be added: a LinuxCNC
//! `linuxcncrsh` client ([`linuxcnc::LinuxCnc`]); a simulator of that protocol is trim-sim's.

pub mod linuxcnc;

use std::time::Duration;

use futures::future::BoxFuture;
use trim_cell::job::Pose;

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
    /// The machine is not ready and the step that would make it so was not allowed
    /// ([`EnableSteps`]).
    #[error("the machine is {state}: {remedy}")]
    NotReady {
        /// What it is (in E-stop, off, not homed).
        state: String,
        /// What makes it ready.
        remedy: String,
    },
}

/// The machine's state as the control reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct MachineState {
    /// In E-stop.
    pub estop: bool,
    /// Switched on.
    pub on: bool,
    /// Every joint homed.
    pub homed: bool,
}

/// What preparing the machine may do beyond switching its mode and kinematics: each step only
/// when the operator allowed it (`--enable-machine`, `--home`). Resetting an E-stop or homing
/// (the axes move) is the operator's decision, never trimctl's own.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EnableSteps {
    /// Reset the E-stop and switch the machine on.
    pub enable_machine: bool,
    /// Home the machine's joints.
    pub home: bool,
}

impl EnableSteps {
    /// Every step allowed (tests and CI against a simulated control).
    pub const ALL: EnableSteps = EnableSteps {
        enable_machine: true,
        home: true,
    };

    /// Why the machine in `state` cannot be made ready with these steps, or `None`.
    #[must_use]
    pub fn refusal(self, state: MachineState) -> Option<CncFault> {
        let refuse = |what: &str, remedy: &str| CncFault::NotReady {
            state: what.to_owned(),
            remedy: remedy.to_owned(),
        };
        if state.estop && !self.enable_machine {
            return Some(refuse(
                "in E-stop",
                "release it and switch the machine on at the control, or allow trimctl to with --enable-machine",
            ));
        }
        if !state.estop && !state.on && !self.enable_machine {
            return Some(refuse(
                "switched off",
                "switch it on at the control, or allow trimctl to with --enable-machine",
            ));
        }
        if !state.homed && !self.home {
            return Some(refuse(
                "not homed",
                "home it at the control, or allow trimctl to (the axes move) with --home",
            ));
        }
        None
    }
}

/// A device result: transport error outside, the control's refusal inside.
pub type CncResult<T> = Result<Result<T, CncFault>, CncError>;

/// Largest distance between the commanded and the reached position that counts as in position
/// (mm for linear, degrees for rotary axes).
pub const IN_POSITION_TOLERANCE: f64 = 1e-3;

/// While a layer marks, the largest distance from the layer's pose the machine may show before
/// the run stops (mm, degrees): above the control's reported jitter, far below a layer step.
pub const HOLD_TOLERANCE: f64 = 5e-3;

/// What the control reports while a layer marks: where the machine is and its state.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Watch {
    /// The positions.
    pub positions: Positions,
    /// E-stop, on, homed.
    pub state: MachineState,
}

/// A five-axis CNC control.
pub trait Cnc: Send {
    /// Reads whether the machine is in E-stop, on, and homed.
    fn state(&mut self) -> BoxFuture<'_, CncResult<MachineState>>;
    /// Makes the machine ready: E-stop reset and machine on, homed (each only when `steps`
    /// allows it, else [`CncFault::NotReady`] naming the state), MDI mode, TCP kinematics.
    fn enable(&mut self, steps: EnableSteps) -> BoxFuture<'_, CncResult<()>>;
    /// Starts a rapid move to a pose (returns when the control accepted it).
    fn start_move<'a>(&'a mut self, pose: &'a Pose) -> BoxFuture<'a, CncResult<()>>;
    /// Waits until the last move is done and checks the position (within
    /// [`IN_POSITION_TOLERANCE`]); fails after `timeout`.
    fn wait_in_position(&mut self, timeout: Duration) -> BoxFuture<'_, CncResult<Positions>>;
    /// Reads the positions.
    fn positions(&mut self) -> BoxFuture<'_, CncResult<Positions>>;
    /// Reads the positions and the machine's state (polled while a layer marks).
    fn watch(&mut self) -> BoxFuture<'_, CncResult<Watch>>;
    /// Stops motion (the machine stays enabled).
    fn abort(&mut self) -> BoxFuture<'_, CncResult<()>>;
    /// Emergency stop.
    fn estop(&mut self) -> BoxFuture<'_, CncResult<()>>;
    /// Pops and returns every queued error message.
    fn errors(&mut self) -> BoxFuture<'_, CncResult<Vec<String>>>;
}
