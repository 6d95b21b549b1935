//! The executor: a state machine over the Job (DESIGN.md "Execution and devices", paper §3).
//!
//! Per layer, in job order: [`Phase::Move`] → [`Phase::LoadList`] (into the other list
//! buffer, while the CNC moves: preloading) → [`Phase::WaitInPosition`] →
//! [`Phase::EnableEmission`] → [`Phase::Execute`] → [`Phase::WaitDone`] → [`Phase::GateOff`]
//! → [`Phase::Journal`]. Interlocks:
//! - emission is enabled only after the CNC is in position and the list is loaded, and disabled
//!   before the next move, so the laser never emits while the CNC moves; the galvo gate opens
//!   only while its list marks; loading a list while the CNC moves is not emitting (the
//!   emission stays off until in position);
//! - every device await has a timeout ([`Timeouts`]), and a cancel (Ctrl-C) is honoured at every
//!   await;
//! - on any fault, timeout, lost link, bad reply or cancel: **laser off first** (the serial
//!   emission-off command and the galvo laser signals off, together), **then** the galvo list is
//!   stopped, **then** motion is stopped; then the layer is journaled as cut, with how far it got.
//!   Host-side failures after preparation (a journal write, the list encoding) take the same way
//!   down: nothing returns early past [`Phase::Prepare`];
//! - a finished layer is journaled (fsync) before the next begins; [`Executor::resume`] continues
//!   at the first unfinished layer, from the first vector the galvo did not mark. When neither
//!   the galvo nor the journal can tell how far a cut layer got, resume refuses to start unless
//!   the operator chose ([`ExecOptions::cut_layer`]): redo the layer or leave it out; the choice
//!   is journaled before anything is switched on.
//!
//! The module: the public types here, with [`Executor`]'s run loop; `layer` holds one layer's
//! phases, `resume` where a resumed run starts, `shutdown` the way down and the one exit path
//! every failure after preparation takes, `gate` the optional [`ZoneGate`] asked before each
//! zone (red-light framing, `run --frame`).

use std::collections::BTreeSet;
use std::future::Future;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use tokio::sync::mpsc::UnboundedSender;
use tokio_util::sync::CancellationToken;
use trim_cell::galvo_timing::ListComposition;
use trim_cell::job::{Job, LayerKey};

use crate::cell_devices::{Cell, Timeouts};
use crate::galvo::list::{layer_list, vector_count};
use crate::galvo::protocol::StatusBlock;
use crate::journal::{CutLayer, Journal, JournalError, JournalSink, JournalState};
pub use crate::laser::client::{OffAttempt, OffPort};
use crate::record::{LogLevel, SharedRecorder};
use crate::tap::{Device, now_ns};

pub use gate::{ZoneDecision, ZoneGate};
use layer::LayerWork;
use resume::CutStart;
use shutdown::Fault;

mod gate;
mod layer;
mod resume;
mod shutdown;

/// How often the galvo status is polled while a list runs (ms).
pub const STATUS_POLL_MS: u64 = 10;
/// How often the laser's faults are checked while a list runs (ms); also once right after
/// `EXECUTE`.
pub const LASER_POLL_MS: u64 = 250;
/// How often the CNC's position and state are read while a list runs (ms); also once right
/// after `EXECUTE`.
pub const CNC_POLL_MS: u64 = 50;

/// The steps of a layer (and the run's preparation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub enum Phase {
    /// Before the first layer: reset the galvo, laser off and checked, CNC enabled.
    Prepare,
    /// CNC move to the layer's pose.
    Move,
    /// Wait until the CNC is in position.
    WaitInPosition,
    /// Load the layer's list into a galvo list buffer.
    LoadList,
    /// Laser emission on.
    EnableEmission,
    /// Start the list.
    Execute,
    /// Wait until the list is done.
    WaitDone,
    /// Laser emission off.
    GateOff,
    /// Journal the finished layer.
    Journal,
    /// Before a zone's first layer: the [`ZoneGate`] (framing, the operator's answer).
    Frame,
}

impl Phase {
    /// The phases of one layer, in order.
    pub const LAYER: [Phase; 8] = [
        Phase::Move,
        Phase::LoadList,
        Phase::WaitInPosition,
        Phase::EnableEmission,
        Phase::Execute,
        Phase::WaitDone,
        Phase::GateOff,
        Phase::Journal,
    ];
}

