//! The way down: **laser off first** (the serial emission-off and the galvo laser signals off,
//! together), **then** the galvo list stopped, **then** motion stopped; then the cut layer
//! journaled with how far it got. Every failure after preparation begins reaches
//! [`Executor::stop`] through one exit path: the layer phases return a [`LayerFault`] (never
//! return early past it), the run loop turns it into a [`Fault`], and `execute` hands that to
//! `stop`.

use std::time::Instant;

use trim_plan::job::LayerKey;

use super::layer::LayerWork;
use super::{ExecError, Executor, Phase, ShutdownReport, Step, StopCause, Stopped};
use crate::galvo::protocol::NO_LIST;
use crate::journal::{Entry, Journal};
use crate::record::LogLevel;

/// A failure after preparation began: what the way down journals and reports.
pub(super) struct Fault {
    /// Why.
    pub(super) cause: StopCause,
    /// The layer (`None`: during preparation).
    pub(super) key: Option<LayerKey>,
    /// The phase.
    pub(super) phase: Phase,
    /// Vectors of the layer marked, when known.
    pub(super) vectors_done: Option<u32>,
    /// Vectors in the layer.
    pub(super) vectors: u32,
    /// Layers finished (this run and before).
    pub(super) layers_finished: usize,
    /// The layer's `layer_begin` is journaled in this run: its cut is journaled too.
    pub(super) journal_cut: bool,
    /// When the failure was seen.
    pub(super) detected_at: Instant,
    /// The laser already switched off (before asking the galvo how far the layer got).
    pub(super) laser_off: Option<LaserOff>,
}

/// The first step of the way down, done: both laser-off commands answered or timed out.
#[derive(Debug, Clone, Copy)]
pub(super) struct LaserOff {
    /// The serial emission-off was acknowledged.
    ok: bool,
    /// The galvo laser signals off was acknowledged.
    galvo_signals_ok: bool,
    /// From detection to both answered or timed out (s).
    after_s: f64,
}

impl Fault {
    /// A failure while preparing the cell (no layer begun).
    pub(super) fn preparation(cause: StopCause, layers_finished: usize) -> Fault {
        Fault {
            cause,
            key: None,
            phase: Phase::Prepare,
            vectors_done: None,
            vectors: 0,
            layers_finished,
            journal_cut: false,
            detected_at: Instant::now(),
            laser_off: None,
        }
    }
}

/// A layer phase's failure, before the layer's progress is known.
pub(super) struct LayerFault {
    /// Why.
    pub(super) cause: StopCause,
    /// The phase it failed in.
    pub(super) phase: Phase,
    /// A list for this layer may have been loaded in this run (its `layer_begin` is journaled):
    /// the galvo is asked how far it got and the cut is journaled.
    pub(super) began: bool,
}

/// The result of a layer phase.
pub(super) type LayerStep<T> = Result<T, LayerFault>;

/// Tags a device step's failure with the layer phase it happened in.
pub(super) trait At<T> {
    /// `self`, its failure in `phase` (`began`: see [`LayerFault::began`]).
    fn at(self, phase: Phase, began: bool) -> LayerStep<T>;
}

impl<T> At<T> for Step<T> {
    fn at(self, phase: Phase, began: bool) -> LayerStep<T> {
        self.map_err(|cause| LayerFault {
            cause,
            phase,
            began,
        })
    }
}

impl Executor {
    /// The failed layer's [`Fault`]: how far it got, asking the galvo when its list may have
    /// marked. That question waits for an answer, so the laser goes off before it is asked.
    pub(super) async fn layer_fault(
        &mut self,
        journal: &Journal,
        work: &LayerWork,
        fault: LayerFault,
        layers_finished: usize,
    ) -> Fault {
        let detected_at = Instant::now();
        let LayerFault {
            cause,
            phase,
            began,
        } = fault;
        // Before `EXECUTE` this attempt marked nothing, whatever the galvo reports (a preloaded
        // list is not a marked layer).
        let executed = !matches!(
            phase,
            Phase::Move | Phase::LoadList | Phase::WaitInPosition | Phase::EnableEmission
        );
        let mut laser_off = None;
        let vectors_done = if began && executed {
            laser_off = Some(self.laser_off(detected_at).await);
            self.marked_so_far(work.first, journal.current_tag()).await
        } else if began || work.first > 0 {
            Some(work.first)
        } else {
            None
        };
        Fault {
            cause,
            key: Some(work.key),
            phase,
            vectors_done,
            vectors: work.vectors,
            layers_finished,
            journal_cut: began,
            detected_at,
            laser_off,
        }
    }

