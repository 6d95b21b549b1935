//! Red-light framing on the cell: the CNC moves to a layer's pose (as the executor moves it,
//! with the same timeouts), then the galvo traces the layer's outline
//! ([`crate::galvo::outline`]) with the pointer on and the process laser's light path shut:
//! emission off (acknowledged by the laser first), the galvo's laser signals disabled (so its
//! gate cannot open), the list run by `EXECUTE_FRAME` (docs/protocols/galvo.md §5a), which never
//! opens the gate. The trace repeats until a number of passes or until the caller's `hold`
//! resolves (an operator's Enter), after at least one whole pass.
//!
//! Every device await has a timeout and honours the cancel token. On any failure: the galvo is
//! stopped (which drops its pointer and signals), the pointer switched off, emission off again,
//! motion stopped, each within the shutdown step, and the failure returned.

use std::future::Future;
use std::time::{Duration, Instant};

use tokio_util::sync::CancellationToken;
use trim_cell::job::{Job, Layer, LayerKey};

use crate::cell_devices::{Cell, Timeouts};
use crate::executor::{Executor, Preparation, StopCause, prepare_cell};
use crate::galvo::GalvoClient;
use crate::galvo::list_clock::ListClock;
use crate::galvo::outline::{Outline, OutlineKind, frame_list, frame_tag, layer_outline};
use crate::galvo::protocol::StatusBlock;
use crate::tap::Device;

/// How often the galvo is polled while a frame is traced (ms).
pub const FRAME_POLL_MS: u64 = 25;

/// Framing settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSettings {
    /// Device timeouts (the executor's).
    pub timeouts: Timeouts,
    /// Hull or box.
    pub outline: OutlineKind,
    /// The galvo list buffer the frame list is loaded into.
    pub list: u8,
    /// Before moving: reset the galvo's latched error and enable the CNC, as a run's
    /// preparation does (a standalone `trimctl frame`; not inside a run, which prepared already).
    pub prepare: bool,
    /// What that preparation may do to the CNC (see [`crate::cnc::EnableSteps`]).
    pub enable: crate::cnc::EnableSteps,
}

impl FrameSettings {
    /// Default timeouts, the convex hull, list 0, with preparation.
    #[must_use]
    pub fn new(outline: OutlineKind) -> FrameSettings {
        FrameSettings {
            timeouts: Timeouts::default(),
            outline,
            list: 0,
            prepare: true,
            enable: crate::cnc::EnableSteps::default(),
        }
    }

    fn galvo_timeout(&self) -> Duration {
        self.timeouts.galvo_request()
    }
}

/// A layer framed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Framed {
    /// The layer.
    pub key: LayerKey,
    /// What was traced (bits, galvo field frame).
    pub outline: Outline,
    /// Whole passes the galvo reports traced.
    pub passes_done: u32,
    /// Vectors the galvo reports traced (all passes).
    pub vectors_traced: u32,
    /// The modelled time of one pass (s).
    pub pass_s: f64,
    /// From the pointer on to the trace stopped (s).
    pub traced_s: f64,
}

/// The layer `key` of `job`, or a [`StopCause::Job`] naming it.
pub fn find_layer(job: &Job, key: LayerKey) -> Result<&Layer, StopCause> {
    let zone = job
        .zones
        .iter()
        .find(|z| z.id == key.zone)
        .ok_or_else(|| job_error(format!("no zone {} in the job", key.zone)))?;
    if let Some(why) = &zone.unreachable {
        return Err(job_error(format!(
            "zone {} is unreachable: {why}; framing does not move toward it",
            zone.id
        )));
    }
    zone.layers
        .iter()
        .find(|l| l.index == key.layer)
        .ok_or_else(|| {
            job_error(format!(
                "zone {} has no layer {} (layers {:?})",
                key.zone,
                key.layer,
                zone.layers.iter().map(|l| l.index).collect::<Vec<_>>()
            ))
        })
}

fn job_error(message: String) -> StopCause {
    StopCause::Job { message }
}

