//! The laser over RS-232: command profiles as data and the client on a serial port (the
//! simulator on a pseudo-terminal is trim-sim's).

pub mod client;
pub mod profile;

pub use client::{LaserClient, LaserError, LaserFault, LaserResult};
pub use profile::{LaserStatus, Profile};
