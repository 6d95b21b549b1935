//! `trimctl run --verify`: after the job, the part is rescanned and every contour inspected
//! (as `trimctl inspect`, through the run's own registration: the part has not moved); the
//! contours that fail are planned again, each with the passes its measured excess needs, and
//! trimmed, up to `--rounds` times (DESIGN.md "Inspection", "Ablation and the twin's part").
//!
//! On the built-in demo part the digital twin does the physics: it trims its true part by the
//! landed cuts of each round and rescans it, through the true scanner and `[calibration]` as
//! the first scan was made. A part of the job's own files is rescanned by the cell's scanner
//! (`rescan`: a file the run waits for, or a configured scan command); there is no truth then. Each inspection is written to `verify_<k>/` (inspection.json/csv,
//! deviation.png, report.html) and each retrim is a run of its own in `retrim_<k>/` (plan,
//! journal, record); `verify.json` lists the rounds.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use trim_geom::mesh::Mesh;
use trim_geom::{Path as TrimPath, PointCloud, Similarity3};
use trim_inspect::{InspectSettings, Inspection, Placement, Verdict, inspect};
use trim_plan::planner::plan_with_sides;
use trim_register::eval::quantile;
use trim_register::regional::Registration;
use trim_sim::twin_part::{ContourTrim, TwinPart};

use super::blocked;
use super::execute::{TwinLink, execute, twin_link};
use super::inputs::Inputs;
use super::rescan;
use super::{Args, exec_failure, files, write_plan};
use crate::config::JobConfig;
use crate::exit::{Exit, Failure};
use crate::progress::stage;

/// One inspection of the part and what followed it.
#[derive(Debug, Clone, Serialize)]
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

/// Inspects and retrims until every contour passes inspection or the rounds are spent; the
/// rounds, in order. `twin` is the twin of the job just run; `mesh` the part's CAD mesh.
pub(super) fn verify(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    inputs: &Inputs,
    mesh: &Mesh,
    registration: &Registration,
    twin: &TwinLink,
) -> anyhow::Result<Vec<Round>> {
    // The demo part is the twin's: it trims the part by the landed cuts and rescans it.
    let mut part = inputs
        .demo
        .as_ref()
        .map(|demo| TwinPart::new(demo.case.clone(), demo.workpiece_from_case));
    let kerf_mm = config.plan.process.kerf_width_mm(&config.plan.beam);
    let settings = InspectSettings::default();
    let placement = Placement::from_registration(registration);
    let mut cuts = match part {
        Some(_) => landed_cuts(twin)?,
        None => Vec::new(),
    };
    let mut rounds: Vec<Round> = Vec::new();
    for k in 1..=args.rounds + 1 {
        let scan = match part.as_mut() {
            Some(part) => {
                part.trim(&cuts, &config.plan.process, kerf_mm)?;
                let _spinner = stage("rescanning the part");
                twin_rescan(config, part, args.demo_seed ^ u64::from(k) << 32)?
            }
            None => rescan::rescan(config, run_dir, k)?,
        };
        let spinner = stage("inspecting the part");
        let result = inspect(mesh, &inputs.path, scan.points(), &placement, &settings)?;
        let dir = run_dir.join(format!("verify_{k}"));
        crate::inspect::write_inspection(
            &dir,
            mesh,
            &inputs.path,
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
        let round = Round {
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
            retrimmed: !failing.is_empty() && k <= args.rounds,
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
        let retrim = round.retrimmed;
        rounds.push(round);
        if !retrim {
            break;
        }
        let (landed, hatched) =
            retrim_round(config, args, run_dir, registration, &result, &failing, k)?;
        if part.is_some() {
            cuts = landed_cuts(&landed)?;
        }
        if let Some(r) = rounds.last_mut() {
            r.hatched = hatched;
        }
    }
    std::fs::write(
        run_dir.join(files::VERIFY),
        serde_json::to_string_pretty(&rounds)?,
    )?;
    Ok(rounds)
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

/// The twin's landed cuts of a run.
fn landed_cuts(twin: &TwinLink) -> anyhow::Result<Vec<trim_sim::ablation::LandedCut>> {
    twin.twin
        .as_ref()
        .map(|t| t.cuts())
        .context("--verify: the galvo is not simulated, so nothing tells what the laser removed")
}

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
/// blocked openings among them (`blocked`: each track with the passes of `[trim]
/// film_thickness_um`; a rim blocked but with no excess is hatched, not trimmed again), and
/// runs them in `retrim_<k>/`; the run's twin link (what the simulated galvo landed) and the
/// rims hatched.
fn retrim_round(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    registration: &Registration,
    found: &Inspection,
    failing: &BTreeSet<i64>,
    k: u32,
) -> anyhow::Result<(TwinLink, Vec<i64>)> {
    let dir = run_dir.join(format!("retrim_{k}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    // The retrim's folder is a run folder of its own: a stopped retrim resumes with `trimctl
    // run --resume RUN/retrim_<k>` (its effective job file and field correction beside it).
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
    let twin = twin_link(config, run_dir)?;
    let (outcome, _) = execute(config, args, &dir, &plan.job, None, false, None, &twin)?;
    outcome.map_err(|e| exec_failure(e, &dir))?;
    Ok((twin, hatched.into_iter().collect()))
}