/// Frames layer `key` of `job`: the CNC to its pose, the pointer on, the outline traced
/// `passes` times (0: until `hold` resolves) or until `hold` resolves after the first whole
/// pass, then the trace stopped and the pointer off. Returns what was framed and `hold`'s
/// output if it ended the trace. The laser signals are left disabled ([`rearm`] enables them
/// for marking).
pub async fn frame_layer<T>(
    cell: &mut Cell,
    job: &Job,
    key: LayerKey,
    settings: &FrameSettings,
    passes: u32,
    hold: impl Future<Output = T>,
    cancel: &CancellationToken,
) -> Result<(Framed, Option<T>), FramingStop> {
    let refused = |cause| FramingStop {
        cause,
        laser_off_ok: true,
    };
    let layer = find_layer(job, key).map_err(refused)?;
    let outline =
        layer_outline(layer, &job.settings.plan.galvo, settings.outline).map_err(|e| {
            refused(job_error(format!(
                "zone {} layer {}: {e}",
                key.zone, key.layer
            )))
        })?;
    let commands = frame_list(&outline, &job.settings.plan.galvo);
    let pass_s = ListClock::list_s(&commands);
    // The trace's waits are bounded by this time (checked before the pointer goes on).
    if !(pass_s.is_finite() && pass_s >= 0.0) {
        return Err(refused(job_error(format!(
            "zone {} layer {}: the outline's modelled time is {pass_s} s (check the job's galvo speeds and delays)",
            key.zone, key.layer
        ))));
    }
    let result = trace(
        cell, layer, key, settings, &commands, passes, pass_s, hold, cancel,
    )
    .await;
    match result {
        Ok((passes_done, vectors_traced, traced_s, held)) => Ok((
            Framed {
                key,
                outline,
                passes_done,
                vectors_traced,
                pass_s,
                traced_s,
            },
            held,
        )),
        Err(cause) => {
            let laser_off_ok = lights_out(cell, &settings.timeouts).await;
            Err(FramingStop {
                cause,
                laser_off_ok,
            })
        }
    }
}

/// Why framing stopped, and whether the laser acknowledged its emission-off on the way down
/// ([`lights_out`]); a refusal before anything was switched on counts as acknowledged.
#[derive(Debug, Clone, PartialEq)]
pub struct FramingStop {
    /// What stopped it.
    pub cause: StopCause,
    /// The laser acknowledged its emission-off (or nothing was switched on).
    pub laser_off_ok: bool,
}

impl std::fmt::Display for FramingStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.cause)?;
        if !self.laser_off_ok {
            write!(
                f,
                "; laser emission-off NOT acknowledged: switch the laser off at its key"
            )?;
        }
        Ok(())
    }
}

/// In a run (`run --frame`'s zone gate) the executor takes its own way down after the cause.
impl From<FramingStop> for StopCause {
    fn from(stop: FramingStop) -> Self {
        stop.cause
    }
}

/// The device steps of [`frame_layer`], in order; the caller takes the way down on failure.
#[expect(clippy::too_many_arguments)] // one layer's framing: its inputs, each used once
async fn trace<T>(
    cell: &mut Cell,
    layer: &Layer,
    key: LayerKey,
    settings: &FrameSettings,
    commands: &[crate::galvo::protocol::ListCommand],
    passes: u32,
    pass_s: f64,
    hold: impl Future<Output = T>,
    cancel: &CancellationToken,
) -> Result<(u32, u32, f64, Option<T>), StopCause> {
    // The light path shut first (emission off, acknowledged; the galvo's signals disabled), as
    // a run prepares the cell.
    let steps = Preparation {
        laser_signals: false,
        check_laser: false,
        power_pct: None,
        enable: settings.prepare.then_some(settings.enable),
    };
    prepare_cell(cell, &settings.timeouts, cancel, steps).await?;
    move_to_pose(cell, layer, &settings.timeouts, cancel).await?;
    load_frame(cell, key, settings, commands, cancel).await?;
    let t_on = start_trace(cell, settings, passes, cancel).await?;
    let held = follow_trace(cell, key, settings, passes, pass_s, t_on, hold, cancel).await?;
    let traced_s = t_on.elapsed().as_secs_f64();
    let (passes_done, vectors_traced) = end_trace(cell, settings, cancel).await?;
    Ok((passes_done, vectors_traced, traced_s, held))
}

