//! trim-io: the cell's devices and the execution of a Job (DESIGN.md "Execution and devices").
//!
//! - [`galvo`]: the 2D scanner over TCP (docs/protocols/galvo.md): codec, timing model, client.
//! - [`laser`]: the laser over RS-232 with command profiles as data.
//! - [`cnc`]: the five-axis CNC behind the [`cnc::Cnc`] trait; LinuxCNC `linuxcncrsh` client.
//! - [`executor`]: the state machine over the Job with its interlocks, the [`journal`], and the
//!   run [`record`] (MCAP, through the Foxglove SDK), served [`live`] over the Foxglove
//!   WebSocket protocol with `run --live`.
//! - [`frame`]: red-light framing: a layer's outline traced with the galvo's pointer, the
//!   process laser's light path shut.
//! - [`limits`]: the Job's poses checked against the machine's axis limits before anything
//!   moves.
//! - [`cell`]: the three devices together.
//!
//! The simulators of the three devices, their fault injection, the safety monitor and the
//! digital twin are trim-sim's: a shop build links none of them.
//!
//! Device calls return `Result<Result<T, Fault>, Error>`: the outer error is the transport (link,
//! timeout, garbled bytes), the inner one the device's own refusal or fault.

pub mod cell_devices;
pub mod cnc;
pub mod disk;
pub mod executor;
pub mod framing;
pub mod galvo;
pub mod journal;
pub mod jsonl;
pub mod laser;
pub mod limits;
pub mod live;
pub mod record;
pub mod tap;