/// Progress events for a progress display.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub enum Progress {
    /// The run starts.
    Started {
        /// Layers in the job.
        layers: usize,
        /// Layers already finished (resume).
        finished_before: usize,
        /// Vectors in the job.
        vectors: u64,
    },
    /// A layer enters a phase.
    Phase {
        /// The layer.
        key: LayerKey,
        /// Its position in the job (0-based).
        index: usize,
        /// The phase.
        phase: Phase,
    },
    /// Vectors of the running layer marked so far.
    Vectors {
        /// The layer.
        key: LayerKey,
        /// Marked.
        done: u32,
        /// In the layer.
        total: u32,
    },
    /// A layer is finished and journaled.
    LayerDone {
        /// The layer.
        key: LayerKey,
        /// Its position in the job.
        index: usize,
    },
    /// A layer was finished in an earlier run (resume).
    LayerSkipped {
        /// The layer.
        key: LayerKey,
    },
}

/// Why a run stopped.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub enum StopCause {
    /// Cancelled by the operator.
    Cancelled,
    /// A device's link failed (timeout, lost link, garbled or unexpected reply).
    Link {
        /// The device.
        device: Device,
        /// What happened.
        message: String,
    },
    /// A device refused or reported a fault.
    Fault {
        /// The device.
        device: Device,
        /// What happened.
        message: String,
    },
    /// The journal could not be written (a full disk, an I/O error).
    Journal {
        /// What happened.
        message: String,
    },
    /// A layer's list could not be built.
    Job {
        /// What happened.
        message: String,
    },
    /// The run record's disk hangs: a flush did not return within its timeout.
    Record {
        /// What happened.
        message: String,
    },
}

impl std::fmt::Display for StopCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopCause::Cancelled => f.write_str("cancelled"),
            StopCause::Link { device, message } => write!(f, "{device} link: {message}"),
            StopCause::Fault { device, message } => write!(f, "{device} fault: {message}"),
            StopCause::Journal { message } => write!(f, "journal: {message}"),
            StopCause::Job { message } => write!(f, "job: {message}"),
            StopCause::Record { message } => write!(f, "record: {message}"),
        }
    }
}

/// What the way down did, in order: each step acknowledged or not, what went wrong, and when
/// (host view, from the fault's detection).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ShutdownReport {
    /// The serial emission-off was acknowledged (by one of [`ShutdownReport::emission_off`]'s
    /// attempts). When not, the laser's state is unknown.
    pub laser_off_ok: bool,
    /// The galvo laser signals off was acknowledged.
    pub galvo_signals_off_ok: bool,
    /// The galvo link was lost, and the way down opened a new session for its laser signals
    /// off, stop and status (the controller drops the signals as its connection is replaced).
    pub galvo_reopened: bool,
    /// The galvo stop was acknowledged.
    pub galvo_stop_ok: bool,
    /// The CNC abort was acknowledged.
    pub cnc_abort_ok: bool,
    /// From the fault's detection to both laser-off commands answered or given up (s).
    pub laser_off_s: f64,
    /// From detection to the end of the way down (s).
    pub total_s: f64,
    /// Every attempt of the serial emission-off (the port already open, then reopened).
    pub emission_off: Vec<OffAttempt>,
    /// Why each step that was not acknowledged failed, in the way down's order.
    pub failures: Vec<StepFailure>,
}

impl ShutdownReport {
    /// Every step acknowledged.
    #[must_use]
    pub fn all_acknowledged(&self) -> bool {
        self.laser_off_ok && self.galvo_signals_off_ok && self.galvo_stop_ok && self.cnc_abort_ok
    }
}

/// A step of the way down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShutdownStep {
    /// The laser's serial emission-off.
    EmissionOff,
    /// The galvo's laser signals off.
    GalvoSignalsOff,
    /// The galvo list stopped.
    GalvoStop,
    /// The CNC's motion aborted.
    CncAbort,
}

