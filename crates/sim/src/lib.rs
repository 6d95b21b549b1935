//! trim-sim: the cell simulated (DESIGN.md "Execution and devices"), for the demo, `trimctl sim`
//! and the tests. trim-io's clients and executor talk to these simulators as to the real
//! devices, over loopback TCP and a pseudo-terminal.
//!
//! - [`galvo`]: a galvo controller implementing docs/protocols/galvo.md on a TCP port.
//! - [`laser`]: a laser speaking a command profile on a pty.
//! - [`cnc`]: a simulator of the LinuxCNC `linuxcncrsh` protocol subset the client uses.
//! - [`fault`]: fault injection (drop link, stall, garble, refuse) for the three simulators.
//! - [`safety`]: the safety monitor: the simulators' physical state in one event log, the
//!   interlock invariants checked on every change.
//! - [`twin`]: the digital twin: a true cell in the simulators, and the spot error on the true
//!   part.
//! - [`ablation`]: what the twin's landed lines remove from the true part: burr webs cut or
//!   left standing, gouges.
//! - [`film_ablation`]: what the landed lines remove from the films over blocked openings:
//!   cleared where the kerfs sweep the film's thickness away, thinner or standing elsewhere.
//! - [`twin_part`]: the twin's true part through a run: a synthetic core with burrs, trimmed by
//!   each round's cuts and rescanned.
//! - [`sim_cell`]: [`sim_cell::SimCell`], the three simulators started in-process.

pub mod ablation;
pub mod cnc;
pub mod fault;
pub mod film_ablation;
pub mod galvo;
pub mod laser;
pub mod safety;
pub mod sim_cell;
pub mod twin;
pub mod twin_part;

pub use sim_cell::{SimCell, SimError, SimFaults, SimOptions};
