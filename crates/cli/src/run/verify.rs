//! `trimctl run --verify`: after the job, the part is rescanned and every contour inspected
//! (as `trimctl inspect`, through the run's own registration: the part has not moved); the
//! contours that fail are planned again, each with the passes its measured excess needs, and
//! trimmed, up to `--rounds` times (DESIGN.md "Inspection", "Ablation and the twin's part").
//!
//! On the built-in demo part the digital twin does the physics: it trims its true part by the
//! landed cuts of each round and rescans it, through the true scanner and `[calibration]` as
//! the first scan was made. A part of the job's own files is rescanned by the cell's scanner
//! (`rescan`: a file the run waits for, or a configured scan command); there is no truth then.
//! Each inspection is written to `verify_<k>/` (inspection.json/csv, deviation.png,
//! report.html) and each retrim is a run of its own in `retrim_<k>/` (plan, journal, record);
//! `verify.json` lists the rounds.
//!
//! The loop goes on from wherever a stop left it (`trimctl run --resume RUN`): what it needs is
//! in the run folder as it goes ([`super::verify_state`], [`super::twin_cuts`]).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::{Deserialize, Serialize};
use trim_cell::Job;
use trim_geom::mesh::Mesh;
use trim_geom::{Path as TrimPath, PointCloud, Similarity3};
use trim_inspect::{InspectSettings, Inspection, Placement, Verdict, inspect};
use trim_io::executor::ExecError;
use trim_plan::planner::plan_with_sides;
use trim_register::eval::quantile;
use trim_register::regional::Registration;
use trim_sim::twin_part::{ContourTrim, TwinPart};

use super::blocked;
use super::execute::{execute, twin_link};
use super::inputs::Inputs;
use super::report::append_resume_report;
use super::rescan;
use super::twin_cuts::{self, CutsLog};
use super::verify_state::{VerifyState, load_rounds, save_rounds};
use super::{Args, exec_failure, files, job_finished, write_plan};
use crate::config::JobConfig;
use crate::exit::{Exit, Failure};
use crate::progress::stage;

/// One inspection of the part and what followed it (a round of `verify.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Round {
    /// 1 after the job, 2 after the first retrim, …
    pub(super) inspection: u32,
    /// Contours by verdict.
    pub(super) pass: usize,
    /// Contours that fail.
    pub(super) fail: usize,
    /// Contours neither proven good nor bad.
    pub(super) undecided: usize,
    /// The failing contours' ids.
    pub(super) failing: Vec<i64>,
    /// The digital twin's truth: the tallest web still standing and the deepest gouge over all
    /// contours, µm (null on a real part: nothing knows the truth).
    pub(super) true_residual_max_um: Option<f64>,
    /// See `true_residual_max_um`.
    pub(super) true_gouge_max_um: Option<f64>,
    /// The 95th percentile over the contours of each contour's tallest standing web, µm.
    pub(super) true_residual_p95_um: Option<f64>,
    /// The 95th percentile over the contours of each contour's deepest gouge, µm.
    pub(super) true_gouge_p95_um: Option<f64>,
    /// The twin's truth: the largest share of an opening a film still covers (0: every film
    /// cleared, or none was there; null on a real part).
    pub(super) true_film_covered_max: Option<f64>,
    /// The blocked openings hatched in the retrim after it (`[trim] hatch_blocked`).
    pub(super) hatched: Vec<i64>,
    /// Whether the failing contours were trimmed again after it.
    pub(super) retrimmed: bool,
}

/// A `--verify` run's loop: where it works and what it works with.
pub(super) struct VerifyRun<'a> {
    /// The job (overrides applied).
    pub(super) config: &'a JobConfig,
    /// The command line: the devices' options for the retrims (`--sim-time-scale`,
    /// `--cut-layer`, `--frame`, the cell's steps). The loop's own options are in `state`.
    pub(super) args: &'a Args,
    /// The run folder.
    pub(super) run_dir: &'a Path,
    /// The part's inputs (the demo part, as the twin carries it).
    pub(super) inputs: &'a Inputs,
    /// The part's CAD mesh.
    pub(super) mesh: &'a Mesh,
    /// The run's own registration (the part has not moved).
    pub(super) registration: &'a Registration,
    /// `--rounds` and the demo part's spec (`verify_state.json`).
    pub(super) state: &'a VerifyState,
}