impl std::fmt::Display for ShutdownStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ShutdownStep::EmissionOff => "laser emission-off",
            ShutdownStep::GalvoSignalsOff => "galvo laser signals off",
            ShutdownStep::GalvoStop => "galvo stop",
            ShutdownStep::CncAbort => "CNC abort",
        })
    }
}

/// A step of the way down that was not acknowledged.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StepFailure {
    /// The step.
    pub step: ShutdownStep,
    /// What went wrong (the last attempt's error for the emission-off).
    pub error: String,
    /// From detection to the step given up (s).
    pub after_s: f64,
}

/// A run that stopped before the end.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Stopped {
    /// Why.
    pub cause: StopCause,
    /// The layer it stopped in (`None`: during preparation).
    pub key: Option<LayerKey>,
    /// The phase it stopped in.
    pub phase: Phase,
    /// Vectors of that layer marked, when known.
    pub vectors_done: Option<u32>,
    /// Vectors in that layer.
    pub vectors: u32,
    /// Layers finished (this run and before).
    pub layers_finished: usize,
    /// The way down.
    pub shutdown: ShutdownReport,
    /// When the fault was detected.
    #[serde(skip)]
    pub detected_at: Option<Instant>,
}

/// A run that did not finish.
#[derive(Debug, thiserror::Error)]
pub enum ExecError {
    /// Stopped by a fault or a cancel after the way down (whose steps, acknowledged or not,
    /// are in [`Stopped::shutdown`]: the laser is off only when `laser_off_ok`); the layer
    /// journaled as cut.
    #[error("run stopped in {} ({phase:?}): {cause}; {done} of {total} vectors of the layer marked", .0.key.map_or("preparation".to_owned(), |k| k.to_string()), phase = .0.phase, cause = .0.cause, done = .0.vectors_done.map_or("unknown".to_owned(), |v| v.to_string()), total = .0.vectors)]
    Stopped(Box<Stopped>),
    /// The journal.
    #[error(transparent)]
    Journal(#[from] JournalError),
    /// The job cannot be sent to the galvo, or moves outside the machine's limits.
    #[error("job: {0}")]
    Job(String),
    /// The CNC is not ready (in E-stop, off, not homed) and the step that would make it so was
    /// not allowed ([`ExecOptions::enable`]), or its state could not be read; nothing was
    /// switched on.
    #[error("the CNC: {0}; nothing was switched on")]
    MachineNotReady(String),
    /// Resume cannot tell how far the cut layer got and no choice was given
    /// ([`ExecOptions::cut_layer`]); nothing was switched on.
    #[error("resume: cannot tell how far {key} got: {reason}. Choose what to do with the layer: redo (marks it again from vector {first_vector}: up to {} of its {vectors} vectors may be marked twice) or skip (leaves it out, unmarked; the report lists it)", vectors - first_vector)]
    ResumeUnknown {
        /// The layer.
        key: LayerKey,
        /// Why.
        reason: String,
        /// The first vector of the attempt whose progress is unknown.
        first_vector: u32,
        /// Vectors in the layer.
        vectors: u32,
    },
}

/// What resume did with a layer it could not tell the progress of.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct CutLayerOutcome {
    /// The layer.
    pub key: LayerKey,
    /// The operator's choice.
    pub choice: CutLayer,
    /// The first vector of the attempt whose progress was unknown (redo starts there).
    pub first_vector: u32,
    /// Vectors in the layer.
    pub vectors: u32,
    /// Redo: vectors that may have been marked twice; skip: 0.
    pub vectors_maybe_twice: u32,
}

/// One layer's timing (wall clock, s).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LayerTiming {
    /// The layer.
    pub key: LayerKey,
    /// Move and wait in position (the list is loaded meanwhile).
    pub motion_s: f64,
    /// `LOAD_LIST`, overlapped with the move (hidden when shorter than `motion_s`).
    pub load_s: f64,
    /// From "in position" to `EXECUTE` acknowledged (emission on, execute): the galvo idle
    /// before the list runs.
    pub to_execute_s: f64,
    /// From done seen to the layer journaled (emission off, journal fsync, record).
    pub after_done_s: f64,
    /// Of `overhead_s`: awaiting the laser's replies to emission on and off (`EXECUTE`'s reply
    /// counts in `list_s`).
    pub device_replies_s: f64,
    /// Of `after_done_s`: the `layer_done` journal write and its fsync (the disk's time; the
    /// next layer begins only after it). The rest of the overhead is the host's own time.
    pub journal_s: f64,
    /// From `EXECUTE` to done seen.
    pub list_s: f64,
    /// The galvo's modelled time of the list.
    pub modelled_s: f64,
    /// The whole layer.
    pub total_s: f64,
    /// `total − motion − list`: the executor's per-layer overhead outside the CNC's motion and
    /// the galvo's list (emission on/off, `EXECUTE`, journal, record; a load longer than the
    /// move shows in `motion_s`).
    pub overhead_s: f64,
}

