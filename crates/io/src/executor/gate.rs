//! The zone gate (`trimctl run --frame`): before the first layer of each zone a run marks, the
//! executor hands the cell to a [`ZoneGate`] (red-light framing and the operator's answer), then
//! marks the zone or takes the normal way down.
//!
//! The gate runs between layers: the laser's emission is off (the previous layer's
//! [`Phase::GateOff`], or preparation), and the gate leaves the cell as it found it (the laser
//! signals enabled, the pointer off) when it answers [`ZoneDecision::Mark`]. Its failures are
//! the layer's, in [`Phase::Frame`], before anything of the layer is loaded or journaled.

use futures::future::BoxFuture;
use tokio_util::sync::CancellationToken;
use trim_cell::job::{Job, LayerKey};

use super::shutdown::{At, LayerStep};
use super::{Executor, Phase, StopCause};
use crate::cell_devices::Cell;

/// What the operator chose for a zone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum ZoneDecision {
    /// Mark the zone.
    Mark,
    /// Stop the run here (the normal way down, as a cancel; resume continues at this zone).
    Quit,
}

/// Asked before the first layer of each zone a run marks.
pub trait ZoneGate: Send {
    /// Before layer `key` (the zone's first layer this run marks) of `job`: may move the CNC
    /// and trace with the galvo; must leave the laser signals enabled and the pointer off when
    /// it answers [`ZoneDecision::Mark`]. Every device await with a timeout; `cancel` honoured.
    fn before_zone<'a>(
        &'a mut self,
        cell: &'a mut Cell,
        job: &'a Job,
        key: LayerKey,
        cancel: &'a CancellationToken,
    ) -> BoxFuture<'a, Result<ZoneDecision, StopCause>>;
}

impl Executor {
    /// Asks the gate, if any, before `key` when it begins a zone (`gated_zone` is the zone asked
    /// last). `Quit` is a cancel.
    pub(super) async fn gate_zone(
        &mut self,
        key: LayerKey,
        gated_zone: &mut Option<usize>,
    ) -> LayerStep<()> {
        if *gated_zone == Some(key.zone) {
            return Ok(());
        }
        *gated_zone = Some(key.zone);
        let Some(gate) = self.zone_gate.as_mut() else {
            return Ok(());
        };
        let decision = gate
            .before_zone(&mut self.cell, &self.job, key, &self.cancel)
            .await
            .at(Phase::Frame, false)?;
        match decision {
            ZoneDecision::Mark => Ok(()),
            ZoneDecision::Quit => Err(StopCause::Cancelled).at(Phase::Frame, false),
        }
    }
}