/// Inspects and retrims until every contour passes inspection or the rounds are spent; the
/// rounds, in order. Goes on from where `verify.json` and the retrims' folders say the loop
/// stands: the twin's part (the demo's) is recreated from the landed cuts of the job and of
/// each recorded retrim, a recorded retrim that did not finish is finished first (resumed
/// from its journal: no layer marked twice), and the next inspection follows. A fresh run
/// starts with no round recorded.
pub(super) fn verify(v: &VerifyRun<'_>) -> anyhow::Result<Vec<Round>> {
    let config = v.config;
    // The demo part is the twin's: it trims the part by the landed cuts and rescans it.
    let mut part = v
        .inputs
        .demo
        .as_ref()
        .map(|demo| TwinPart::new(demo.case.clone(), demo.workpiece_from_case));
    let settings = InspectSettings::default();
    let placement = Placement::from_registration(v.registration);
    let mut rounds = load_rounds(v.run_dir, v.state.rounds)?;
    let recorded = match rounds.len() {
        0 => None,
        1 => Some("inspection 1".to_owned()),
        n => Some(format!("inspections 1–{n}")),
    };
    if let Some(which) = recorded {
        println!(
            "verify: {which} recorded in {}; going on from there",
            v.run_dir.join(files::VERIFY).display()
        );
    }
    // The loop ended at its last inspection (every retrim before it finished).
    if rounds.last().is_some_and(|r| !r.retrimmed) {
        return Ok(rounds);
    }
    replay(&mut part, v.run_dir, config)?;
    for r in rounds.iter().filter(|r| r.retrimmed) {
        execute_retrim(v, r.inspection)?;
        replay(&mut part, &retrim_dir(v.run_dir, r.inspection), config)?;
    }
    let next = u32::try_from(rounds.len() + 1).context("too many rounds")?;
    for k in next..=v.state.rounds + 1 {
        let scan = match part.as_ref() {
            Some(part) => {
                let _spinner = stage("rescanning the part");
                let seed = v.state.demo.map_or(0, |d| d.seed);
                twin_rescan(config, part, seed ^ u64::from(k) << 32)?
            }
            None => rescan::rescan(config, v.run_dir, k)?,
        };
        let spinner = stage("inspecting the part");
        let mut result = inspect(v.mesh, &v.inputs.path, scan.points(), &placement, &settings)?;
        // The scanner looks a second time when a dropout left contours uncovered, and those
        // contours are judged on the second rescan where it covers them better: an uncovered
        // contour is unverified, not good, and one more look is what a shop does. The twin's
        // scanner always can; a real cell's when `[verify] scan_command` scans on demand
        // (waiting for files, the run takes the one rescan as given). Not merged: the blocked
        // share of an opening counts any scan point over it, so twice the points read films
        // where the twin's truth has none (the demo's contour 19 at 13 %).
        let uncovered: Vec<i64> = result
            .contours
            .iter()
            .filter(|c| c.coverage < settings.min_coverage)
            .map(|c| c.id)
            .collect();
        if !uncovered.is_empty() {
            let again = match part.as_ref() {
                Some(part) => {
                    let _spinner = stage("rescanning the uncovered contours");
                    let seed = v.state.demo.map_or(0, |d| d.seed);
                    Some(twin_rescan(
                        config,
                        part,
                        seed ^ u64::from(k) << 32 ^ SECOND_LOOK,
                    )?)
                }
                None => rescan::rescan_again(config, v.run_dir, k)?,
            };
            if let Some(again) = again {
                let second = inspect(
                    v.mesh,
                    &v.inputs.path,
                    again.points(),
                    &placement,
                    &settings,
                )?;
                for c in &mut result.contours {
                    if let Some(s) = second.contours.iter().find(|s| s.id == c.id)
                        && uncovered.contains(&c.id)
                        && s.coverage > c.coverage
                    {
                        *c = s.clone();
                    }
                }
                println!(
                    "verify {k}: the rescan covered contours {uncovered:?} under {:.0} %; judged on a second rescan where it covers them better",
                    100.0 * settings.min_coverage
                );
            }
        }
        let dir = v.run_dir.join(format!("verify_{k}"));
        crate::inspect::write_inspection(
            &dir,
            v.mesh,
            &v.inputs.path,
            &scan,
            &placement,
            &settings,
            &result,
        )?;
        drop(spinner);
        let failing = ids(&result, Verdict::Fail);
        let state = part.as_ref().map(TwinPart::state);
        let truth = |of: fn(&ContourTrim) -> f64, stat: fn(&[f64]) -> f64| {
            state
                .as_ref()
                .map(|s| stat(&s.iter().map(of).collect::<Vec<f64>>()))
        };
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        let p95 = |v: &[f64]| quantile(v, 0.95);
        let residual = |c: &ContourTrim| c.residual_um;
        let gouge = |c: &ContourTrim| c.gouge_um;
        let mut round = Round {
            inspection: k,
            pass: ids(&result, Verdict::Pass).len(),
            fail: failing.len(),
            undecided: ids(&result, Verdict::Undecided).len(),
            failing: failing.iter().copied().collect(),
            true_residual_max_um: truth(residual, max),
            true_gouge_max_um: truth(gouge, max),
            true_residual_p95_um: truth(residual, p95),
            true_gouge_p95_um: truth(gouge, p95),
            true_film_covered_max: state.as_ref().map(|s| {
                s.iter()
                    .filter_map(|c| c.film_covered_share)
                    .fold(0.0, f64::max)
            }),
            hatched: Vec::new(),
            retrimmed: !failing.is_empty() && k <= v.state.rounds,
        };
        println!(
            "verify {k}: {} pass, {} fail, {} undecided{}{}; {}",
            round.pass,
            round.fail,
            round.undecided,
            if failing.is_empty() {
                String::new()
            } else {
                format!(" {:?}", round.failing)
            },
            round.truth_words(),
            dir.display()
        );
        // The retrim is planned before the round is recorded: a recorded round that was
        // retrimmed always has its plan, so a resume never inspects it again.
        if round.retrimmed {
            round.hatched = plan_retrim(v, &result, &failing, k)?;
        }
        let retrim = round.retrimmed;
        rounds.push(round);
        save_rounds(v.run_dir, &rounds)?;
        if !retrim {
            break;
        }
        execute_retrim(v, k)?;
        replay(&mut part, &retrim_dir(v.run_dir, k), config)?;
    }
    Ok(rounds)
}