/// A finished run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunSummary {
    /// Layers in the job.
    pub layers_total: usize,
    /// Layers marked in this run.
    pub layers_marked: usize,
    /// Layers skipped as finished before (resume).
    pub layers_skipped: usize,
    /// Vectors marked in this run.
    pub vectors_marked: u64,
    /// The cut layer this run continued, and the vector it continued from.
    pub resumed_from: Option<(LayerKey, u32)>,
    /// The cut layer this run redid or skipped because its progress was unknown.
    pub cut_layer: Option<CutLayerOutcome>,
    /// Layers left out by a `skip` choice (this run's and earlier), never marked.
    pub layers_left_out: Vec<LayerKey>,
    /// Wall time (s).
    pub wall_s: f64,
    /// The galvo's modelled time of this run's lists (s).
    pub galvo_modelled_s: f64,
    /// The timing model's estimate for the layers marked whole in this run (s).
    pub galvo_estimate_s: f64,
    /// Per layer.
    pub layers: Vec<LayerTiming>,
}

/// Executor settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExecOptions {
    /// Timeouts.
    pub timeouts: Timeouts,
    /// Laser power to set before the first layer (%), if any.
    pub laser_power_pct: Option<f64>,
    /// How often the laser's faults are checked while a list runs (also once right after
    /// `EXECUTE`).
    pub laser_poll: Duration,
    /// How often the CNC is read while a list runs (also once right after `EXECUTE`): a
    /// position off the layer's pose by more than [`crate::cnc::HOLD_TOLERANCE`], or the
    /// machine in E-stop or off, takes the way down.
    pub cnc_poll: Duration,
    /// On resume, what to do with a cut layer whose progress neither the galvo nor the journal
    /// can tell (`None`: refuse with [`ExecError::ResumeUnknown`]). Not used when the progress
    /// is known.
    pub cut_layer: Option<CutLayer>,
    /// What preparation may do to the CNC beyond its mode: reset the E-stop and switch it on,
    /// home it. A machine that needs a step not allowed is refused before anything is switched
    /// on ([`ExecError::MachineNotReady`]).
    pub enable: crate::cnc::EnableSteps,
    /// The machine (`[machine]`): every layer's pose is checked against its axis limits before
    /// anything moves ([`crate::limits`]). `None`: only the CNC's own limits guard the moves.
    pub machine: Option<trim_cell::kinematics::MachineSettings>,
}

impl Default for ExecOptions {
    fn default() -> Self {
        ExecOptions {
            timeouts: Timeouts::default(),
            laser_power_pct: None,
            laser_poll: Duration::from_millis(LASER_POLL_MS),
            cnc_poll: Duration::from_millis(CNC_POLL_MS),
            cut_layer: None,
            enable: crate::cnc::EnableSteps::default(),
            machine: None,
        }
    }
}

/// Replaces the journal's sink (see [`Executor::with_journal_sink`]).
type SinkWrap = Box<dyn FnOnce(Box<dyn JournalSink>) -> Box<dyn JournalSink> + Send>;

/// Runs a Job on a Cell.
pub struct Executor {
    job: Job,
    cell: Cell,
    journal_path: PathBuf,
    recorder: Option<SharedRecorder>,
    options: ExecOptions,
    progress: Option<UnboundedSender<Progress>>,
    cancel: CancellationToken,
    journal_wrap: Option<SinkWrap>,
    zone_gate: Option<Box<dyn ZoneGate>>,
}

type Step<T> = Result<T, StopCause>;

