//! `trimctl calibrate timing RUN_DIR... --out timing.toml`: the cycle-time model fitted from
//! recorded runs (DESIGN.md "Estimates learned from runs"), and the timing file it writes, which
//! `plan`, `run` and `report` take with `--timing`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use trim_calib::timing_fit::{
    ListSample, MOVE_PARAMETERS, MoveSample, fit_lists, fit_moves, median_s,
};
use trim_cell::galvo_timing::TimingSettings;
use trim_cell::kinematics::{AxisPose, MachineSettings, MoveModel};

use crate::timing_record::{self, TimingRecord};

/// Arguments of `trimctl calibrate timing`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Run folders of `trimctl run` on the cell to model (each holds `timing.json`), recorded
    /// in real time (real devices, or simulators at `--sim-time-scale 1`).
    #[arg(required = true, value_name = "RUN_DIR")]
    runs: Vec<PathBuf>,
    /// Where to write the fitted model: a `[machine]` and a `[timing]` table, the keys of
    /// job.toml (`--timing FILE` on plan, run and report).
    #[arg(long, value_name = "timing.toml")]
    out: PathBuf,
}

/// The move keys of job.toml's `[machine]` that a timing file sets.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MoveKeys {
    /// `machine.move_model`.
    pub move_model: MoveModel,
    /// `machine.linear_speed_mm_per_s`.
    pub linear_speed_mm_per_s: f64,
    /// `machine.rotary_speed_deg_per_s`.
    pub rotary_speed_deg_per_s: f64,
    /// `machine.linear_accel_mm_per_s2`.
    pub linear_accel_mm_per_s2: f64,
    /// `machine.rotary_accel_deg_per_s2`.
    pub rotary_accel_deg_per_s2: f64,
    /// `machine.settle_s`.
    pub settle_s: f64,
}

/// A timing file: the time model's keys of job.toml, `[machine]` (moves) and `[timing]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingFile {
    /// The move model.
    pub machine: MoveKeys,
    /// The terms beyond the commanded model.
    pub timing: TimingSettings,
}

