//! A run's timing record, `timing.json` in the run folder: per layer the planned move (from/to
//! axis values), the estimated and measured move, list and overhead times, and what the galvo
//! list held. `trimctl report` compares estimate and actual from it; `trimctl calibrate timing`
//! fits the time model to it. A resumed run writes `timing.resume-N.json` beside it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use trim_cell::galvo_timing::{ListComposition, TimingSettings, list_time_s};
use trim_cell::job::Pose;
use trim_cell::kinematics::{AxisPose, MachineSettings, move_time_s};
use trim_cell::{GalvoSettings, Job};
use trim_io::executor::RunSummary;

/// The record's file name in a run folder.
pub const FILE: &str = "timing.json";
/// The record format version this code writes and reads.
pub const VERSION: u32 = 1;

/// A run's timing record.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TimingRecord {
    /// [`VERSION`].
    pub version: u32,
    /// The CNC: an address, or "sim".
    pub cnc: String,
    /// Real seconds per machine second of the CNC (1 for a real control; `--sim-time-scale`
    /// for the simulator).
    pub cnc_time_scale: f64,
    /// The galvo: an address, or "sim".
    pub galvo: String,
    /// Real seconds per machine second of the galvo.
    pub galvo_time_scale: f64,
    /// The machine settings the estimate was made with.
    pub machine: MachineSettings,
    /// The galvo settings the lists were sent with.
    pub galvo_settings: GalvoSettings,
    /// The `[timing]` terms the estimate was made with.
    pub timing: TimingSettings,
    /// The CNC's position before the first layer (world axes), when it could be read.
    pub start_pose: Option<Pose>,
    /// Per layer marked, in order.
    pub layers: Vec<LayerRecord>,
}

/// One layer's estimate and measurement (s, machine time as measured: divide by the time
/// scales for a time-scaled simulator).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LayerRecord {
    /// The zone id.
    pub zone: usize,
    /// The layer index.
    pub layer: usize,
    /// Where the machine was before the move (the previous layer's pose, or the start pose);
    /// `None` when unknown.
    pub from: Option<Pose>,
    /// The layer's pose.
    pub to: Pose,
    /// The list this run sent began at this vector (0 unless a cut layer was continued).
    pub first_vector: u32,
    /// What the layer's galvo list held (the whole layer).
    pub list: ListComposition,
    /// Estimated move + settle (from the start pose, or home when it is unknown).
    pub move_estimate_s: f64,
    /// Estimated list time.
    pub list_estimate_s: f64,
    /// Estimated per-layer overhead (`timing.layer_overhead_s`).
    pub overhead_estimate_s: f64,
    /// Measured: move command to in position (the list loads meanwhile).
    pub motion_s: f64,
    /// Measured: `LOAD_LIST` (overlapped with the move).
    pub load_s: f64,
    /// Measured: `EXECUTE` to done seen.
    pub list_s: f64,
    /// The galvo's own model of the list as sent.
    pub list_modelled_s: f64,
    /// Measured: the rest of the layer (emission on/off, journal).
    pub overhead_s: f64,
    /// Measured: the whole layer.
    pub total_s: f64,
}

/// How the run's devices kept time.
#[derive(Debug, Clone)]
pub struct Clocks {
    /// The CNC's address or "sim".
    pub cnc: String,
    /// Its real seconds per machine second.
    pub cnc_time_scale: f64,
    /// The galvo's address or "sim".
    pub galvo: String,
    /// Its real seconds per machine second.
    pub galvo_time_scale: f64,
}