impl Executor {
    /// An executor for `job` on `cell`, journaling to `journal_path`, recording to `recorder`.
    #[must_use]
    pub fn new(
        job: Job,
        cell: Cell,
        journal_path: impl Into<PathBuf>,
        recorder: Option<SharedRecorder>,
    ) -> Executor {
        Executor {
            job,
            cell,
            journal_path: journal_path.into(),
            recorder,
            options: ExecOptions::default(),
            progress: None,
            cancel: CancellationToken::new(),
            journal_wrap: None,
            zone_gate: None,
        }
    }

    /// Asks `gate` before the first layer of each zone the run marks (`run --frame`).
    #[must_use]
    pub fn with_zone_gate(mut self, gate: Box<dyn ZoneGate>) -> Executor {
        self.zone_gate = Some(gate);
        self
    }

    /// Wraps the journal's sink once it is open (`wrap(file)`): for tests that inject journal
    /// write failures.
    #[must_use]
    pub fn with_journal_sink(
        mut self,
        wrap: impl FnOnce(Box<dyn JournalSink>) -> Box<dyn JournalSink> + Send + 'static,
    ) -> Executor {
        self.journal_wrap = Some(Box::new(wrap));
        self
    }

    fn wrap_journal(&mut self, journal: &mut Journal) {
        if let Some(wrap) = self.journal_wrap.take() {
            journal.wrap_sink(wrap);
        }
    }

    /// Replaces the options.
    #[must_use]
    pub fn with_options(mut self, options: ExecOptions) -> Executor {
        self.options = options;
        self
    }

    /// Runs the job from the start (the journal must not exist).
    pub async fn run(
        mut self,
        cancel: CancellationToken,
        progress: Option<UnboundedSender<Progress>>,
    ) -> Result<RunSummary, ExecError> {
        self.cancel = cancel;
        self.progress = progress;
        self.check_job()?;
        self.check_machine().await?;
        let mut journal = Journal::create(&self.journal_path, &self.job)?;
        self.wrap_journal(&mut journal);
        self.execute(journal, JournalState::default()).await
    }

    /// Continues a stopped run: skips finished layers, continues the cut layer from the first
    /// vector not marked, never marks a vector twice.
    pub async fn resume(
        mut self,
        cancel: CancellationToken,
        progress: Option<UnboundedSender<Progress>>,
    ) -> Result<RunSummary, ExecError> {
        self.cancel = cancel;
        self.progress = progress;
        self.check_job()?;
        self.check_machine().await?;
        let (mut journal, state) = Journal::resume(&self.journal_path, &self.job)?;
        self.wrap_journal(&mut journal);
        self.execute(journal, state).await
    }

    fn check_job(&self) -> Result<(), ExecError> {
        // Never move toward a pose outside the axis limits, whatever validation was overridden.
        if let Some(z) = self.job.zones.iter().find(|z| z.unreachable.is_some()) {
            return Err(ExecError::Job(format!(
                "zone {} (contours {:?}) is unreachable: {}",
                z.id,
                z.contours,
                z.unreachable.as_deref().unwrap_or_default()
            )));
        }
        if let Some(machine) = &self.options.machine {
            crate::limits::check_poses(&self.job, machine, None)
                .map_err(|e| ExecError::Job(e.to_string()))?;
        }
        // The lists' speeds and delays, as the planner checked them: a job file edited (or
        // written by another tool) to a speed of 0 would make a list's modelled time infinite,
        // and its wait's deadline with it.
        self.job
            .settings
            .plan
            .galvo
            .validate()
            .map_err(|e| ExecError::Job(format!("the job's {e}")))?;
        for (key, _, layer) in self.job.layers() {
            layer_list(layer, &self.job.settings.plan.galvo, 0)
                .map_err(|e| ExecError::Job(format!("{key}: {e}")))?;
        }
        Ok(())
    }