impl TimingFile {
    /// Reads and checks a timing file, naming it in any error.
    pub fn load(path: &Path) -> anyhow::Result<TimingFile> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read timing file {}", path.display()))?;
        let file: TimingFile = toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("timing file {}: {}", path.display(), e.message()))?;
        let mut machine = MachineSettings::default();
        let mut timing = TimingSettings::default();
        file.apply(&mut machine, &mut timing);
        machine
            .validate()
            .and_then(|()| timing.validate())
            .map_err(|e| anyhow::anyhow!("timing file {}: {e}", path.display()))?;
        Ok(file)
    }

    /// Sets the file's keys on a job's settings.
    pub fn apply(&self, machine: &mut MachineSettings, timing: &mut TimingSettings) {
        let m = &self.machine;
        machine.move_model = m.move_model;
        machine.linear_speed_mm_per_s = m.linear_speed_mm_per_s;
        machine.rotary_speed_deg_per_s = m.rotary_speed_deg_per_s;
        machine.linear_accel_mm_per_s2 = m.linear_accel_mm_per_s2;
        machine.rotary_accel_deg_per_s2 = m.rotary_accel_deg_per_s2;
        machine.settle_s = m.settle_s;
        *timing = self.timing;
    }
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut records: Vec<(PathBuf, TimingRecord)> = Vec::new();
    for dir in &args.runs {
        let (path, record) = timing_record::read(dir)?;
        for (scale, device) in [
            (record.cnc_time_scale, "CNC"),
            (record.galvo_time_scale, "galvo"),
        ] {
            if (scale - 1.0).abs() > 1e-12 {
                bail!(
                    "{}: the {device} ran time-scaled ({scale} real s per s): its times are not the cell's; record with real devices or --sim-time-scale 1",
                    path.display()
                );
            }
        }
        records.push((path, record));
    }
    let start = records[0].1.machine;
    let mut moves = Vec::new();
    let mut lists = Vec::new();
    let mut overheads = Vec::new();
    for (_, r) in &records {
        let kind = r.machine.kinematics;
        for l in &r.layers {
            let from = l
                .from
                .as_ref()
                .and_then(|p| AxisPose::from_job_pose(p, kind));
            let to = AxisPose::from_job_pose(&l.to, kind);
            // A layer whose list took longer to load than the move measures the load.
            if let (Some(from), Some(to)) = (from, to)
                && l.load_s < l.motion_s
            {
                moves.push(MoveSample {
                    from,
                    to,
                    measured_s: l.motion_s,
                });
            }
            if l.first_vector == 0 {
                lists.push(ListSample {
                    galvo: r.galvo_settings,
                    list: l.list,
                    measured_s: l.list_s,
                });
            }
            overheads.push(l.overhead_s);
        }
    }
    let files = records
        .iter()
        .map(|(p, _)| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let move_fit =
        fit_moves(&start, &moves).with_context(|| format!("fitting moves of {files}"))?;
    let list_fit = fit_lists(&lists).with_context(|| format!("fitting lists of {files}"))?;
    // A per-layer overhead is time the cell adds: a negative median (clock noise) is held at
    // 0, as the list terms are (`fit_lists`), so the file is one `[timing]` accepts.
    let layer_median_s = median_s(&overheads);
    let timing = TimingSettings {
        layer_overhead_s: layer_median_s.max(0.0),
        ..list_fit.timing
    };
    let m = move_fit.machine;
    let file = TimingFile {
        machine: MoveKeys {
            move_model: MoveModel::Coordinated,
            linear_speed_mm_per_s: m.linear_speed_mm_per_s,
            rotary_speed_deg_per_s: m.rotary_speed_deg_per_s,
            linear_accel_mm_per_s2: m.linear_accel_mm_per_s2,
            rotary_accel_deg_per_s2: m.rotary_accel_deg_per_s2,
            settle_s: m.settle_s,
        },
        timing,
    };
    let values = [
        m.linear_speed_mm_per_s,
        m.rotary_speed_deg_per_s,
        m.linear_accel_mm_per_s2,
        m.rotary_accel_deg_per_s2,
        m.settle_s,
    ];
    let mut summary = String::new();
    let _ = writeln!(
        summary,
        "moves: {} fitted, RMS error {:.1} ms before (the runs' model) → {:.1} ms after ({} LM iterations)",
        move_fit.samples,
        move_fit.rms_before_s * 1e3,
        move_fit.rms_after_s * 1e3,
        move_fit.iterations
    );
    for (k, name) in MOVE_PARAMETERS.iter().enumerate() {
        let note = if move_fit.not_determined.contains(name) {
            " (not determined by these moves: kept)".to_owned()
        } else {
            format!(" ± {:.3}", move_fit.sigma[k])
        };
        let _ = writeln!(summary, "  {name} = {:.4}{note}", values[k]);
    }
    let _ = writeln!(
        summary,
        "lists: {} fitted, RMS error {:.2} ms before (commanded speeds and delays) → {:.2} ms after",
        list_fit.samples,
        list_fit.rms_before_s * 1e3,
        list_fit.rms_after_s * 1e3
    );
    let _ = writeln!(
        summary,
        "  list_overhead_s = {:.6}, polyline_overhead_s = {:.6}, vertex_overhead_s = {:.7}{}",
        timing.list_overhead_s,
        timing.polyline_overhead_s,
        timing.vertex_overhead_s,
        if list_fit.not_determined.is_empty() {
            String::new()
        } else {
            format!(
                " ({} not determined by these lists: 0)",
                list_fit.not_determined.join(", ")
            )
        }
    );
    for (name, fitted) in &list_fit.held_at_zero {
        let _ = writeln!(
            summary,
            "  {name} held at 0: it fitted {fitted:.7} s (the cell quicker than commanded on that \
             count; an overhead is never negative), the other terms re-fitted without it"
        );
    }
    let _ = writeln!(
        summary,
        "layer overhead: median {:.2} ms over {} layers{}",
        layer_median_s * 1e3,
        overheads.len(),
        if layer_median_s < 0.0 {
            " (negative: held at 0)"
        } else {
            ""
        }
    );
    let mut text = String::from(
        "# trimctl timing model, fitted by `trimctl calibrate timing` (DESIGN.md \"Estimates learned\n# from runs\"). The keys are job.toml's: pass the file with --timing to plan, run or report,\n# or copy the keys into job.toml's [machine] and [timing].\n",
    );
    let _ = writeln!(text, "# runs: {files}");
    for line in summary.lines() {
        let _ = writeln!(text, "# {line}");
    }
    text.push('\n');
    text.push_str(&toml::to_string(&file).context("writing the timing file")?);
    trim_geom::fs::write_atomic(&args.out, text)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    print!("{summary}");
    println!("wrote {}", args.out.display());
    Ok(())
}
