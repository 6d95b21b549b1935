//! One layer's phases, in order: [`Phase::Move`] → [`Phase::LoadList`] (preloaded while the CNC
//! moves) → [`Phase::WaitInPosition`] → [`Phase::EnableEmission`] → [`Phase::Execute`] →
//! [`Phase::WaitDone`] → [`Phase::GateOff`] → [`Phase::Journal`]. Each phase returns its failure
//! as a [`LayerFault`] (no early return past the way down): the run loop takes it to
//! [`Executor::stop`].

use std::time::{Duration, Instant};

use trim_cell::job::{Layer, LayerKey};

use super::shutdown::{At, LayerFault, LayerStep};
use super::{
    Executor, LayerTiming, Phase, Progress, RunPlan, RunSummary, STATUS_POLL_MS, StopCause,
};
use crate::galvo::list::layer_list;
use crate::galvo::list_clock::ListClock;
use crate::galvo::protocol::{ControllerState, ListCommand, StatusBlock};
use crate::journal::{Entry, Journal, JournalError};
use crate::tap::Device;

/// One layer this run marks (or only journals as done).
pub(super) struct LayerWork {
    /// The layer.
    pub(super) key: LayerKey,
    /// Its position in the job (0-based).
    pub(super) index: usize,
    /// The layer itself.
    pub(super) layer: Layer,
    /// Vectors in the layer.
    pub(super) vectors: u32,
    /// The first vector this run marks (after a cut, where the cut left off).
    pub(super) first: u32,
    /// When the layer began.
    pub(super) started: Instant,
}

impl LayerWork {
    /// The layer at `index` of the job, marked from vector `first`.
    pub(super) fn new(key: LayerKey, index: usize, layer: Layer, first: u32) -> LayerWork {
        LayerWork {
            key,
            index,
            vectors: crate::galvo::list::vector_count(&layer),
            layer,
            first,
            started: Instant::now(),
        }
    }

    /// Every vector was marked before the cut: only the journal entry is missing.
    pub(super) fn all_marked_before(&self) -> bool {
        self.first >= self.vectors
    }
}

/// A layer's list, built and journaled as begun.
struct BegunList {
    commands: Vec<ListCommand>,
    tag: u32,
    /// The galvo's modelled time of the list (s).
    modelled_s: f64,
}

/// The list loaded and the CNC in position.
struct InPosition {
    /// `LOAD_LIST`'s time (s).
    load_s: f64,
    /// When the CNC reported in position.
    at: Instant,
}

/// The list started.
struct Running {
    /// When `EXECUTE` was sent.
    t_exec: Instant,
    /// The laser's reply to emission on (s).
    emission_on_s: f64,
    /// From in position to `EXECUTE` acknowledged (s).
    to_execute_s: f64,
}

fn journal_failed(e: &JournalError) -> StopCause {
    StopCause::Journal {
        message: e.to_string(),
    }
}

fn galvo_fault(message: String) -> StopCause {
    StopCause::Fault {
        device: Device::Galvo,
        message,
    }
}

impl Executor {
    /// The keys of the job's layers with their positions, in job order.
    pub(super) fn layer_keys(&self) -> Vec<(usize, LayerKey)> {
        self.job
            .layers()
            .enumerate()
            .map(|(i, (k, _, _))| (i, k))
            .collect()
    }

    /// The layer at position `index` of the job.
    pub(super) fn layer_at(&self, index: usize) -> Layer {
        let (_, _, l) = self
            .job
            .layers()
            .nth(index)
            .unwrap_or_else(|| unreachable!("index from the same iterator"));
        l.clone()
    }

    /// A layer this run does not mark: finished before (resume) or left out by a `skip` choice.
    /// Counted, shown and recorded; `true` when passed over.
    pub(super) fn pass_over(
        &self,
        key: LayerKey,
        n: u32,
        plan: &RunPlan,
        summary: &mut RunSummary,
    ) -> bool {
        if plan.finished.contains(&key) {
            summary.layers_skipped += 1;
            self.emit(Progress::LayerSkipped { key });
            self.record_layer(key, "skipped", n, n, false);
            return true;
        }
        if plan.left_out.contains(&key) {
            summary.layers_left_out.push(key);
            self.emit(Progress::LayerSkipped { key });
            self.record_layer(key, "left_out", 0, n, false);
            return true;
        }
        false
    }

    /// A layer whose every vector was marked before the cut: journaled as done, nothing moves.
    pub(super) async fn complete_layer(
        &self,
        journal: &mut Journal,
        work: &LayerWork,
    ) -> LayerStep<()> {
        self.journal_done(journal, work, false).await?;
        self.layer_done(work);
        Ok(())
    }

