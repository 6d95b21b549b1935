//! The laser over RS-232: command profiles as data, the client on a serial port, and a simulator
//! on a pseudo-terminal.

pub mod client;
pub mod profile;
pub mod sim;

pub use client::{LaserClient, LaserError, LaserFault, LaserResult};
pub use profile::{LaserStatus, Profile};
pub use sim::LaserSim;