/// The CNC to the layer's pose, as the executor moves it, and in position.
async fn move_to_pose(
    cell: &mut Cell,
    layer: &Layer,
    t: &Timeouts,
    cancel: &CancellationToken,
) -> Result<(), StopCause> {
    let moving = cell.cnc.start_move(&layer.pose);
    Executor::guard(cancel, t.cnc_reply, Device::Cnc, "move", moving).await?;
    let waiting = cell.cnc.wait_in_position(t.cnc_motion);
    let wait_timeout = t.cnc_motion + Duration::from_secs(1);
    Executor::guard(
        cancel,
        wait_timeout,
        Device::Cnc,
        "wait in position",
        waiting,
    )
    .await?;
    Ok(())
}

/// The frame list loaded, and the galvo's light path checked shut.
async fn load_frame(
    cell: &mut Cell,
    key: LayerKey,
    settings: &FrameSettings,
    commands: &[crate::galvo::protocol::ListCommand],
    cancel: &CancellationToken,
) -> Result<(), StopCause> {
    let tag = frame_tag(key.zone, key.layer);
    let loading = cell.galvo.load_list(settings.list, tag, commands);
    let load_timeout = settings.timeouts.galvo_load(commands.len());
    Executor::guard(cancel, load_timeout, Device::Galvo, "LOAD_LIST", loading).await?;
    let s = galvo_status(&cell.galvo, settings, cancel).await?;
    if s.gate_open || s.laser_signals {
        return Err(galvo_fault(format!(
            "before framing: the galvo reports gate open {} and laser signals {}",
            s.gate_open, s.laser_signals
        )));
    }
    Ok(())
}

/// The pointer on and the frame list run (`EXECUTE_FRAME`); returns when the pointer went on.
async fn start_trace(
    cell: &mut Cell,
    settings: &FrameSettings,
    passes: u32,
    cancel: &CancellationToken,
) -> Result<Instant, StopCause> {
    let gt = settings.galvo_timeout();
    let pointer = cell.galvo.pointer(true);
    Executor::guard(cancel, gt, Device::Galvo, "POINTER on", pointer).await?;
    let t_on = Instant::now();
    let execute = cell.galvo.execute_frame(settings.list, passes);
    Executor::guard(cancel, gt, Device::Galvo, "EXECUTE_FRAME", execute).await?;
    Ok(t_on)
}

/// The trace: polls until the passes are done, or `hold` resolves after the first whole pass;
/// returns `hold`'s output if it ended the trace.
#[expect(clippy::too_many_arguments)] // the trace's inputs, each used once
async fn follow_trace<T>(
    cell: &mut Cell,
    key: LayerKey,
    settings: &FrameSettings,
    passes: u32,
    pass_s: f64,
    t_on: Instant,
    hold: impl Future<Output = T>,
    cancel: &CancellationToken,
) -> Result<Option<T>, StopCause> {
    let (t, gt) = (settings.timeouts, settings.galvo_timeout());
    let deadline = (passes > 0).then(|| {
        t_on + Duration::from_secs_f64(pass_s * f64::from(passes) * t.list_time_factor)
            + t.list_time_margin
    });
    let first_pass_deadline =
        t_on + Duration::from_secs_f64(pass_s * t.list_time_factor) + t.list_time_margin;
    let mut hold = std::pin::pin!(hold);
    loop {
        let s = galvo_status(&cell.galvo, settings, cancel).await?;
        if s.gate_open || s.marks_done > 0 {
            return Err(galvo_fault(format!(
                "while framing the galvo reports the gate open ({}) or {} vectors marked",
                s.gate_open, s.marks_done
            )));
        }
        let status = cell.galvo.frame_status();
        let f = Executor::guard(cancel, gt, Device::Galvo, "FRAME_STATUS", status).await?;
        let passes_seen = f.passes_done;
        if !f.framing {
            if passes > 0 && f.passes_done >= passes {
                return Ok(None);
            }
            return Err(galvo_fault(format!(
                "the galvo ended the frame: {:?}, error code {}, {} passes traced",
                s.state, s.last_error, f.passes_done
            )));
        }
        let now = Instant::now();
        if deadline.is_some_and(|d| now > d) || (passes_seen == 0 && now > first_pass_deadline) {
            return Err(StopCause::Link {
                device: Device::Galvo,
                message: format!(
                    "frame of zone {} layer {}: {passes_seen} passes traced in {:.3} s",
                    key.zone,
                    key.layer,
                    t_on.elapsed().as_secs_f64()
                ),
            });
        }
        let poll = tokio::time::sleep(Duration::from_millis(FRAME_POLL_MS));
        if passes_seen == 0 {
            tokio::select! {
                () = cancel.cancelled() => return Err(StopCause::Cancelled),
                () = poll => {}
            }
        } else {
            tokio::select! {
                () = cancel.cancelled() => return Err(StopCause::Cancelled),
                h = &mut hold => return Ok(Some(h)),
                () = poll => {}
            }
        }
    }
}