    /// Marks one layer through its phases, from `work.first`, with list buffer `list_buf`.
    pub(super) async fn mark_layer(
        &mut self,
        journal: &mut Journal,
        work: &LayerWork,
        list_buf: u8,
    ) -> LayerStep<LayerTiming> {
        self.start_move(work).await?;
        let list = self.begin_list(journal, work).await?;
        let in_position = self.load_while_moving(work, &list, list_buf).await?;
        let running = self.start_list(work, list_buf, in_position.at).await?;
        let t_done = self
            .wait_done(work, &list, list_buf, running.t_exec)
            .await?;
        let gate_off_s = self.gate_off(work).await?;
        self.phase(work, Phase::Journal);
        let t_journal = Instant::now();
        self.journal_done(journal, work, true).await?;
        let journal_s = t_journal.elapsed().as_secs_f64();
        self.layer_done(work);
        let total_s = work.started.elapsed().as_secs_f64();
        let motion_s = (in_position.at - work.started).as_secs_f64();
        let list_s = (t_done - running.t_exec).as_secs_f64();
        Ok(LayerTiming {
            key: work.key,
            motion_s,
            load_s: in_position.load_s,
            to_execute_s: running.to_execute_s,
            after_done_s: t_done.elapsed().as_secs_f64(),
            device_replies_s: running.emission_on_s + gate_off_s,
            journal_s,
            list_s,
            modelled_s: list.modelled_s,
            total_s,
            overhead_s: total_s - motion_s - list_s,
        })
    }

    /// Shows the layer entering `phase`.
    fn phase(&self, work: &LayerWork, phase: Phase) {
        self.emit(Progress::Phase {
            key: work.key,
            index: work.index,
            phase,
        });
    }

    /// [`Phase::Move`]: the CNC starts the move to the layer's pose.
    async fn start_move(&mut self, work: &LayerWork) -> LayerStep<()> {
        self.phase(work, Phase::Move);
        self.record_layer(work.key, "started", work.first, work.vectors, false);
        let (c, t) = (self.cancel.clone(), self.options.timeouts);
        Self::guard(
            &c,
            t.cnc_reply,
            Device::Cnc,
            "move",
            self.cell.cnc.start_move(&work.layer.pose),
        )
        .await
        .at(Phase::Move, false)?;
        // The previous layer's record goes to disk while the CNC moves, not between its done
        // and this move. A flush that timed out (a hung disk) takes the way down.
        self.flush_record();
        if self.record_disk_hung() {
            return Err(StopCause::Record {
                message: format!(
                    "the record's disk did not flush within {} ms",
                    crate::record::FLUSH_TIMEOUT_MS
                ),
            })
            .at(Phase::Move, false);
        }
        Ok(())
    }

    /// [`Phase::LoadList`], host side: the list built from `work.first` and its `layer_begin`
    /// journaled. Until `EXECUTE` the galvo reports the previous list, so a stop from here to
    /// `EXECUTE` journals the cut at `first` (a preloaded list is not a marked layer).
    async fn begin_list(&self, journal: &mut Journal, work: &LayerWork) -> LayerStep<BegunList> {
        self.phase(work, Phase::LoadList);
        let commands = layer_list(&work.layer, &self.job.settings.plan.galvo, work.first)
            .map_err(|e| StopCause::Job {
                message: format!("{}: {e}", work.key),
            })
            .at(Phase::LoadList, false)?;
        let modelled_s = ListClock::list_s(&commands);
        // The wait for the list's end is bounded by this time: it must be one (checked before
        // the emission goes on, not where the deadline is taken while it is on).
        if !(modelled_s.is_finite() && modelled_s >= 0.0) {
            return Err(StopCause::Job {
                message: format!(
                    "{}: the list's modelled time is {modelled_s} s (check the job's galvo speeds and delays)",
                    work.key
                ),
            })
            .at(Phase::LoadList, false);
        }
        let tag = journal.next_tag();
        journal
            .append_within(
                &Entry::LayerBegin {
                    key: work.key,
                    first_vector: work.first,
                    vectors: work.vectors,
                    tag,
                },
                self.options.timeouts.journal_write,
            )
            .await
            .map_err(|e| journal_failed(&e))
            .at(Phase::LoadList, false)?;
        Ok(BegunList {
            commands,
            tag,
            modelled_s,
        })
    }

