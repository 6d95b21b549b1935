//! The run's report: `report.md` and `summary.json` (stage timings, the run summary, the spot
//! error of the digital twin), and what a resume appends to them.

use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use trim_cell::Job;
use trim_io::executor::{ExecError, RunSummary, ShutdownReport, ShutdownStep};
#[cfg(feature = "sim")]
use trim_io::journal::Entry;
use trim_plan::planner::PlanOutput;
use trim_register::regional::Registration;
#[cfg(feature = "sim")]
use trim_sim::twin::{Spot, SpotStats};

use super::detect::Detection;
use super::{Timings, files};
use crate::config::JobConfig;
use crate::summary;

/// The twin's spot errors of a run: overall and per zone (µm), over the spots of contours on
/// the true trimming line (hatch tracks have no line to be measured against).
#[cfg(feature = "sim")]
#[derive(Debug, Clone, Serialize)]
pub struct SpotReport {
    /// Over every landed spot of a trimming-line contour.
    pub overall: SpotStats,
    /// Per zone id, in job order.
    pub per_zone: Vec<(usize, SpotStats)>,
    /// Spots left out: on contours the true line does not hold (hatch tracks).
    pub excluded_spots: usize,
}

#[cfg(feature = "sim")]
impl SpotReport {
    /// Finds each spot's layer through the journal's list tags and its contour through the
    /// layer's vectors (each polyline of n points is n − 1 vectors per pass; a resumed list
    /// starts at the journaled `first_vector`), then keeps the spots of `line_ids`' contours.
    pub(crate) fn new(
        spots: &[Spot],
        journal: &Path,
        job: &Job,
        line_ids: &std::collections::HashSet<i64>,
    ) -> SpotReport {
        let layers: std::collections::HashMap<_, _> =
            job.layers().map(|(key, _, layer)| (key, layer)).collect();
        let mut list_of_tag = std::collections::HashMap::new();
        if let Ok(text) = std::fs::read_to_string(journal) {
            for line in text.lines() {
                if let Ok(Entry::LayerBegin {
                    key,
                    tag,
                    first_vector,
                    ..
                }) = serde_json::from_str(line)
                {
                    list_of_tag.insert(tag, (key, first_vector));
                }
            }
        }
        let contour_of = |s: &Spot| -> Option<(usize, i64)> {
            let (key, first) = list_of_tag.get(&s.tag)?;
            let layer = layers.get(key)?;
            let v = u64::from(*first) + u64::from(s.vector);
            let i = trim_io::galvo::list::polyline_of_vector(layer, v)?;
            Some((key.zone, layer.polylines[i].contour))
        };
        let mut per: std::collections::BTreeMap<usize, Vec<f64>> = Default::default();
        let mut all = Vec::with_capacity(spots.len());
        let mut excluded_spots = 0;
        for s in spots {
            match contour_of(s) {
                Some((zone, contour)) if line_ids.contains(&contour) => {
                    per.entry(zone).or_default().push(s.error_mm);
                    all.push(s.error_mm);
                }
                _ => excluded_spots += 1,
            }
        }
        SpotReport {
            overall: SpotStats::of_mm(&all),
            per_zone: per
                .into_iter()
                .map(|(z, e)| (z, SpotStats::of_mm(&e)))
                .collect(),
            excluded_spots,
        }
    }

    pub(super) fn line(&self) -> String {
        format!(
            "spot error on the true part (digital twin, registration included): P95 {:.1} µm, max {:.1} µm, mean {:.1} µm over {} spots{}\n",
            self.overall.p95_um,
            self.overall.max_um,
            self.overall.mean_um,
            self.overall.spots,
            self.excluded_note()
        )
    }

    fn excluded_note(&self) -> String {
        if self.excluded_spots == 0 {
            String::new()
        } else {
            format!(
                " (the {} spots of hatch tracks, which have no line, left out)",
                self.excluded_spots
            )
        }
    }

