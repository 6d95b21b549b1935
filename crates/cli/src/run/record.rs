//! The run's MCAP record: opened (a resume records into its own file; with `--live` on the
//! live view's context, so viewers get every message too), the inputs and the registration,
//! the calibration, the run's progress, the twin's spot error, and closed.

use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use trim_cell::{Job, LayerKey};
use trim_geom::{Path as TrimPath, PointCloud};
use trim_io::executor::Progress;
use trim_io::live::LiveServer;
use trim_io::record::{ProgressMessage, Recorder, SharedRecorder, topic};
use trim_io::tap::now_ns;
use trim_register::regional::Registration;

use super::files;
use super::inputs::Inputs;
use super::report::SpotReport;
use crate::config::{JobConfig, ScanPoses};

/// `/progress` is written at most this often while a layer's vectors are counted up (every
/// layer start, phase and end is written).
const PROGRESS_INTERVAL: Duration = Duration::from_millis(50);

pub(super) fn open_recorder(
    run_dir: &Path,
    resuming: bool,
    live: Option<&LiveServer>,
) -> anyhow::Result<Option<SharedRecorder>> {
    // A resumed run records into its own file so the first record stays as it was.
    let name = if resuming {
        let mut n = 1;
        while run_dir.join(format!("run.resume-{n}.mcap")).exists() {
            n += 1;
        }
        format!("run.resume-{n}.mcap")
    } else {
        files::RECORD.to_string()
    };
    let path = run_dir.join(&name);
    let recorder = match live {
        Some(server) => Recorder::create_live(&path, server),
        None => Recorder::create(&path),
    }
    .with_context(|| format!("cannot create {}", path.display()))?;
    Ok(Some(recorder.shared()))
}

pub(super) fn record_inputs(
    rec: &SharedRecorder,
    inputs: &Inputs,
    registration: &Registration,
    job: &Job,
) -> anyhow::Result<()> {
    let mut r = rec
        .lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?;
    let to_rows = |c: &PointCloud| {
        c.points()
            .iter()
            .map(|p| [p.x, p.y, p.z])
            .collect::<Vec<_>>()
    };
    let t_ns = now_ns();
    r.point_cloud(topic::SCAN, t_ns, &to_rows(&inputs.scan))?;
    let cad_in_scan = inputs.cad.transformed(&registration.scan_from_cad)?;
    r.point_cloud(topic::CAD, t_ns, &to_rows(&cad_in_scan))?;
    let paths = |p: &TrimPath| {
        p.contours()
            .iter()
            .map(|c| (c.id(), c.points().iter().map(|q| [q.x, q.y, q.z]).collect()))
            .collect::<Vec<_>>()
    };
    let template_in_scan = inputs.path.transformed(&registration.scan_from_cad)?;
    r.paths(
        topic::TEMPLATE,
        t_ns,
        &paths(&template_in_scan),
        [0.6, 0.6, 0.6, 1.0],
    )?;
    r.paths(
        topic::REGISTERED,
        t_ns,
        &paths(&registration.path),
        [1.0, 0.3, 0.1, 1.0],
    )?;
    r.zone_frames(t_ns, job)?;
    Ok(())
}

/// The calibration, the lens and the scan pose the run used (`/calibration`); with
/// `[part] scans`, each scan's file and machine pose too (`scan_poses`: the inputs', so a
/// resumed run's record, which records no inputs, has none).
pub(super) fn record_calibration(
    rec: &SharedRecorder,
    config: &JobConfig,
    job: &Job,
    scan_poses: &ScanPoses,
) -> anyhow::Result<()> {
    let scan_poses: Vec<serde_json::Value> = scan_poses
        .iter()
        .map(|(file, pose)| serde_json::json!({"scan": file, "pose": pose}))
        .collect();
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .json(
            topic::CALIBRATION,
            topic::CALIBRATION_SCHEMA,
            now_ns(),
            &serde_json::json!({
                "calibration": config.plan.calibration,
                "lens": job.settings.lens,
                "scan_pose": config.part.scan_pose,
                "scan_poses": scan_poses,
            }),
        )?;
    Ok(())
}

/// The twin's spot errors (`/twin/spot_error`).
pub(super) fn record_spot_error(rec: &SharedRecorder, report: &SpotReport) -> anyhow::Result<()> {
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .json(
            topic::SPOT_ERROR,
            topic::SPOT_ERROR_SCHEMA,
            now_ns(),
            &serde_json::to_value(report)?,
        )?;
    Ok(())
}

/// Turns the executor's progress events into `/progress` messages.
pub(super) struct ProgressRecord {
    rec: SharedRecorder,
    vectors_of: HashMap<LayerKey, u64>,
    msg: ProgressMessage,
    /// Vectors of the layers finished (or skipped) so far.
    vectors_finished: u64,
    last_written: Option<Instant>,
}

impl ProgressRecord {
    pub(super) fn new(rec: SharedRecorder, job: &Job) -> ProgressRecord {
        let vectors_of: HashMap<LayerKey, u64> = job
            .layers()
            .map(|(key, _, l)| (key, u64::from(trim_io::galvo::list::vector_count(l))))
            .collect();
        let msg = ProgressMessage {
            layers_total: vectors_of.len() as u64,
            vectors_total: vectors_of.values().sum(),
            ..ProgressMessage::default()
        };
        ProgressRecord {
            rec,
            vectors_of,
            msg,
            vectors_finished: 0,
            last_written: None,
        }
    }

    /// Follows one event; writes `/progress` unless it is a vector count within
    /// [`PROGRESS_INTERVAL`] of the last one written.
    pub(super) fn on(&mut self, event: &Progress) {
        let vectors = |key| self.vectors_of.get(&key).copied().unwrap_or(0);
        let mut always = true;
        match *event {
            Progress::Started {
                layers, vectors, ..
            } => {
                self.msg.layers_total = layers as u64;
                self.msg.vectors_total = vectors;
            }
            Progress::Phase { key, phase, .. } => {
                self.msg.zone = Some(key.zone);
                self.msg.layer = Some(key.layer);
                self.msg.phase = Some(format!("{phase:?}"));
            }
            Progress::Vectors { key, done, .. } => {
                self.msg.zone = Some(key.zone);
                self.msg.layer = Some(key.layer);
                self.msg.vectors_done = self.vectors_finished + u64::from(done);
                always = false;
            }
            Progress::LayerDone { key, .. } | Progress::LayerSkipped { key } => {
                self.msg.layers_done += 1;
                self.vectors_finished += vectors(key);
                self.msg.vectors_done = self.vectors_finished;
                self.msg.zone = None;
                self.msg.layer = None;
                self.msg.phase = None;
            }
        }
        self.msg.fraction = if self.msg.vectors_total == 0 {
            0.0
        } else {
            self.msg.vectors_done as f64 / self.msg.vectors_total as f64
        };
        if !always
            && self
                .last_written
                .is_some_and(|t| t.elapsed() < PROGRESS_INTERVAL)
        {
            return;
        }
        self.last_written = Some(Instant::now());
        let mut r = self
            .rec
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Err(e) = r.progress(now_ns(), &self.msg) {
            tracing::debug!(error = %e, "record: progress message lost");
        }
    }
}

pub(super) fn finish_recorder(rec: SharedRecorder) -> anyhow::Result<()> {
    // Closing writes the summary and index; a device tap that still holds the recorder gets
    // its late messages refused rather than written after the end.
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .finish()
        .context("closing the run record")
}
