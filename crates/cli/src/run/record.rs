//! The run's MCAP record: opened (a resume records into its own file), the inputs and the
//! registration, the calibration, the twin's spot error, and closed.

use std::path::Path;

use anyhow::Context;
use trim_geom::{Path as TrimPath, PointCloud};
use trim_io::record::{Recorder, SharedRecorder};
use trim_plan::Job;
use trim_register::regional::Registration;

use super::files;
use super::inputs::Inputs;
use super::report::SpotReport;
use crate::config::JobConfig;

pub(super) fn open_recorder(
    run_dir: &Path,
    resuming: bool,
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
    let recorder = Recorder::create(&run_dir.join(&name))
        .with_context(|| format!("cannot create {}", run_dir.join(&name).display()))?;
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
    r.point_cloud("/scan", 0, &to_rows(&inputs.scan))?;
    let cad_in_scan = inputs.cad.transformed(&registration.scan_from_cad);
    r.point_cloud("/cad", 0, &to_rows(&cad_in_scan))?;
    let paths = |p: &TrimPath| {
        p.contours()
            .iter()
            .map(|c| (c.id(), c.points().iter().map(|q| [q.x, q.y, q.z]).collect()))
            .collect::<Vec<_>>()
    };
    let template_in_scan = inputs.path.transformed(&registration.scan_from_cad);
    r.paths(
        "/path/template",
        0,
        &paths(&template_in_scan),
        [0.6, 0.6, 0.6, 1.0],
    )?;
    r.paths(
        "/path/registered",
        0,
        &paths(&registration.path),
        [1.0, 0.3, 0.1, 1.0],
    )?;
    r.zone_frames(0, job)?;
    Ok(())
}

/// The calibration, the lens and the scan pose the run used (`/calibration`).
pub(super) fn record_calibration(
    rec: &SharedRecorder,
    config: &JobConfig,
    job: &Job,
) -> anyhow::Result<()> {
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .json(
            "/calibration",
            "trimctl.Calibration",
            0,
            &serde_json::json!({
                "calibration": config.calibration,
                "lens": job.settings.lens,
                "scan_pose": config.part.scan_pose,
            }),
        )?;
    Ok(())
}

/// The twin's spot errors (`/twin/spot_error`).
pub(super) fn record_spot_error(rec: &SharedRecorder, report: &SpotReport) -> anyhow::Result<()> {
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .json(
            "/twin/spot_error",
            "trimctl.SpotError",
            0,
            &serde_json::to_value(report)?,
        )?;
    Ok(())
}

pub(super) fn finish_recorder(rec: SharedRecorder) -> anyhow::Result<()> {
    // Closing writes the summary and index; a device tap that still holds the recorder gets
    // its late messages refused rather than written after the end.
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .finish()
        .context("closing the run record")
}