/// The trace stopped and the pointer off, checked; returns the passes and vectors traced.
async fn end_trace(
    cell: &mut Cell,
    settings: &FrameSettings,
    cancel: &CancellationToken,
) -> Result<(u32, u32), StopCause> {
    let gt = settings.galvo_timeout();
    Executor::guard(cancel, gt, Device::Galvo, "STOP", cell.galvo.stop()).await?;
    let pointer = cell.galvo.pointer(false);
    Executor::guard(cancel, gt, Device::Galvo, "POINTER off", pointer).await?;
    let status = cell.galvo.frame_status();
    let f = Executor::guard(cancel, gt, Device::Galvo, "FRAME_STATUS", status).await?;
    if f.pointer || f.framing {
        return Err(galvo_fault(format!(
            "after framing the galvo reports pointer {} and framing {}",
            f.pointer, f.framing
        )));
    }
    Ok((f.passes_done, f.vectors_traced))
}

async fn galvo_status(
    galvo: &GalvoClient,
    settings: &FrameSettings,
    cancel: &CancellationToken,
) -> Result<StatusBlock, StopCause> {
    Executor::guard(
        cancel,
        settings.galvo_timeout(),
        Device::Galvo,
        "STATUS",
        galvo.status(),
    )
    .await
}

fn galvo_fault(message: String) -> StopCause {
    StopCause::Fault {
        device: Device::Galvo,
        message,
    }
}

/// After framing, for marking: the pointer off and the galvo's laser signals enabled again.
pub async fn rearm(
    cell: &mut Cell,
    timeouts: &Timeouts,
    cancel: &CancellationToken,
) -> Result<(), StopCause> {
    let settings = FrameSettings {
        timeouts: *timeouts,
        ..FrameSettings::new(OutlineKind::Hull)
    };
    let gt = settings.galvo_timeout();
    Executor::guard(
        cancel,
        gt,
        Device::Galvo,
        "POINTER off",
        cell.galvo.pointer(false),
    )
    .await?;
    Executor::guard(
        cancel,
        gt,
        Device::Galvo,
        "LASER_SIGNALS on",
        cell.galvo.laser_signals(true),
    )
    .await
}

/// The way down after a framing failure, as the executor's: the laser's emission off first (on
/// the open port, then reopened, until acknowledged or `laser_off_budget` is spent: it must be
/// off even after a missed reply), then the galvo stopped (its pointer and signals drop), the
/// pointer off, motion stopped; each within the shutdown step, each tried whatever the others
/// did; a lost galvo link gets a new session first ([`GalvoClient::reopen_if_lost`]). Returns
/// whether the laser acknowledged its emission-off.
pub async fn lights_out(cell: &mut Cell, timeouts: &Timeouts) -> bool {
    let step = timeouts.shutdown_step;
    let deadline = tokio::time::Instant::now() + timeouts.laser_off_budget;
    let laser = cell.laser.emission_off_until(deadline).await;
    let stop = tokio::time::timeout(step, async {
        // A lost link gets a new session first (which itself drops the signals and the pointer).
        let _reopened = cell.galvo.reopen_if_lost().await?;
        cell.galvo.stop().await
    })
    .await;
    let pointer = tokio::time::timeout(step, cell.galvo.pointer(false)).await;
    let abort = tokio::time::timeout(step + timeouts.cnc_reply, cell.cnc.abort()).await;
    tracing::warn!(
        emission_off = laser.acknowledged,
        galvo_stop = matches!(stop, Ok(Ok(Ok(())))),
        pointer_off = matches!(pointer, Ok(Ok(Ok(())))),
        cnc_abort = matches!(abort, Ok(Ok(Ok(())))),
        "framing: way down"
    );
    laser.acknowledged
}