/// The record of `run` (a run of `job` planned with `machine` and `timing`), the machine at
/// `start_pose` before it.
#[must_use]
pub fn record(
    job: &Job,
    machine: &MachineSettings,
    timing: &TimingSettings,
    run: &RunSummary,
    start_pose: Option<Pose>,
    clocks: &Clocks,
) -> TimingRecord {
    let kind = machine.kinematics;
    let layers: std::collections::HashMap<_, _> =
        job.layers().map(|(key, _, layer)| (key, layer)).collect();
    let mut from = start_pose.clone();
    let mut rows = Vec::with_capacity(run.layers.len());
    for t in &run.layers {
        let Some(layer) = layers.get(&t.key) else {
            continue;
        };
        let list = ListComposition::of(&layer.polylines);
        let start = from
            .as_ref()
            .and_then(|p| AxisPose::from_job_pose(p, kind))
            .unwrap_or(AxisPose::HOME);
        let move_estimate_s = AxisPose::from_job_pose(&layer.pose, kind)
            .map_or(f64::NAN, |to| move_time_s(machine, &start, &to));
        rows.push(LayerRecord {
            zone: t.key.zone,
            layer: t.key.layer,
            from: from.take(),
            to: layer.pose.clone(),
            first_vector: 0,
            list,
            move_estimate_s,
            list_estimate_s: list_time_s(&job.settings.plan.galvo, timing, &list),
            overhead_estimate_s: timing.layer_overhead_s,
            motion_s: t.motion_s,
            load_s: t.load_s,
            list_s: t.list_s,
            list_modelled_s: t.modelled_s,
            overhead_s: t.overhead_s,
            total_s: t.total_s,
        });
        from = Some(layer.pose.clone());
    }
    if let Some((key, first)) = run.resumed_from {
        for r in &mut rows {
            if r.zone == key.zone && r.layer == key.layer {
                r.first_vector = first;
            }
        }
    }
    TimingRecord {
        version: VERSION,
        cnc: clocks.cnc.clone(),
        cnc_time_scale: clocks.cnc_time_scale,
        galvo: clocks.galvo.clone(),
        galvo_time_scale: clocks.galvo_time_scale,
        machine: *machine,
        galvo_settings: job.settings.plan.galvo,
        timing: *timing,
        start_pose,
        layers: rows,
    }
}

/// Writes the record into `run_dir`: `timing.json`, or for a resume the first free
/// `timing.resume-N.json`. Returns the file written.
pub fn write(run_dir: &Path, record: &TimingRecord, resuming: bool) -> anyhow::Result<PathBuf> {
    let path = if resuming {
        let mut n = 1;
        while run_dir.join(format!("timing.resume-{n}.json")).exists() {
            n += 1;
        }
        run_dir.join(format!("timing.resume-{n}.json"))
    } else {
        run_dir.join(FILE)
    };
    trim_geom::fs::write_atomic(&path, serde_json::to_string_pretty(record)? + "\n")
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// Reads the record of the run folder `run_dir` (its `timing.json`), or a record file given
/// directly.
pub fn read(run_dir: &Path) -> anyhow::Result<(PathBuf, TimingRecord)> {
    let path = if run_dir.is_dir() {
        run_dir.join(FILE)
    } else {
        run_dir.to_path_buf()
    };
    if !path.exists() {
        let why = if run_dir.join("summary.json").exists() {
            "the run folder has no per-layer timing record: the run was recorded before trimctl kept one, or it did not finish executing (a dry run, or a run that stopped)"
        } else {
            "not found (is this a run folder of `trimctl run`?)"
        };
        anyhow::bail!("{}: {why}", path.display());
    }
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let version = value.get("version").and_then(serde_json::Value::as_u64);
    if version != Some(u64::from(VERSION)) {
        anyhow::bail!(
            "{}: timing record version {version:?}, this trimctl reads version {VERSION}",
            path.display()
        );
    }
    let record: TimingRecord = serde_path_to_error::deserialize(value)
        .map_err(|e| anyhow::anyhow!("{}: {}: {}", path.display(), e.path(), e.inner()))?;
    for (scale, what) in [
        (record.cnc_time_scale, "cnc_time_scale"),
        (record.galvo_time_scale, "galvo_time_scale"),
    ] {
        if !(scale.is_finite() && scale > 0.0) {
            anyhow::bail!("{}: {what} must be > 0, got {scale}", path.display());
        }
    }
    Ok((path, record))
}
