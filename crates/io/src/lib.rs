//! trim-io: the cell's devices and the execution of a Job (DESIGN.md "Execution and devices").
//!
//! - [`galvo`]: the 2D scanner over TCP (docs/protocols/galvo.md): codec, client, simulator.
//! - [`laser`]: the laser over RS-232 with command profiles as data; simulator on a pty.
//! - [`cnc`]: the five-axis CNC behind the [`cnc::Cnc`] trait; LinuxCNC `linuxcncrsh` client and
//!   a simulator of that protocol.
//! - [`executor`]: the state machine over the Job with its interlocks, the [`journal`], and the
//!   run [`record`] (MCAP, through the Foxglove SDK), served [`live`] over the Foxglove
//!   WebSocket protocol with `run --live`.
//! - [`frame`]: red-light framing: a layer's outline traced with the galvo's pointer, the
//!   process laser's light path shut.
//! - [`limits`]: the Job's poses checked against the machine's axis limits before anything
//!   moves.
//! - [`cell`]: the three devices together, and [`cell::SimCell`], all three simulated.
//! - [`twin`]: the digital twin: a true cell in the simulators, and the spot error on the true
//!   part.
//!
//! Device calls return `Result<Result<T, Fault>, Error>`: the outer error is the transport (link,
//! timeout, garbled bytes), the inner one the device's own refusal or fault.

pub mod cell;
pub mod cnc;
pub mod disk;
pub mod executor;
pub mod fault;
pub mod frame;
pub mod galvo;
pub mod journal;
pub mod laser;
pub mod limits;
pub mod live;
pub mod record;
pub mod safety;
pub mod tap;
pub mod twin;
