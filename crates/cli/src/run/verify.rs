//! `trimctl run --verify`: after the job, the part is rescanned and every contour inspected
//! (as `trimctl inspect`, through the run's own registration: the part has not moved); the
//! contours that fail are planned again, each with the passes its measured excess needs, and
//! trimmed, up to `--rounds` times (DESIGN.md "Inspection", "Ablation and the twin's part").
//!
//! On the built-in cell the digital twin does the physics: it trims its true part by the
//! landed cuts of each round and rescans it, through the true scanner and `[calibration]` as
//! the first scan was made. Each inspection is written to `verify_<k>/` (inspection.json/csv,
//! deviation.png, report.html) and each retrim is a run of its own in `retrim_<k>/` (plan,
//! journal, record); `verify.json` lists the rounds.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use trim_geom::{Path as TrimPath, PointCloud, Similarity3};
use trim_inspect::{InspectSettings, Inspection, Placement, Verdict, inspect};
use trim_plan::planner::plan_with_sides;
use trim_register::regional::Registration;
use trim_sim::twin_part::TwinPart;

use super::blocked;
use super::execute::{TwinLink, execute, twin_link};
use super::inputs::Inputs;
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
    /// contours, µm.
    pub(super) true_residual_max_um: f64,
    /// See `true_residual_max_um`.
    pub(super) true_gouge_max_um: f64,
    /// The twin's truth: the largest share of an opening a film still covers (0: every film
    /// cleared, or none was there).
    pub(super) true_film_covered_max: f64,
    /// The blocked openings hatched in the retrim after it (`[trim] hatch_blocked`).
    pub(super) hatched: Vec<i64>,
    /// Whether the failing contours were trimmed again after it.
    pub(super) retrimmed: bool,
}

/// Inspects and retrims until every contour passes inspection or the rounds are spent; the
/// rounds, in order. `twin` is the twin of the job just run.
pub(super) fn verify(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    inputs: &Inputs,
    registration: &Registration,
    twin: &TwinLink,
) -> anyhow::Result<Vec<Round>> {
    let demo = inputs.demo.as_ref().context(
        "--verify: only the built-in demo part can be rescanned (by the digital twin); rescanning a real part is not supported yet",
    )?;
    let mut part = TwinPart::new(demo.case.clone(), demo.workpiece_from_case);
    let mesh = demo.case.cad_mesh()?;
    let kerf_mm = config.plan.process.kerf_width_mm(&config.plan.beam);
    let settings = InspectSettings::default();
    let placement = Placement::from_registration(registration);
    let mut cuts = landed_cuts(twin)?;
    let mut rounds: Vec<Round> = Vec::new();
    for k in 1..=args.rounds + 1 {
        part.trim(&cuts, &config.plan.process, kerf_mm)?;
        let spinner = stage("rescanning and inspecting the part");
        let scan = rescan(config, &part, args.demo_seed ^ u64::from(k) << 32)?;
        let result = inspect(&mesh, &inputs.path, scan.points(), &placement, &settings)?;
        let dir = run_dir.join(format!("verify_{k}"));
        crate::inspect::write_inspection(
            &dir,
            &mesh,
            &inputs.path,
            &scan,
            &placement,
            &settings,
            &result,
        )?;
        drop(spinner);
        let failing = ids(&result, Verdict::Fail);
        let state = part.state();
        let round = Round {
            inspection: k,
            pass: ids(&result, Verdict::Pass).len(),
            fail: failing.len(),
            undecided: ids(&result, Verdict::Undecided).len(),
            failing: failing.iter().copied().collect(),
            true_residual_max_um: state.iter().map(|c| c.residual_um).fold(0.0, f64::max),
            true_gouge_max_um: state.iter().map(|c| c.gouge_um).fold(0.0, f64::max),
            true_film_covered_max: state
                .iter()
                .filter_map(|c| c.film_covered_share)
                .fold(0.0, f64::max),
            hatched: Vec::new(),
            retrimmed: !failing.is_empty() && k <= args.rounds,
        };
        println!(
            "verify {k}: {} pass, {} fail, {} undecided{} (twin truth: residual web max {:.1} µm, gouge max {:.1} µm, films cover at most {:.0} % of an opening); {}",
            round.pass,
            round.fail,
            round.undecided,
            if failing.is_empty() {
                String::new()
            } else {
                format!(" {:?}", round.failing)
            },
            round.true_residual_max_um,
            round.true_gouge_max_um,
            100.0 * round.true_film_covered_max,
            dir.display()
        );
        let retrim = round.retrimmed;
        rounds.push(round);
        if !retrim {
            break;
        }
        let (landed, hatched) =
            retrim_round(config, args, run_dir, registration, &result, &failing, k)?;
        cuts = landed;
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
fn rescan(config: &JobConfig, part: &TwinPart, seed: u64) -> anyhow::Result<PointCloud> {
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
/// runs them in `retrim_<k>/`; the cuts the twin saw land, and the rims hatched.
fn retrim_round(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    registration: &Registration,
    found: &Inspection,
    failing: &BTreeSet<i64>,
    k: u32,
) -> anyhow::Result<(Vec<trim_sim::ablation::LandedCut>, Vec<i64>)> {
    let dir = run_dir.join(format!("retrim_{k}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
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
    Ok((landed_cuts(&twin)?, hatched.into_iter().collect()))
}
