//! The galvo scanner over TCP (docs/protocols/galvo.md): protocol, timing model, client (the
//! simulator is trim-sim's), the conversion of a layer's polylines into a list, and the outline red-light
//! framing traces.

pub mod client;
pub mod list;
pub mod list_clock;
pub mod outline;
pub mod protocol;

pub use client::{GalvoClient, GalvoClientConfig, GalvoError, GalvoFault, GalvoResult};