/// Refuses, before anything moves, a `--verify` run whose loop could not go on: `verify.json`
/// unreadable or out of order, or (the demo part) a folder that executed without its landed
/// cuts (`twin_cuts.jsonl` is created before an execution's journal).
pub(super) fn check_resumable(run_dir: &Path, state: &VerifyState) -> anyhow::Result<()> {
    let rounds = load_rounds(run_dir, state.rounds)?;
    if state.demo.is_none() {
        return Ok(());
    }
    let executed = std::iter::once(run_dir.to_path_buf()).chain(
        rounds
            .iter()
            .filter(|r| r.retrimmed)
            .map(|r| retrim_dir(run_dir, r.inspection)),
    );
    for dir in executed.filter(|d| d.join(files::JOURNAL).exists()) {
        let cuts = dir.join(files::TWIN_CUTS);
        if !cuts.exists() {
            return Err(Failure::with_exit(
                Exit::Refused,
                anyhow::anyhow!(
                    "{} is missing: the twin's landed cuts of {} are needed to make its part again; the verify loop cannot go on",
                    cuts.display(),
                    dir.display()
                ),
            ));
        }
    }
    Ok(())
}

/// The folder of retrim `k`.
fn retrim_dir(run_dir: &Path, k: u32) -> PathBuf {
    run_dir.join(format!("retrim_{k}"))
}