    fn markdown(&self) -> String {
        let mut out = String::from(
            "\n## Spot error (digital twin)\n\nDistance from each landed spot to the true trimming line, on the true cell of `[sim.truth]`; registration error included.\n\n",
        );
        out.push_str(&format!(
            "Overall: P95 {:.1} µm, max {:.1} µm, mean {:.1} µm ({} spots{}).\n\n| zone | spots | P95 µm | max µm |\n|---|---|---|---|\n",
            self.overall.p95_um,
            self.overall.max_um,
            self.overall.mean_um,
            self.overall.spots,
            self.excluded_note()
        ));
        for (z, s) in &self.per_zone {
            out.push_str(&format!(
                "| {z} | {} | {:.1} | {:.1} |\n",
                s.spots, s.p95_um, s.max_um
            ));
        }
        out
    }
}

/// No spot error without the digital twin: a build without the simulators has none.
#[cfg(not(feature = "sim"))]
#[derive(Debug, Clone, Serialize)]
pub enum SpotReport {}

#[cfg(not(feature = "sim"))]
impl SpotReport {
    pub(super) fn line(&self) -> String {
        match *self {}
    }

    fn markdown(&self) -> String {
        match *self {}
    }
}

/// What a fresh run adds to its report beyond the stages: what detection called each contour
/// (`[trim] only_detected`) and an injected fault (`--sim-block-beam`).
#[derive(Debug, Default)]
pub(super) struct RunNotes<'a> {
    /// The first scan's calls.
    pub(super) detection: Option<&'a Detection>,
    /// The twin's beam blocked during one layer.
    pub(super) beam_block: Option<BeamBlock>,
}

/// `--sim-block-beam`: the layer whose beam the twin blocked.
#[derive(Debug, Clone, Serialize)]
pub(super) struct BeamBlock {
    /// The layer.
    pub(super) layer: trim_cell::LayerKey,
    /// Its place in the job's execution order (1 = the first layer).
    pub(super) nth_list: u32,
    /// The contours of its polylines.
    pub(super) contours: Vec<i64>,
    /// Mark vectors that landed nothing (every pass counted).
    pub(super) marks_blocked: u64,
}

impl BeamBlock {
    /// One line for stdout and report.md.
    pub(super) fn line(&self) -> String {
        format!(
            "FAULT INJECTED (simulation, --sim-block-beam): the twin's beam was blocked while {} marked ({} mark vectors landed nothing on the part; contours {:?}); the journal records the layer as marked",
            self.layer, self.marks_blocked, self.contours
        )
    }
}

impl RunNotes<'_> {
    fn markdown(&self) -> String {
        let mut md = String::new();
        if let Some(b) = &self.beam_block {
            md.push_str(&format!("\n## Injected fault\n\n{}.\n", b.line()));
        }
        if let Some(d) = self.detection {
            md.push_str(&d.markdown());
        }
        md
    }

    fn json(&self) -> (serde_json::Value, serde_json::Value) {
        (
            serde_json::to_value(self.detection).unwrap_or_default(),
            serde_json::to_value(&self.beam_block).unwrap_or_default(),
        )
    }
}

/// report.md and summary.json of a run with nothing to trim (nothing planned, nothing moved).
pub(super) fn write_nothing_to_trim(
    run_dir: &Path,
    description: &str,
    why: &str,
    timings: &Timings,
    notes: &RunNotes<'_>,
) -> anyhow::Result<()> {
    let mut report = format!(
        "# trimctl run\n\nPart: {description}\n\n**Nothing to trim**: {why}. Nothing was planned and the machine was not moved.\n"
    );
    report.push_str(&notes.markdown());
    trim_geom::fs::write_atomic(run_dir.join(files::REPORT), report)?;
    let (detection, _) = notes.json();
    let json = serde_json::json!({
        "timings_s": timings,
        "nothing_to_trim": why,
        "detection": detection,
    });
    trim_geom::fs::write_atomic(
        run_dir.join(files::SUMMARY),
        serde_json::to_string_pretty(&json)?,
    )?;
    Ok(())
}

