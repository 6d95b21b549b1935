//! `trimctl report RUN_DIR`: the time estimate against the actual time of a recorded run, per
//! layer, per move and per list, from the run's `timing.json`; with `--timing FILE`, the
//! estimate of a fitted model on the same moves and lists.

use std::fmt::Write as _;
use std::path::PathBuf;

use trim_cell::galvo_timing::list_time_s;
use trim_cell::kinematics::{AxisPose, move_time_s};

use crate::calibrate_timing::TimingFile;
use crate::timing_record::{self, TimingRecord};

/// Arguments of `trimctl report`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A run folder of `trimctl run` (it holds `timing.json`).
    #[arg(value_name = "RUN_DIR")]
    run_dir: PathBuf,
    /// Estimate with this timing file (`trimctl calibrate timing`) instead of the model the run
    /// was planned with.
    #[arg(long, value_name = "timing.toml")]
    timing: Option<PathBuf>,
    /// How many of the worst layers to list.
    #[arg(long, default_value_t = 5)]
    worst: usize,
}

/// One layer: estimate and actual (s, the cell's time).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Zone id.
    pub zone: usize,
    /// Layer index.
    pub layer: usize,
    /// Move + settle: estimate, actual.
    pub move_s: (f64, f64),
    /// Galvo list: estimate, actual.
    pub list_s: (f64, f64),
    /// The rest of the layer: estimate, actual.
    pub other_s: (f64, f64),
}

impl Row {
    /// The layer's total: estimate, actual.
    #[must_use]
    pub fn total_s(&self) -> (f64, f64) {
        (
            self.move_s.0 + self.list_s.0 + self.other_s.0,
            self.move_s.1 + self.list_s.1 + self.other_s.1,
        )
    }
}

/// The comparison of a record with a model: the record's own, or a timing file's.
#[must_use]
pub fn compare(record: &TimingRecord, model: Option<&TimingFile>) -> Vec<Row> {
    let mut machine = record.machine;
    let mut timing = record.timing;
    if let Some(f) = model {
        f.apply(&mut machine, &mut timing);
    }
    let kind = machine.kinematics;
    record
        .layers
        .iter()
        .map(|l| {
            let (move_est, list_est, other_est) = if model.is_some() {
                let from = l
                    .from
                    .as_ref()
                    .and_then(|p| AxisPose::from_job_pose(p, kind))
                    .unwrap_or(AxisPose::HOME);
                let move_est = AxisPose::from_job_pose(&l.to, kind)
                    .map_or(f64::NAN, |to| move_time_s(&machine, &from, &to));
                (
                    move_est,
                    list_time_s(&record.galvo_settings, &timing, &l.list),
                    timing.layer_overhead_s,
                )
            } else {
                (l.move_estimate_s, l.list_estimate_s, l.overhead_estimate_s)
            };
            Row {
                zone: l.zone,
                layer: l.layer,
                move_s: (move_est, l.motion_s / record.cnc_time_scale),
                list_s: (list_est, l.list_s / record.galvo_time_scale),
                other_s: (other_est, l.overhead_s),
            }
        })
        .collect()
}

/// The relative error of an estimate (%), `(estimate − actual) / actual`.
#[must_use]
pub fn error_pct(estimate: f64, actual: f64) -> f64 {
    if actual.abs() > 0.0 {
        (estimate - actual) / actual * 1e2
    } else {
        f64::NAN
    }
}

/// Summary figures of a comparison.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Totals {
    /// Total estimate and actual (s).
    pub total_s: (f64, f64),
    /// Moves: summed estimate and actual (s).
    pub moves_s: (f64, f64),
    /// Lists: summed estimate and actual (s).
    pub lists_s: (f64, f64),
    /// Mean and largest |estimate − actual| of a move (s).
    pub move_abs_error_s: (f64, f64),
    /// Mean and largest |estimate − actual| of a list (s).
    pub list_abs_error_s: (f64, f64),
}

