//! The way down: **laser off first** (the serial emission-off and the galvo laser signals off,
//! together; a lost galvo link gets a new session for them), **then** the galvo list stopped, **then** motion stopped; then the cut layer
//! journaled with how far it got. Every failure after preparation begins reaches
//! [`Executor::stop`] through one exit path: the layer phases return a [`LayerFault`] (never
//! return early past it), the run loop turns it into a [`Fault`], and `execute` hands that to
//! `stop`.

use std::time::Instant;

use trim_cell::job::LayerKey;

use super::layer::LayerWork;
use super::{ExecError, Executor, Phase, ShutdownReport, Step, StopCause, Stopped};
use super::{ShutdownStep, StepFailure};
use crate::galvo::outline::is_frame_tag;
use crate::galvo::protocol::NO_LIST;
use crate::journal::{Entry, Journal};
use crate::laser::client::EmissionOff;
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

/// The first step of the way down, done: both laser-off commands answered or given up.
#[derive(Debug, Clone)]
pub(super) struct LaserOff {
    /// The serial emission-off: acknowledged or not, every attempt.
    emission: EmissionOff,
    /// The galvo laser signals off: `None` acknowledged, else why not.
    galvo_signals: Option<String>,
    /// The galvo link was lost and a new session was opened for the way down's requests.
    galvo_reopened: bool,
    /// From detection to the serial emission-off acknowledged or given up (s).
    emission_after_s: f64,
    /// From detection to the galvo's answer or its timeout (s).
    galvo_after_s: f64,
    /// From detection to both answered or given up (s).
    after_s: f64,
}

/// `None` when the step was acknowledged, else what went wrong (its timeout included).
fn step_error<E1: std::fmt::Display, E2: std::fmt::Display>(
    r: Result<Result<Result<(), E2>, E1>, tokio::time::error::Elapsed>,
    timeout: std::time::Duration,
) -> Option<String> {
    match r {
        Ok(Ok(Ok(()))) => None,
        Ok(Ok(Err(fault))) => Some(format!("refused: {fault}")),
        Ok(Err(e)) => Some(e.to_string()),
        Err(_) => Some(format!("no answer within {} ms", timeout.as_millis())),
    }
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
            Ok(Ok(Ok(s))) if s.tag >> 16 == tag >> 16 && s.tag < tag && !is_frame_tag(s.tag) => {
                Some(first)
            }
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
            let cut = Entry::LayerCut {
                key,
                vectors_done,
                reason: cause.to_string(),
            };
            let timeout = self.options.timeouts.journal_write;
            if let Err(e) = journal.append_within(&cut, timeout).await {
                tracing::error!(error = %e, "journal: cut entry lost");
            }
            self.record_layer(key, "cut", vectors_done.unwrap_or(0), vectors, true);
        }
        self.log(
            LogLevel::Error,
            &format!("run stopped at {phase:?}: {cause}"),
        );
        self.record_shutdown(&cause, key, phase, &shutdown);
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

    /// The way down on `/shutdown` (a failure is logged: the record is not the journal).
    fn record_shutdown(
        &self,
        cause: &StopCause,
        key: Option<LayerKey>,
        phase: Phase,
        shutdown: &ShutdownReport,
    ) {
        let Some(r) = &self.recorder else { return };
        let msg = serde_json::json!({
            "cause": cause.to_string(),
            "layer": key.map(|k| k.to_string()),
            "phase": format!("{phase:?}"),
            "report": shutdown,
        });
        let mut r = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let res = r.json(
            crate::record::topic::SHUTDOWN,
            crate::record::topic::SHUTDOWN_SCHEMA,
            crate::tap::now_ns(),
            &msg,
        );
        if let Err(e) = res {
            tracing::warn!(error = %e, "record: shutdown report lost");
        }
    }

    /// The laser off: the serial emission-off (retried on the port reopened until acknowledged
    /// or the laser-off budget is spent: [`LaserClient::emission_off_until`]) and the galvo laser
    /// signals off (within the shutdown step), together.
    ///
    /// [`LaserClient::emission_off_until`]: crate::laser::LaserClient::emission_off_until
    async fn laser_off(&mut self, detected_at: Instant) -> LaserOff {
        let t = self.options.timeouts;
        let deadline = tokio::time::Instant::now() + t.laser_off_budget;
        let cell = &mut self.cell;
        let (emission, galvo) = tokio::join!(
            async {
                let e = cell.laser.emission_off_until(deadline).await;
                (e, detected_at.elapsed().as_secs_f64())
            },
            async {
                let mut reopened = false;
                let r = tokio::time::timeout(t.shutdown_step, async {
                    // A lost link gets a new session first (which itself drops the signals).
                    match cell.galvo.reopen_if_lost().await {
                        Ok(Ok(fresh)) => reopened = fresh,
                        Ok(Err(fault)) => return Ok(Err(fault)),
                        Err(e) => return Err(e),
                    }
                    cell.galvo.laser_signals(false).await
                })
                .await;
                (
                    step_error(r, t.shutdown_step),
                    reopened,
                    detected_at.elapsed().as_secs_f64(),
                )
            },
        );
        LaserOff {
            emission: emission.0,
            emission_after_s: emission.1,
            galvo_signals: galvo.0,
            galvo_reopened: galvo.1,
            galvo_after_s: galvo.2,
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
        let mut failures = Vec::new();
        if !laser.emission.acknowledged {
            let error = laser
                .emission
                .attempts
                .last()
                .and_then(|a| a.error.clone())
                .unwrap_or_else(|| "no attempt".into());
            failures.push(StepFailure {
                step: ShutdownStep::EmissionOff,
                error: format!("{error} ({} attempts)", laser.emission.attempts.len()),
                after_s: laser.emission_after_s,
            });
        }
        if let Some(error) = &laser.galvo_signals {
            failures.push(StepFailure {
                step: ShutdownStep::GalvoSignalsOff,
                error: error.clone(),
                after_s: laser.galvo_after_s,
            });
        }
        let cell = &mut self.cell;
        let galvo_stop = step_error(tokio::time::timeout(step, cell.galvo.stop()).await, step);
        if let Some(error) = &galvo_stop {
            failures.push(StepFailure {
                step: ShutdownStep::GalvoStop,
                error: error.clone(),
                after_s: detected_at.elapsed().as_secs_f64(),
            });
        }
        // A stop on a fresh CNC session may need a connect: allow it the reply timeout too.
        let cnc_step = step + self.options.timeouts.cnc_reply;
        let cnc_abort = step_error(
            tokio::time::timeout(cnc_step, cell.cnc.abort()).await,
            cnc_step,
        );
        if let Some(error) = &cnc_abort {
            failures.push(StepFailure {
                step: ShutdownStep::CncAbort,
                error: error.clone(),
                after_s: detected_at.elapsed().as_secs_f64(),
            });
        }
        let report = ShutdownReport {
            laser_off_ok: laser.emission.acknowledged,
            galvo_signals_off_ok: laser.galvo_signals.is_none(),
            galvo_reopened: laser.galvo_reopened,
            galvo_stop_ok: galvo_stop.is_none(),
            cnc_abort_ok: cnc_abort.is_none(),
            laser_off_s: laser.after_s,
            total_s: detected_at.elapsed().as_secs_f64(),
            emission_off: laser.emission.attempts,
            failures,
        };
        if report.all_acknowledged() {
            tracing::warn!(?report, "executor: way down, every step acknowledged");
        } else {
            tracing::error!(?report, "executor: way down, NOT every step acknowledged");
        }
        report
    }
}