/// Trims the twin's part (if there is one: the demo's) by the cuts that landed in the
/// executions in `dir` (`twin_cuts.jsonl`), as one round.
fn replay(part: &mut Option<TwinPart>, dir: &Path, config: &JobConfig) -> anyhow::Result<()> {
    if let Some(part) = part {
        let kerf_mm = config.plan.process.kerf_width_mm(&config.plan.beam);
        part.trim(&twin_cuts::read(dir)?, &config.plan.process, kerf_mm)
            .with_context(|| {
                format!("trimming the twin's part by the cuts of {}", dir.display())
            })?;
    }
    Ok(())
}

impl Round {
    /// The twin's truth, as the round's line prints it (nothing on a real part).
    pub(super) fn truth_words(&self) -> String {
        match (
            self.true_residual_p95_um,
            self.true_residual_max_um,
            self.true_gouge_p95_um,
            self.true_gouge_max_um,
        ) {
            (Some(rp), Some(rm), Some(gp), Some(gm)) => format!(
                " (twin truth over the contours: residual web P95 {rp:.1} / max {rm:.1} µm, gouge P95 {gp:.1} / max {gm:.1} µm, films cover at most {:.0} % of an opening)",
                100.0 * self.true_film_covered_max.unwrap_or(0.0)
            ),
            _ => String::new(),
        }
    }
}

/// The ids of the contours with verdict `v`.
fn ids(result: &Inspection, v: Verdict) -> BTreeSet<i64> {
    result
        .contours
        .iter()
        .filter(|c| c.verdict == v)
        .map(|c| c.id)
        .collect()
}

/// Mixed into a round's rescan seed for the twin's second look at contours the first left
/// uncovered.
const SECOND_LOOK: u64 = 0x5345_434f_4e44;

/// The part as it stands, scanned through the true cell's scanner and carried into the
/// work-piece frame through `[calibration]`, as the first scan.
fn twin_rescan(config: &JobConfig, part: &TwinPart, seed: u64) -> anyhow::Result<PointCloud> {
    let scanner_from_workpiece =
        Similarity3::from_isometry(crate::simulated::true_scanner_from_workpiece(config)?, 1.0);
    let in_scanner = part
        .rescan(seed)?
        .transformed(&scanner_from_workpiece)
        .context("sim.truth at part.scan_pose")?;
    config.workpiece_from_scan(&in_scanner)
}