/// What the operator must do when a step of the way down was not acknowledged.
fn operator_action(step: ShutdownStep) -> &'static str {
    match step {
        ShutdownStep::EmissionOff => "switch the laser off at its key",
        ShutdownStep::GalvoSignalsOff => {
            "the galvo's laser signals may be on: switch the laser off at its key"
        }
        ShutdownStep::GalvoStop => "the galvo list may still run: stop the scan head controller",
        ShutdownStep::CncAbort => "the machine may still move: press its E-stop",
    }
}

/// One line per step of the way down, in order: acknowledged (and when) or NOT, with what
/// went wrong and what the operator must do.
pub(super) fn shutdown_lines(r: &ShutdownReport) -> Vec<String> {
    let failure = |step: ShutdownStep| r.failures.iter().find(|f| f.step == step);
    let attempts = r.emission_off.len();
    let mut out = Vec::new();
    for (step, ok) in [
        (ShutdownStep::EmissionOff, r.laser_off_ok),
        (ShutdownStep::GalvoSignalsOff, r.galvo_signals_off_ok),
        (ShutdownStep::GalvoStop, r.galvo_stop_ok),
        (ShutdownStep::CncAbort, r.cnc_abort_ok),
    ] {
        let line = match (ok, failure(step)) {
            (true, _) if step == ShutdownStep::EmissionOff => {
                let after_ms = r.emission_off.last().map_or(0.0, |a| a.after_s * 1e3);
                format!("{step} acknowledged ({attempts} attempt(s), {after_ms:.0} ms)")
            }
            (true, _) if step == ShutdownStep::GalvoSignalsOff && r.galvo_reopened => {
                format!("{step} acknowledged, on a new session (the galvo link was lost)")
            }
            (true, _) => format!("{step} acknowledged"),
            (false, Some(f)) => format!(
                "{step} NOT acknowledged ({}; gave up {:.0} ms after the stop): {}",
                f.error,
                f.after_s * 1e3,
                operator_action(step)
            ),
            (false, None) => format!("{step} NOT acknowledged: {}", operator_action(step)),
        };
        out.push(line);
    }
    out
}

/// One sentence on the way down for the error line: "the laser is off" only when its
/// emission-off was acknowledged, and every step that was not, named.
pub(super) fn shutdown_sentence(r: &ShutdownReport) -> String {
    if r.all_acknowledged() {
        return format!(
            "the laser is off (emission-off acknowledged {:.0} ms after the stop; galvo laser signals off, galvo stopped, motion stopped)",
            r.laser_off_s * 1e3
        );
    }
    let lines = shutdown_lines(r);
    let bad: Vec<&String> = lines.iter().filter(|l| l.contains("NOT")).collect();
    let head = if r.laser_off_ok {
        "the laser's emission is off (acknowledged), but NOT every step of the way down was"
    } else {
        "the laser's state is UNKNOWN"
    };
    format!(
        "{head}: {}",
        bad.iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join("; ")
    )
}

/// The way down's section of `report.md`.
pub(super) fn shutdown_markdown(r: &ShutdownReport) -> String {
    let mut s = String::from("\n## Way down\n\n");
    for line in shutdown_lines(r) {
        s.push_str(&format!("- {line}\n"));
    }
    s.push_str("\n| emission-off attempt | port | after ms | result |\n|---|---|---|---|\n");
    for (i, a) in r.emission_off.iter().enumerate() {
        s.push_str(&format!(
            "| {} | {:?} | {:.0} | {} |\n",
            i + 1,
            a.port,
            a.after_s * 1e3,
            a.error.as_deref().unwrap_or("acknowledged")
        ));
    }
    s
}

/// The way down of a stopped run, if it stopped through it.
pub(super) fn shutdown_of(outcome: &Result<RunSummary, ExecError>) -> Option<&ShutdownReport> {
    match outcome {
        Err(ExecError::Stopped(s)) => Some(&s.shutdown),
        _ => None,
    }
}