    /// [`Phase::LoadList`] and [`Phase::WaitInPosition`]: preloading, the list goes into the
    /// other buffer while the CNC moves (the emission stays off; loading a list is not
    /// emitting). The first failure stops both (the other is dropped).
    async fn load_while_moving(
        &mut self,
        work: &LayerWork,
        list: &BegunList,
        list_buf: u8,
    ) -> LayerStep<InPosition> {
        let (c, t) = (self.cancel.clone(), self.options.timeouts);
        let load_timeout = t.galvo_load(list.commands.len());
        let (galvo, cnc) = (&self.cell.galvo, &mut self.cell.cnc);
        let load = async {
            let t0 = Instant::now();
            Self::guard(
                &c,
                load_timeout,
                Device::Galvo,
                "LOAD_LIST",
                galvo.load_list(list_buf, list.tag, &list.commands),
            )
            .await
            .map(|()| t0.elapsed().as_secs_f64())
            .map_err(|e| (Phase::LoadList, e))
        };
        let wait = async {
            Self::guard(
                &c,
                t.cnc_motion + Duration::from_secs(1),
                Device::Cnc,
                "wait in position",
                cnc.wait_in_position(t.cnc_motion),
            )
            .await
            .map(|_| Instant::now())
            .map_err(|e| (Phase::WaitInPosition, e))
        };
        let joined = tokio::try_join!(load, wait);
        self.phase(work, Phase::WaitInPosition);
        match joined {
            Ok((load_s, at)) => Ok(InPosition { load_s, at }),
            Err((phase, cause)) => Err(LayerFault {
                cause,
                phase,
                began: true,
            }),
        }
    }

    /// [`Phase::EnableEmission`] and [`Phase::Execute`]: emission on (only now, in position
    /// with the list loaded), then the list started.
    async fn start_list(
        &mut self,
        work: &LayerWork,
        list_buf: u8,
        in_position_at: Instant,
    ) -> LayerStep<Running> {
        let (c, t) = (self.cancel.clone(), self.options.timeouts);
        self.phase(work, Phase::EnableEmission);
        let t_on = Instant::now();
        Self::guard(
            &c,
            t.laser_request(1),
            Device::Laser,
            "emission on",
            self.cell.laser.emission(true),
        )
        .await
        .at(Phase::EnableEmission, true)?;

        self.phase(work, Phase::Execute);
        let t_exec = Instant::now();
        let emission_on_s = (t_exec - t_on).as_secs_f64();
        Self::guard(
            &c,
            self.galvo_timeout(),
            Device::Galvo,
            "EXECUTE",
            self.cell.galvo.execute(list_buf),
        )
        .await
        .at(Phase::Execute, true)?;
        Ok(Running {
            t_exec,
            emission_on_s,
            to_execute_s: in_position_at.elapsed().as_secs_f64(),
        })
    }

    /// [`Phase::WaitDone`]: polls the galvo (and the laser's faults) until the list is done,
    /// within the list's modelled time × factor + margin; checks that every vector was marked.
    /// Returns when the done was seen.
    async fn wait_done(
        &mut self,
        work: &LayerWork,
        list: &BegunList,
        list_buf: u8,
        t_exec: Instant,
    ) -> LayerStep<Instant> {
        self.phase(work, Phase::WaitDone);
        let t = self.options.timeouts;
        let deadline = t_exec
            + Duration::from_secs_f64(list.modelled_s * t.list_time_factor)
            + t.list_time_margin;
        let mut last_laser_check: Option<Instant> = None;
        let mut last_cnc_check: Option<Instant> = None;
        let done_status = loop {
            if last_laser_check.is_none_or(|l| l.elapsed() >= self.options.laser_poll) {
                self.check_laser().await.at(Phase::WaitDone, true)?;
                last_laser_check = Some(Instant::now());
            }
            if last_cnc_check.is_none_or(|l| l.elapsed() >= self.options.cnc_poll) {
                self.check_cnc_holds(&work.layer.pose)
                    .await
                    .at(Phase::WaitDone, true)?;
                last_cnc_check = Some(Instant::now());
            }
            let s = self.galvo_status().await.at(Phase::WaitDone, true)?;
            if s.tag != list.tag || s.list != list_buf {
                return Err(galvo_fault(format!(
                    "the galvo reports list {} tag {}, not list {list_buf} tag {}",
                    s.list, s.tag, list.tag
                )))
                .at(Phase::WaitDone, true);
            }
            self.emit(Progress::Vectors {
                key: work.key,
                done: work.first + s.marks_done,
                total: work.vectors,
            });
            match s.state {
                ControllerState::Executing => {}
                ControllerState::Idle => break s,
                other => {
                    return Err(galvo_fault(format!(
                        "the galvo stopped the list: {other:?}, error code {}",
                        s.last_error
                    )))
                    .at(Phase::WaitDone, true);
                }
            }
            if Instant::now() > deadline {
                return Err(StopCause::Link {
                    device: Device::Galvo,
                    message: format!(
                        "list not done within {:.3} s",
                        (deadline - t_exec).as_secs_f64()
                    ),
                })
                .at(Phase::WaitDone, true);
            }
            tokio::select! {
                () = self.cancel.cancelled() => {
                    return Err(StopCause::Cancelled).at(Phase::WaitDone, true);
                }
                () = tokio::time::sleep(Duration::from_millis(STATUS_POLL_MS)) => {}
            }
        };
        let t_done = Instant::now();
        Self::check_marks(work, list, &done_status).at(Phase::WaitDone, true)?;
        Ok(t_done)
    }