/// Plans the failing contours (each polyline with the passes its measured excess height
/// needs: a web is no thicker than it is tall) and, with `[trim] hatch_blocked`, hatches the
/// blocked openings among them (`blocked`: each track with the passes through the film's
/// measured thickness, or `[trim] film_thickness_um` where only one side is seen; a rim
/// blocked but with no excess is hatched, not trimmed again), into
/// `retrim_<k>/` (a run folder of its own: the effective job file and field correction copied
/// in, plan.json); the rims hatched. Nothing is executed.
fn plan_retrim(
    v: &VerifyRun<'_>,
    found: &Inspection,
    failing: &BTreeSet<i64>,
    k: u32,
) -> anyhow::Result<Vec<i64>> {
    let (config, run_dir, registration) = (v.config, v.run_dir, v.registration);
    let dir = retrim_dir(run_dir, k);
    // Planned only before it runs: a retrim that began is finished from its journal, never
    // planned again over it.
    if dir.join(files::JOURNAL).exists() {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "{} already holds a journal, but {} does not record inspection {k}: the run folder is inconsistent; refusing to plan retrim {k} again over a retrim that began",
                dir.display(),
                run_dir.join(files::VERIFY).display()
            ),
        ));
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for file in [files::JOB, files::FIELD] {
        let src = run_dir.join(file);
        if src.exists() {
            std::fs::copy(&src, dir.join(file))
                .with_context(|| format!("cannot copy {} into {}", src.display(), dir.display()))?;
        }
    }
    let settings = InspectSettings::default();
    let hatches = blocked::hatch_blocked(
        &found.contours,
        &settings,
        &registration.path,
        failing,
        0,
        config,
        &dir,
    )?;
    let hatched = hatches.contours();
    let only_hatched: BTreeSet<i64> = found
        .contours
        .iter()
        .filter(|c| hatched.contains(&c.id) && c.excess_height_um <= 0.0)
        .map(|c| c.id)
        .collect();
    let path = TrimPath::new(
        registration
            .path
            .contours()
            .iter()
            .filter(|c| failing.contains(&c.id()) && !only_hatched.contains(&c.id()))
            .cloned()
            .chain(hatches.tracks.iter().cloned())
            .collect(),
    )?;
    // The failing contours alone may not say where their material is (a hole without its
    // outline): the sides come from the whole registered path.
    let sides = trim_plan::kerf::material_sides(&registration.path);
    let mut plan =
        plan_with_sides(&path, &config.plan, Some(&sides)).context("planning the retrim")?;
    plan.job.set_passes(|id| {
        if let Some(p) = hatches.passes.get(&id) {
            return *p;
        }
        found
            .contours
            .iter()
            .find(|c| c.id == id)
            .and_then(|c| {
                config
                    .plan
                    .process
                    .passes_through(c.excess_height_um * 1e-3)
            })
            .unwrap_or(trim_cell::process::MAX_PASSES)
    });
    if !plan.job.validation.passed {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "the retrim of {failing:?} fails validation:\n  {}",
                plan.job.validation.violations.join("\n  ")
            ),
        ));
    }
    write_plan(&dir, &plan)?;
    println!(
        "retrim {k}: contours {:?}, {} layers, passes from the measured excess; {}",
        failing.difference(&only_hatched).collect::<Vec<_>>(),
        plan.job.layers().count(),
        dir.display()
    );
    if let Some(line) = hatches.line() {
        println!("retrim {k}: {line}");
    }
    Ok(hatched.into_iter().collect())
}

/// Runs retrim `k` from its folder's plan (`retrim_<k>/plan.json`), the twin's cuts kept in
/// the folder: afresh when it has no journal, resumed from the journal when it began but did
/// not finish (finished layers are not marked again; the resume is added to the folder's
/// report.md and summary.json, as any resume), not at all when it finished. A stop is the
/// run's failure, and names the run folder to resume.
fn execute_retrim(v: &VerifyRun<'_>, k: u32) -> anyhow::Result<()> {
    let dir = retrim_dir(v.run_dir, k);
    let plan_file = dir.join(files::PLAN);
    let text = std::fs::read_to_string(&plan_file).with_context(|| {
        format!(
            "cannot read {} ({} records retrim {k})",
            plan_file.display(),
            v.run_dir.join(files::VERIFY).display()
        )
    })?;
    let job = Job::from_json(&text).with_context(|| plan_file.display().to_string())?;
    let journal = dir.join(files::JOURNAL);
    let resuming = journal.exists();
    if resuming && job_finished(&job, &journal)? {
        return Ok(());
    }
    if resuming {
        println!("retrim {k}: resuming {}", dir.display());
    }
    let twin = twin_link(v.config, v.run_dir)?;
    let log = twin_cuts::attach(&twin, &dir)?;
    let t = Instant::now();
    let executed = execute(v.config, v.args, &dir, &job, None, resuming, None, &twin);
    let wall_s = t.elapsed().as_secs_f64();
    let logged = log.map_or(Ok(()), CutsLog::finish);
    let (outcome, spots) = executed?;
    if resuming {
        if let Some(r) = &spots {
            print!("{}", r.line());
        }
        // A refusal before anything was switched on leaves the folder as it was.
        if !matches!(outcome, Err(ExecError::ResumeUnknown { .. })) {
            append_resume_report(&dir, &job, &outcome, wall_s)?;
        }
        if let Ok(run) = &outcome {
            print!("{}", crate::summary::execution(run, &job));
        }
    }
    outcome.map_err(|e| exec_failure(e, v.run_dir))?;
    logged
}