    /// Refuses a machine that is in E-stop, off or unhomed when the step that fixes it was not
    /// allowed, before anything is switched on.
    async fn check_machine(&mut self) -> Result<(), ExecError> {
        let timeout = self.options.timeouts.cnc_reply * 3;
        let state = match tokio::time::timeout(timeout, self.cell.cnc.state()).await {
            Ok(Ok(Ok(s))) => s,
            Ok(Ok(Err(f))) => return Err(ExecError::MachineNotReady(f.to_string())),
            Ok(Err(e)) => return Err(ExecError::MachineNotReady(e.to_string())),
            Err(_) => {
                return Err(ExecError::MachineNotReady(format!(
                    "no state within {} ms",
                    timeout.as_millis()
                )));
            }
        };
        match self.options.enable.refusal(state) {
            Some(f) => Err(ExecError::MachineNotReady(f.to_string())),
            None => Ok(()),
        }
    }

    fn emit(&self, p: Progress) {
        if let Some(tx) = &self.progress {
            let _ = tx.send(p);
        }
    }

    fn log(&self, level: LogLevel, message: &str) {
        if let Some(r) = &self.recorder {
            let mut r = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if let Err(e) = r.log(now_ns(), level, message) {
                tracing::warn!(error = %e, "record: log lost");
            }
        }
    }

    fn record_layer(&self, key: LayerKey, state: &str, done: u32, total: u32, flush: bool) {
        if let Some(r) = &self.recorder {
            let mut r = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            let res = r.layer(now_ns(), key, state, done, total, &self.job);
            // A hung disk is not asked again (each flush would wait its whole timeout).
            let res = res.and_then(|()| {
                if flush && !r.disk_hung() {
                    r.flush()
                } else {
                    Ok(())
                }
            });
            if let Err(e) = res {
                tracing::warn!(error = %e, "record: layer message lost");
            }
        }
    }

    /// Whether the record's disk hangs (a flush timed out).
    fn record_disk_hung(&self) -> bool {
        self.recorder.as_ref().is_some_and(|r| {
            r.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .disk_hung()
        })
    }

    /// Writes what the record holds to disk, bounded by the record's flush timeout (a failure is
    /// logged: the record is not the journal; a hung disk is seen by
    /// [`Executor::record_disk_hung`]).
    fn flush_record(&self) {
        let Some(r) = &self.recorder else { return };
        let mut r = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        // A hung disk is not asked again (each flush would wait its whole timeout).
        if r.disk_hung() {
            return;
        }
        if let Err(e) = r.flush() {
            tracing::warn!(error = %e, "record: flush failed");
        }
    }

    /// Awaits a device call with a timeout and the cancel token; maps both error layers.
    pub(crate) async fn guard<T, E1: std::fmt::Display, E2: std::fmt::Display>(
        cancel: &CancellationToken,
        timeout: Duration,
        device: Device,
        what: &str,
        fut: impl Future<Output = Result<Result<T, E2>, E1>>,
    ) -> Step<T> {
        tokio::select! {
            biased;
            () = cancel.cancelled() => Err(StopCause::Cancelled),
            r = tokio::time::timeout(timeout, fut) => match r {
                Err(_) => Err(StopCause::Link { device, message: format!("{what}: no answer within {} ms", timeout.as_millis()) }),
                Ok(Err(e)) => Err(StopCause::Link { device, message: e.to_string() }),
                Ok(Ok(Err(f))) => Err(StopCause::Fault { device, message: f.to_string() }),
                Ok(Ok(Ok(v))) => Ok(v),
            }
        }
    }

    /// A timeout for a galvo request: every attempt's reply timeout plus slack.
    fn galvo_timeout(&self) -> Duration {
        self.options.timeouts.galvo_request()
    }

    async fn galvo_status(&self) -> Step<StatusBlock> {
        Self::guard(
            &self.cancel,
            self.galvo_timeout(),
            Device::Galvo,
            "STATUS",
            self.cell.galvo.status(),
        )
        .await
    }

    async fn prepare(&mut self) -> Step<()> {
        let steps = Preparation {
            laser_signals: true,
            check_laser: true,
            power_pct: self.options.laser_power_pct,
            enable: Some(self.options.enable),
        };
        prepare_cell(&mut self.cell, &self.options.timeouts, &self.cancel, steps).await
    }