/// The totals of `rows`.
#[must_use]
pub fn totals(rows: &[Row]) -> Totals {
    let sum = |f: &dyn Fn(&Row) -> (f64, f64)| {
        rows.iter()
            .map(f)
            .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    };
    let abs = |f: &dyn Fn(&Row) -> (f64, f64)| {
        let e: Vec<f64> = rows
            .iter()
            .map(|r| {
                let (a, b) = f(r);
                (a - b).abs()
            })
            .collect();
        let n = e.len().max(1) as f64;
        (
            e.iter().sum::<f64>() / n,
            e.iter().copied().fold(0.0, f64::max),
        )
    };
    Totals {
        total_s: sum(&Row::total_s),
        moves_s: sum(&|r| r.move_s),
        lists_s: sum(&|r| r.list_s),
        move_abs_error_s: abs(&|r| r.move_s),
        list_abs_error_s: abs(&|r| r.list_s),
    }
}

/// The report text.
#[must_use]
pub fn render(record: &TimingRecord, rows: &[Row], model: &str, worst: usize) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{} layers; CNC {}, galvo {}; estimate: {model}",
        rows.len(),
        record.cnc,
        record.galvo
    );
    if record.cnc_time_scale != 1.0 || record.galvo_time_scale != 1.0 {
        let _ = writeln!(
            s,
            "time-scaled simulators: measured moves divided by {}, lists by {} (the overhead is host time, kept)",
            record.cnc_time_scale, record.galvo_time_scale
        );
    }
    let _ = writeln!(
        s,
        "\n| zone | layer | move est s | move act s | list est s | list act s | other est s | other act s | total est s | total act s | error % |\n|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in rows {
        let (te, ta) = r.total_s();
        let _ = writeln!(
            s,
            "| {} | {} | {:.3} | {:.3} | {:.4} | {:.4} | {:.4} | {:.4} | {:.3} | {:.3} | {:+.1} |",
            r.zone,
            r.layer,
            r.move_s.0,
            r.move_s.1,
            r.list_s.0,
            r.list_s.1,
            r.other_s.0,
            r.other_s.1,
            te,
            ta,
            error_pct(te, ta)
        );
    }
    let t = totals(rows);
    let _ = writeln!(
        s,
        "\ntotal: estimate {:.2} s, actual {:.2} s, error {:+.2} %",
        t.total_s.0,
        t.total_s.1,
        error_pct(t.total_s.0, t.total_s.1)
    );
    let _ = writeln!(
        s,
        "moves: estimate {:.2} s, actual {:.2} s, error {:+.2} %; per move |error| mean {:.1} ms, max {:.1} ms",
        t.moves_s.0,
        t.moves_s.1,
        error_pct(t.moves_s.0, t.moves_s.1),
        t.move_abs_error_s.0 * 1e3,
        t.move_abs_error_s.1 * 1e3
    );
    let _ = writeln!(
        s,
        "lists: estimate {:.3} s, actual {:.3} s, error {:+.2} %; per list |error| mean {:.2} ms, max {:.2} ms",
        t.lists_s.0,
        t.lists_s.1,
        error_pct(t.lists_s.0, t.lists_s.1),
        t.list_abs_error_s.0 * 1e3,
        t.list_abs_error_s.1 * 1e3
    );
    let mut order: Vec<&Row> = rows.iter().collect();
    order.sort_by(|a, b| {
        let e = |r: &Row| {
            let (x, y) = r.total_s();
            (x - y).abs()
        };
        e(b).total_cmp(&e(a))
    });
    let _ = writeln!(s, "worst layers (|estimate − actual|):");
    for r in order.iter().take(worst) {
        let (te, ta) = r.total_s();
        let part = if (r.move_s.0 - r.move_s.1).abs() >= (r.list_s.0 - r.list_s.1).abs() {
            "move"
        } else {
            "list"
        };
        let _ = writeln!(
            s,
            "  zone {} layer {}: {:+.1} ms ({:+.1} %), mostly the {part}",
            r.zone,
            r.layer,
            (te - ta) * 1e3,
            error_pct(te, ta)
        );
    }
    s
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let (path, record) = timing_record::read(&args.run_dir)?;
    let model = args.timing.as_deref().map(TimingFile::load).transpose()?;
    let rows = compare(&record, model.as_ref());
    let name = match &args.timing {
        Some(p) => format!("{} (refitted)", p.display()),
        None => "as planned (the run's own settings)".to_owned(),
    };
    println!("{}", path.display());
    print!("{}", render(&record, &rows, &name, args.worst));
    Ok(())
}