    /// How many vectors of the layer are marked, from the galvo (short timeout; `None` when it
    /// cannot tell).
    async fn marked_so_far(&self, first: u32, tag: u32) -> Option<u32> {
        let step = self.options.timeouts.shutdown_step;
        match tokio::time::timeout(step, self.cell.galvo.status()).await {
            Ok(Ok(Ok(s))) if s.tag == tag && s.list != NO_LIST => Some(first + s.marks_done),
            Ok(Ok(Ok(s))) if s.tag >> 16 == tag >> 16 && s.tag < tag => Some(first),
            _ => None,
        }
    }

    /// The way down ([`Executor::shut_down`]), then the cut layer journaled and recorded, the
    /// stop logged and the record flushed.
    pub(super) async fn stop(&mut self, journal: &mut Journal, fault: Fault) -> ExecError {
        let Fault {
            cause,
            key,
            phase,
            vectors_done,
            vectors,
            layers_finished,
            journal_cut,
            detected_at,
            laser_off,
        } = fault;
        let shutdown = self.shut_down(detected_at, laser_off).await;
        if let Some(key) = key
            && journal_cut
        {
            if let Err(e) = journal.append(&Entry::LayerCut {
                key,
                vectors_done,
                reason: cause.to_string(),
            }) {
                tracing::error!(error = %e, "journal: cut entry lost");
            }
            self.record_layer(key, "cut", vectors_done.unwrap_or(0), vectors, true);
        }
        self.log(
            LogLevel::Error,
            &format!("run stopped at {phase:?}: {cause}"),
        );
        self.flush_record();
        ExecError::Stopped(Box::new(Stopped {
            cause,
            key,
            phase,
            vectors_done,
            vectors,
            layers_finished,
            shutdown,
            detected_at: Some(detected_at),
        }))
    }

    /// The laser off: the serial emission-off and the galvo laser signals off, together, each
    /// within the shutdown step.
    async fn laser_off(&mut self, detected_at: Instant) -> LaserOff {
        let step = self.options.timeouts.shutdown_step;
        let cell = &mut self.cell;
        let (laser, galvo) = tokio::join!(
            tokio::time::timeout(step, cell.laser.emission(false)),
            tokio::time::timeout(step, cell.galvo.laser_signals(false)),
        );
        LaserOff {
            ok: matches!(laser, Ok(Ok(Ok(())))),
            galvo_signals_ok: matches!(galvo, Ok(Ok(Ok(())))),
            after_s: detected_at.elapsed().as_secs_f64(),
        }
    }

    /// Laser off first (unless already done), then galvo stop, then motion stop.
    async fn shut_down(&mut self, detected_at: Instant, laser: Option<LaserOff>) -> ShutdownReport {
        let laser = match laser {
            Some(off) => off,
            None => self.laser_off(detected_at).await,
        };
        let step = self.options.timeouts.shutdown_step;
        let cell = &mut self.cell;
        let (laser_off_ok, galvo_signals_off_ok, laser_off_s) =
            (laser.ok, laser.galvo_signals_ok, laser.after_s);
        let galvo_stop_ok = matches!(
            tokio::time::timeout(step, cell.galvo.stop()).await,
            Ok(Ok(Ok(())))
        );
        // A stop on a fresh CNC session may need a connect: allow it the reply timeout too.
        let cnc_step = step + self.options.timeouts.cnc_reply;
        let cnc_abort_ok = matches!(
            tokio::time::timeout(cnc_step, cell.cnc.abort()).await,
            Ok(Ok(Ok(())))
        );
        let report = ShutdownReport {
            laser_off_ok,
            galvo_signals_off_ok,
            galvo_stop_ok,
            cnc_abort_ok,
            laser_off_s,
            total_s: detected_at.elapsed().as_secs_f64(),
        };
        tracing::warn!(?report, "executor: way down");
        report
    }
}