/// Appends a resume's outcome to the run's report (`report.md`) and records it in
/// `summary.json` under `resumes`.
pub(super) fn append_resume_report(
    run_dir: &Path,
    job: &Job,
    outcome: &Result<RunSummary, ExecError>,
    wall_s: f64,
) -> anyhow::Result<()> {
    let report_path = run_dir.join(files::REPORT);
    let mut report = std::fs::read_to_string(&report_path).unwrap_or_default();
    let summary_path = run_dir.join(files::SUMMARY);
    let mut json: serde_json::Value = std::fs::read_to_string(&summary_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_else(|| serde_json::json!({}));
    let resumes = json
        .as_object_mut()
        .context("summary.json is not a JSON object")?
        .entry("resumes")
        .or_insert_with(|| serde_json::json!([]));
    let n = resumes.as_array().map_or(0, Vec::len) + 1;
    report.push_str(&summary::resume_markdown(n, job, outcome, wall_s));
    let shutdown = shutdown_of(outcome);
    if let Some(r) = shutdown {
        report.push_str(&shutdown_markdown(r));
    }
    if let Some(list) = resumes.as_array_mut() {
        list.push(serde_json::json!({
            "wall_s": wall_s,
            "run": outcome.as_ref().ok(),
            "stopped": outcome.as_ref().err().map(ToString::to_string),
            "shutdown": shutdown,
        }));
    }
    trim_geom::fs::write_atomic(&report_path, report)
        .with_context(|| format!("cannot write {}", report_path.display()))?;
    trim_geom::fs::write_atomic(&summary_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    Ok(())
}

#[expect(
    clippy::too_many_arguments,
    reason = "the report gathers every stage's result"
)]
pub(super) fn write_report(
    run_dir: &Path,
    config: &JobConfig,
    description: &str,
    registration: &Registration,
    plan: &PlanOutput,
    timings: &Timings,
    run: Option<&RunSummary>,
    stopped: Option<(&str, Option<&ShutdownReport>)>,
    spots: Option<&SpotReport>,
    notes: &RunNotes<'_>,
) -> anyhow::Result<()> {
    let (stopped, shutdown) = stopped.map_or((None, None), |(s, r)| (Some(s), r));
    let mut report = summary::report_markdown(
        config,
        description,
        &registration.report,
        plan,
        run,
        stopped,
        &[
            ("load", timings.load_s),
            ("register", timings.register_s),
            ("detect", timings.detect_s),
            ("hatch", timings.hatch_s),
            ("plan", timings.plan_s),
            ("execute", timings.execute_s),
        ],
    );
    if let Some(r) = shutdown {
        report.push_str(&shutdown_markdown(r));
    }
    if let Some(s) = spots {
        report.push_str(&s.markdown());
    }
    report.push_str(&notes.markdown());
    trim_geom::fs::write_atomic(run_dir.join(files::REPORT), report)?;
    let (detection, injected_fault) = notes.json();
    let json = serde_json::json!({
        "detection": detection,
        "injected_fault": injected_fault,
        "timings_s": timings,
        "run": run,
        "stopped": stopped,
        "shutdown": shutdown,
        "zoning": {
            "method": if plan.cover.is_some() { "cover" } else { "kmeans" },
            "zones": plan.job.zones.len(),
            "pose_lower_bound": plan.cover.as_ref().map(|c| c.lower_bound),
            "summary": summary::zoning(plan),
        },
        "validation": plan.job.validation,
        "estimate": plan.job.estimate,
        "cycle_s": run.map(summary::cycle_split),
        "spot_error": spots,
        "calibration": config.plan.calibration,
        "lens": plan.job.settings.lens,
    });
    trim_geom::fs::write_atomic(
        run_dir.join(files::SUMMARY),
        serde_json::to_string_pretty(&json)?,
    )?;
    Ok(())
}
