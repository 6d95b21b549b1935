//! The galvo scanner over TCP (docs/protocols/galvo.md): protocol, timing model, client,
//! simulator, the conversion of a layer's polylines into a list, and the outline red-light
//! framing traces.

pub mod client;
pub mod list;
pub mod outline;
pub mod protocol;
pub mod sim;
pub mod timing;

pub use client::{GalvoClient, GalvoClientConfig, GalvoError, GalvoFault, GalvoResult};
pub use sim::{GalvoSim, GalvoSimConfig, Lit, MarkRecord, TraceRecord};