    /// The CNC, while a list runs: still at the layer's pose (within
    /// [`crate::cnc::HOLD_TOLERANCE`]), out of E-stop and on. Anything else (a jog or an MDI
    /// from another session, an E-stop, an abort that left it elsewhere) is a CNC fault.
    async fn check_cnc_holds(&mut self, pose: &trim_cell::job::Pose) -> Result<(), StopCause> {
        let t = self.options.timeouts;
        let w = Self::guard(
            &self.cancel,
            t.cnc_reply,
            Device::Cnc,
            "position and state",
            self.cell.cnc.watch(),
        )
        .await?;
        let fault = |message: String| StopCause::Fault {
            device: Device::Cnc,
            message,
        };
        if w.state.estop || !w.state.on {
            return Err(fault(format!(
                "the machine left its enabled state while the layer marked ({})",
                if w.state.estop {
                    "E-stop"
                } else {
                    "switched off"
                }
            )));
        }
        for (axis, &commanded) in &pose.0 {
            let actual = w.positions.world.axis(axis).unwrap_or(f64::NAN);
            let held = (actual - commanded).abs() <= crate::cnc::HOLD_TOLERANCE; // false for NaN
            if !held {
                return Err(fault(format!(
                    "the machine moved while the layer marked: {axis} at {actual:.4}, the layer's pose {commanded:.4}"
                )));
            }
        }
        Ok(())
    }

    /// The laser's faults, while a list runs.
    async fn check_laser(&mut self) -> Result<(), StopCause> {
        let t = self.options.timeouts;
        let queries = self.cell.laser.profile().queries.len();
        Self::guard(
            &self.cancel,
            t.laser_request(queries),
            Device::Laser,
            "status",
            self.cell.laser.check(),
        )
        .await?;
        Ok(())
    }

    /// The finished list marked every vector of the attempt with light, and ran every command.
    fn check_marks(
        work: &LayerWork,
        list: &BegunList,
        done: &StatusBlock,
    ) -> Result<(), StopCause> {
        let expected_marks = work.vectors - work.first;
        if done.marks_done != expected_marks || done.commands_done as usize != list.commands.len() {
            return Err(galvo_fault(format!(
                "list ended with {} of {expected_marks} vectors marked with light ({} of {} commands)",
                done.marks_done,
                done.commands_done,
                list.commands.len()
            )));
        }
        Ok(())
    }

    /// [`Phase::GateOff`]: emission off before the next move. Returns the laser's reply time
    /// (s).
    async fn gate_off(&mut self, work: &LayerWork) -> LayerStep<f64> {
        self.phase(work, Phase::GateOff);
        let t_gate = Instant::now();
        let (c, t) = (self.cancel.clone(), self.options.timeouts);
        Self::guard(
            &c,
            t.laser_request(1),
            Device::Laser,
            "emission off",
            self.cell.laser.emission(false),
        )
        .await
        .at(Phase::GateOff, true)?;
        Ok(t_gate.elapsed().as_secs_f64())
    }

    /// [`Phase::Journal`]: the layer's `layer_done`, fsynced before the next layer begins.
    /// `began`: this run journaled the layer's `layer_begin` (see [`LayerFault::began`]).
    /// Bounded by the journal-write timeout: a hung disk takes the way down.
    async fn journal_done(
        &self,
        journal: &mut Journal,
        work: &LayerWork,
        began: bool,
    ) -> LayerStep<()> {
        journal
            .append_within(
                &Entry::LayerDone {
                    key: work.key,
                    vectors: work.vectors,
                },
                self.options.timeouts.journal_write,
            )
            .await
            .map_err(|e| journal_failed(&e))
            .at(Phase::Journal, began)
    }

    /// A layer journaled as done: recorded (flushed during the next move, or when the run
    /// ends or stops) and shown.
    fn layer_done(&self, work: &LayerWork) {
        self.record_layer(work.key, "done", work.vectors, work.vectors, false);
        self.emit(Progress::LayerDone {
            key: work.key,
            index: work.index,
        });
    }
}