    /// The run: announced, the cut layer decided (before anything is switched on), then the
    /// cell prepared and the layers marked. Every failure after preparation begins takes the
    /// way down ([`Executor::stop`]) through the one exit here.
    async fn execute(
        mut self,
        mut journal: Journal,
        state: JournalState,
    ) -> Result<RunSummary, ExecError> {
        let started = Instant::now();
        self.announce(&state.finished);

        // Decided before anything is switched on: a refusal leaves the cell as it was.
        let (cut_start, cut_layer) = self.resume_point(&state, &mut journal).await?;
        let mut left_out = state.left_out.clone();
        if let CutStart::Chosen(key, CutLayer::Skip, _) = cut_start {
            left_out.insert(key);
        }
        let plan = RunPlan {
            finished: state.finished.clone(),
            left_out,
            cut_start,
            cut_layer,
        };

        // From here on every error takes the way down: this is the one exit, no `?` below it.
        match self.mark_all(&mut journal, plan, started).await {
            Ok(summary) => Ok(summary),
            Err(fault) => Err(self.stop(&mut journal, fault).await),
        }
    }

    /// Tells the progress display, the record and the log that the run starts.
    fn announce(&self, finished: &BTreeSet<LayerKey>) {
        let total_layers = self.job.layers().count();
        let vectors_total: u64 = self
            .job
            .layers()
            .map(|(_, _, l)| u64::from(vector_count(l)))
            .sum();
        self.emit(Progress::Started {
            layers: total_layers,
            finished_before: finished.len(),
            vectors: vectors_total,
        });
        if let Some(r) = &self.recorder {
            let mut r = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if let Err(e) = r.zone_frames(now_ns(), &self.job) {
                tracing::warn!(error = %e, "record: zone frames lost");
            }
        }
        self.log(
            LogLevel::Info,
            &format!(
                "run starts: {total_layers} layers, {} finished before",
                finished.len()
            ),
        );
    }

    /// Prepares the cell, then marks the layers in job order, each through its phases
    /// ([`Executor::mark_layer`]). The first failure is returned, with how far its layer got,
    /// for the way down.
    async fn mark_all(
        &mut self,
        journal: &mut Journal,
        mut plan: RunPlan,
        started: Instant,
    ) -> Result<RunSummary, Fault> {
        let mut finished_count = plan.finished.len();
        if let Err(cause) = self.prepare().await {
            return Err(Fault::preparation(cause, finished_count));
        }
        let elapsed0 = self.galvo_status().await.map(|s| s.elapsed_ns).unwrap_or(0);
        let mut summary = RunSummary {
            layers_total: self.job.layers().count(),
            layers_marked: 0,
            layers_skipped: 0,
            vectors_marked: 0,
            resumed_from: plan.cut_start.resumed_from(),
            cut_layer: plan.cut_layer.take(),
            layers_left_out: Vec::new(),
            wall_s: 0.0,
            galvo_modelled_s: 0.0,
            galvo_estimate_s: 0.0,
            layers: Vec::new(),
        };
        let mut list_buf = 0_u8;
        let mut gated_zone = None;
        for (index, key) in self.layer_keys() {
            let layer = self.layer_at(index);
            let n = vector_count(&layer);
            if self.pass_over(key, n, &plan, &mut summary) {
                continue;
            }
            let first = plan.cut_start.first_vector(key, n);
            if first < n
                && let Err(f) = self.gate_zone(key, &mut gated_zone).await
            {
                let work = LayerWork::new(key, index, layer, first);
                return Err(self.layer_fault(journal, &work, f, finished_count).await);
            }
            let work = LayerWork::new(key, index, layer, first);
            let marked = if work.all_marked_before() {
                self.complete_layer(journal, &work).await.map(|()| None)
            } else {
                self.mark_layer(journal, &work, list_buf).await.map(Some)
            };
            let timing = match marked {
                Ok(timing) => timing,
                Err(f) => return Err(self.layer_fault(journal, &work, f, finished_count).await),
            };
            finished_count += 1;
            summary.layers_marked += 1;
            if let Some(timing) = timing {
                summary.vectors_marked += u64::from(work.vectors - work.first);
                if work.first == 0 {
                    summary.galvo_estimate_s += ListComposition::of(&work.layer.polylines)
                        .commanded_s(&self.job.settings.plan.galvo);
                }
                summary.layers.push(timing);
                list_buf ^= 1;
            }
        }
        Ok(self.finish(summary, elapsed0, started).await)
    }

    /// After the last layer: the galvo's modelled time, the laser signals off (always, even
    /// when a cancel came after the last layer), the log and the record flushed.
    async fn finish(
        &mut self,
        mut summary: RunSummary,
        elapsed0: u64,
        started: Instant,
    ) -> RunSummary {
        let elapsed1 = self
            .galvo_status()
            .await
            .map(|s| s.elapsed_ns)
            .unwrap_or(elapsed0);
        summary.galvo_modelled_s = elapsed1.saturating_sub(elapsed0) as f64 * 1e-9;
        // Not guarded by the run's cancel token: a cancel that lands after the last layer
        // must not skip the signals off.
        let (never, gt) = (CancellationToken::new(), self.galvo_timeout());
        if let Err(cause) = Self::guard(
            &never,
            gt,
            Device::Galvo,
            "LASER_SIGNALS off",
            self.cell.galvo.laser_signals(false),
        )
        .await
        {
            tracing::warn!(%cause, "executor: laser signals off at the end failed");
        }
        summary.wall_s = started.elapsed().as_secs_f64();
        self.log(
            LogLevel::Info,
            &format!(
                "run finished: {} layers marked, {} skipped",
                summary.layers_marked, summary.layers_skipped
            ),
        );
        self.flush_record();
        summary
    }
}

/// What a run does with each layer, decided before anything is switched on.
struct RunPlan {
    /// Layers finished in earlier runs.
    finished: BTreeSet<LayerKey>,
    /// Layers left out by a `skip` choice (earlier runs' and this one's).
    left_out: BTreeSet<LayerKey>,
    /// Where the cut layer starts.
    cut_start: CutStart,
    /// The operator's choice for a cut layer of unknown progress, if one was made.
    cut_layer: Option<CutLayerOutcome>,
}

/// What [`prepare_cell`] does beyond shutting the light path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Preparation {
    /// The galvo's laser signals: on to mark; off to frame (its gate cannot open).
    pub laser_signals: bool,
    /// Check the laser's status (marking).
    pub check_laser: bool,
    /// Set the laser's power (%), if given.
    pub power_pct: Option<f64>,
    /// Reset the galvo's latched error and enable the CNC with these steps; `None` when the
    /// cell was prepared already (a frame inside a run).
    pub enable: Option<crate::cnc::EnableSteps>,
}

/// The cell made ready, in the one order a run and a frame share: emission off (acknowledged);
/// the galvo's latched error reset; its laser signals on or off; the laser's status checked and
/// its power set; the CNC enabled. Each step as [`Preparation`] asks, each under its timeout.
pub(crate) async fn prepare_cell(
    cell: &mut Cell,
    timeouts: &Timeouts,
    cancel: &CancellationToken,
    steps: Preparation,
) -> Step<()> {
    let (gt, lt) = (timeouts.galvo_request(), timeouts.laser_request(1));
    Executor::guard(
        cancel,
        lt,
        Device::Laser,
        "emission off",
        cell.laser.emission(false),
    )
    .await?;
    if steps.enable.is_some() {
        Executor::guard(
            cancel,
            gt,
            Device::Galvo,
            "RESET_ERROR",
            cell.galvo.reset_error(),
        )
        .await?;
    }
    let signals = if steps.laser_signals {
        "LASER_SIGNALS on"
    } else {
        "LASER_SIGNALS off"
    };
    let set_signals = cell.galvo.laser_signals(steps.laser_signals);
    Executor::guard(cancel, gt, Device::Galvo, signals, set_signals).await?;
    if steps.check_laser {
        let lt_all = timeouts.laser_request(cell.laser.profile().queries.len());
        Executor::guard(cancel, lt_all, Device::Laser, "status", cell.laser.check()).await?;
    }
    if let Some(p) = steps.power_pct {
        Executor::guard(
            cancel,
            lt,
            Device::Laser,
            "set power",
            cell.laser.set_power_pct(p),
        )
        .await?;
    }
    if let Some(enable) = steps.enable {
        let enabling = cell.cnc.enable(enable);
        Executor::guard(cancel, timeouts.cnc_motion, Device::Cnc, "enable", enabling).await?;
    }
    Ok(())
}
