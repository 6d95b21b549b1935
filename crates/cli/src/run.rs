//! `trimctl run`: the whole job from one command. Register, plan, show what will be done,
//! execute on the cell, and leave a complete run folder.
//!
//! With no job file it runs the built-in demo part (a synthetic ceramic core, see
//! `trim_synth`) against the built-in simulated cell.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use serde::Serialize;
use tokio_util::sync::CancellationToken;
use trim_geom::formats;
use trim_geom::math::Similarity3;
use trim_geom::{Path as TrimPath, PointCloud};
use trim_io::cell::{Cell, CellAddresses, SimCell, SimOptions, Timeouts};
use trim_io::executor::{ExecError, ExecOptions, Executor, Progress, RunSummary, StopCause};
use trim_io::journal::{CutLayer, Entry};
use trim_io::laser::Profile;
use trim_io::record::{Recorder, SharedRecorder, device_tap};
use trim_io::tap::Tap;
use trim_io::twin::{Spot, SpotStats, TrueCell, TruePart, Twin};
use trim_plan::Job;
use trim_plan::planner::{PlanOutput, plan_with_report};
use trim_register::regional::{Registration, register};
use trim_synth::{SynthParams, generate};

use crate::config::{HatchRegion, JobConfig, SIM};
use crate::exit::{Exit, Failure};
use crate::progress::{JobProgress, stage};
use crate::summary;

/// Files of a run folder.
pub mod files {
    /// The effective job file (what resume re-reads).
    pub const JOB: &str = "job.toml";
    /// The registered path.
    pub const REGISTERED: &str = "registered.csv";
    /// The registration quality report.
    pub const REGISTRATION: &str = "registration.json";
    /// The planned job.
    pub const PLAN: &str = "plan.json";
    /// The plan's picture.
    pub const PLAN_SVG: &str = "plan.svg";
    /// The executor's journal.
    pub const JOURNAL: &str = "journal.jsonl";
    /// The MCAP record of the execution.
    pub const RECORD: &str = "run.mcap";
    /// The short report.
    pub const REPORT: &str = "report.md";
    /// Stage timings and the run summary.
    pub const SUMMARY: &str = "summary.json";
    /// The demo part's input files.
    pub const INPUTS: &str = "inputs";
    /// The copy of the field correction the run used.
    pub const FIELD: &str = "field.json";
    /// The demo part's true trimming line (work-piece frame), under [`INPUTS`].
    pub const TRUTH: &str = "truth.csv";
}

/// The simulated cell's default speed: real seconds per simulated second. The demo runs the
/// galvo and the CNC 20× faster than real time so it ends in seconds, not minutes.
pub const DEFAULT_SIM_TIME_SCALE: f64 = 0.05;

/// Arguments of `trimctl run`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The job file. Without one: the built-in demo part on the built-in simulated cell.
    #[arg(value_name = "JOB.toml")]
    job: Option<PathBuf>,
    /// The run folder (default: a new time-stamped folder under `output.runs_dir`).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Continue the interrupted run in RUN_DIR at its first unfinished layer.
    #[arg(long, value_name = "RUN_DIR", conflicts_with_all = ["job", "out"])]
    resume: Option<PathBuf>,
    /// With --resume: what to do with a layer cut at a point nobody can tell (the galvo lost
    /// its list to a restart, or trimctl was killed mid-layer): `redo` marks it again (the
    /// vectors it had marked are marked twice), `skip` leaves it out (the report lists it).
    /// The choice is journaled. Not used when the cut point is known.
    #[arg(long, value_enum, value_name = "redo|skip", requires = "resume")]
    cut_layer: Option<CutLayerArg>,
    /// The CNC (LinuxCNC linuxcncrsh) as HOST:PORT, overriding `cell.cnc`.
    #[arg(long, value_name = "HOST:PORT")]
    cnc: Option<String>,
    /// The galvo controller as HOST:PORT, overriding `cell.galvo`.
    #[arg(long, value_name = "HOST:PORT")]
    galvo: Option<String>,
    /// The laser's serial device, overriding `cell.laser`.
    #[arg(long, value_name = "DEVICE")]
    laser: Option<String>,
    /// Start even if the plan fails validation (the violations are printed and recorded).
    #[arg(long)]
    allow_invalid: bool,
    /// Plan without the contours registration flags untrustworthy (they are listed in the
    /// report) instead of refusing to start.
    #[arg(long)]
    skip_untrusted: bool,
    /// Register and plan, write the run folder, execute nothing.
    #[arg(long)]
    dry_run: bool,
    /// The demo part's seed.
    #[arg(long, default_value_t = 1)]
    demo_seed: u64,
    /// Simulated devices: real seconds per simulated second (1 = real time).
    #[arg(long, default_value_t = DEFAULT_SIM_TIME_SCALE)]
    sim_time_scale: f64,
}

/// `--cut-layer`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum CutLayerArg {
    /// Mark the layer again.
    Redo,
    /// Leave the layer out.
    Skip,
}

impl From<CutLayerArg> for CutLayer {
    fn from(a: CutLayerArg) -> CutLayer {
        match a {
            CutLayerArg::Redo => CutLayer::Redo,
            CutLayerArg::Skip => CutLayer::Skip,
        }
    }
}

/// Wall time of each stage (s).
#[derive(Debug, Default, Serialize)]
struct Timings {
    load_s: f64,
    register_s: f64,
    hatch_s: f64,
    plan_s: f64,
    execute_s: f64,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.sim_time_scale.is_finite() && args.sim_time_scale > 0.0) {
        bail!(
            "--sim-time-scale: must be a number > 0, got {}",
            args.sim_time_scale
        );
    }
    match args.resume.clone() {
        Some(dir) => resume(&dir, &args),
        None => fresh(&args),
    }
}

fn apply_overrides(config: &mut JobConfig, args: &Args) -> anyhow::Result<()> {
    if let Some(c) = &args.cnc {
        config.cell.cnc.clone_from(c);
    }
    if let Some(g) = &args.galvo {
        config.cell.galvo.clone_from(g);
    }
    if let Some(l) = &args.laser {
        config.cell.laser.clone_from(l);
    }
    config
        .validate()
        .context("after applying --cnc/--galvo/--laser")?;
    Ok(())
}

/// The part's inputs: CAD cloud with outward normals, the scan mapped into the work-piece
/// frame through `[calibration]`, template path, fixture pose.
struct Inputs {
    cad: PointCloud,
    scan: PointCloud,
    path: TrimPath,
    /// The regions to hatch: `[[hatch]]`, or the demo part's own region.
    hatch: Vec<HatchRegion>,
    scan_from_cad_initial: Similarity3,
    description: String,
}

fn load_inputs(config: &JobConfig, args: &Args, run_dir: &Path) -> anyhow::Result<Inputs> {
    if config.is_demo() {
        let params = SynthParams {
            seed: args.demo_seed,
            ..SynthParams::default()
        };
        let case = generate(&params).context("building the demo part")?;
        let dir = run_dir.join(files::INPUTS);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        // The synthetic part lives in the true work-piece frame; the scanner sees it through
        // the true cell ([sim.truth]) at the scan pose.
        let truth_cell = TrueCell::new(&config.sim.truth, &config.plan_settings());
        let scanner_from_workpiece = Similarity3::from_isometry(
            truth_cell.scanner_from_workpiece(&config.part.scan_pose),
            1.0,
        );
        let scan_in_scanner = case.scan.transformed(&scanner_from_workpiece);
        formats::write_path(&dir.join("path.csv"), &case.path)?;
        formats::write_path(&dir.join(files::TRUTH), &case.truth)?;
        formats::write_ply(
            &dir.join("scan.ply"),
            &scan_in_scanner,
            formats::PlyEncoding::BinaryLittleEndian,
        )?;
        formats::write_ply(
            &dir.join("cad_points.ply"),
            &case.cad_points,
            formats::PlyEncoding::BinaryLittleEndian,
        )?;
        // The demo hatches a flash film on its top face unless the job names its own regions.
        let hatch = if config.hatch.is_empty() {
            let boundary = dir.join(DEMO_HATCH_BOUNDARY);
            formats::write_path(
                &boundary,
                &TrimPath::new(vec![trim_synth::demo_hatch_boundary()?])?,
            )?;
            vec![HatchRegion {
                boundary,
                settings: demo_hatch_settings(),
            }]
        } else {
            config.hatch.clone()
        };
        return Ok(Inputs {
            hatch,
            description: format!(
                "built-in demo part (synthetic ceramic core, seed {}, {} contours, {} scan points)",
                args.demo_seed,
                case.path.len(),
                case.scan.len()
            ),
            cad: case.cad_points,
            scan: config.scan_to_workpiece(&scan_in_scanner),
            path: case.path,
            scan_from_cad_initial: case.scan_from_cad_nominal,
        });
    }
    let (Some(cad_file), Some(path_file), Some(scan_file)) =
        (&config.part.cad, &config.part.path, &config.part.scan)
    else {
        bail!("part: give all of cad, path and scan");
    };
    let cad = match formats::read_geometry(cad_file)? {
        formats::Geometry::Mesh(mesh) => {
            mesh.sample_area_weighted(config.register.cad_sample_points, CAD_SAMPLE_SEED)
        }
        formats::Geometry::Points(cloud) => {
            if !cloud.has_normals() {
                bail!(
                    "{}: a CAD point cloud needs outward normals (nx ny nz); give the STL mesh instead",
                    cad_file.display()
                );
            }
            cloud
        }
        formats::Geometry::Path(_) => bail!(
            "{}: part.cad is a path CSV; give the CAD model (STL/PLY mesh or point cloud)",
            cad_file.display()
        ),
    };
    let scan = config.scan_to_workpiece(&formats::read_points(scan_file)?);
    let path = formats::read_path(path_file)?;
    if !config.hatch.is_empty() {
        crate::hatch::check_path_ids(&path, path_file)?;
    }
    Ok(Inputs {
        hatch: config.hatch.clone(),
        description: format!(
            "CAD {}, path {} ({} contours), scan {} ({} points)",
            cad_file.display(),
            path_file.display(),
            path.len(),
            scan_file.display(),
            scan.len()
        ),
        cad,
        scan,
        path,
        scan_from_cad_initial: Similarity3::identity(),
    })
}

/// The demo's hatch boundary file, in the run folder's inputs.
const DEMO_HATCH_BOUNDARY: &str = "hatch_boundary.csv";

/// The demo region's hatching: 0.05 mm pitch across the top face's camber (the planner splits
/// tracks where the incidence limit requires), points placed by a 2 µm chord tolerance (vector
/// marking).
fn demo_hatch_settings() -> trim_plan::hatch::HatchSettings {
    trim_plan::hatch::HatchSettings {
        pitch_mm: 0.05,
        chord_tolerance_mm: Some(0.002),
        ..trim_plan::hatch::HatchSettings::default()
    }
}

/// The true trimming line the twin measures the spot error against: `[sim.truth] path`, or the
/// demo part's own (in the run folder).
fn truth_line(config: &JobConfig, run_dir: &Path) -> anyhow::Result<Option<TrimPath>> {
    let file = match &config.sim.truth.path {
        Some(p) => p.clone(),
        None => {
            let demo = run_dir.join(files::INPUTS).join(files::TRUTH);
            if !(config.is_demo() && demo.exists()) {
                return Ok(None);
            }
            demo
        }
    };
    Ok(Some(
        formats::read_path(&file).context("sim.truth.path: the true trimming line")?,
    ))
}

/// The twin's spot errors of a run: overall and per zone (µm), over the spots of contours on
/// the true trimming line (hatch tracks have no line to be measured against).
#[derive(Debug, Clone, Serialize)]
pub struct SpotReport {
    /// Over every landed spot of a trimming-line contour.
    pub overall: SpotStats,
    /// Per zone id, in job order.
    pub per_zone: Vec<(usize, SpotStats)>,
    /// Spots left out: on contours the true line does not hold (hatch tracks).
    pub excluded_spots: usize,
}

impl SpotReport {
    /// Finds each spot's layer through the journal's list tags and its contour through the
    /// layer's vectors (each polyline of n points is n − 1 vectors; a resumed list starts at the
    /// journaled `first_vector`), then keeps the spots of `line_ids`' contours.
    fn new(
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
            let mut v = u64::from(*first) + u64::from(s.vector);
            for p in &layer.polylines {
                let n = p.points.len().saturating_sub(1) as u64;
                if v < n {
                    return Some((key.zone, p.contour));
                }
                v -= n;
            }
            None
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

    fn line(&self) -> String {
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

/// The seed of the area-weighted CAD sampling (fixed: the same CAD gives the same samples).
const CAD_SAMPLE_SEED: u64 = 0x00c4_d5a3;

fn new_run_dir(config: &JobConfig, args: &Args) -> anyhow::Result<PathBuf> {
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let stamp = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
                .to_string()
                .replace(':', "-");
            config.output.runs_dir.join(stamp)
        }
    };
    if dir.join(files::JOURNAL).exists() {
        bail!(
            "{} already holds a run (journal present): use --resume {} to continue it, or another --out",
            dir.display(),
            dir.display()
        );
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

fn fresh(args: &Args) -> anyhow::Result<()> {
    let mut timings = Timings::default();
    let t0 = Instant::now();
    let mut config = match &args.job {
        Some(p) => JobConfig::load(p)?,
        None => JobConfig::default(),
    };
    apply_overrides(&mut config, args)?;
    let run_dir = new_run_dir(&config, args)?;
    // The run keeps its own copy of the field correction it used (the Job records its
    // checksum), so the folder alone can be resumed and audited.
    if let Some(src) = config.calibration.field_correction.clone() {
        let copy = run_dir.join(files::FIELD);
        std::fs::copy(&src, &copy).with_context(|| {
            format!(
                "calibration.field_correction: cannot copy {}",
                src.display()
            )
        })?;
        config.calibration.field_correction = Some(copy);
    }
    // The effective job file names the copy relative to itself.
    let mut effective = config.clone();
    if effective.calibration.field_correction.is_some() {
        effective.calibration.field_correction = Some(PathBuf::from(files::FIELD));
    }
    std::fs::write(
        run_dir.join(files::JOB),
        toml::to_string(&effective).context("serialising the job file")?,
    )?;
    eprintln!("trimctl run: recording to {}", run_dir.display());

    let spinner = stage("loading the part");
    let inputs = load_inputs(&config, args, &run_dir)?;
    drop(spinner);
    timings.load_s = t0.elapsed().as_secs_f64();
    println!("part: {}", inputs.description);

    // Register.
    let t = Instant::now();
    let spinner = stage("registering the path onto the scan");
    let registration = register(
        &inputs.cad,
        &inputs.scan,
        &inputs.path,
        &inputs.scan_from_cad_initial,
        &config.register,
    )
    .context("registration")?;
    drop(spinner);
    timings.register_s = t.elapsed().as_secs_f64();
    formats::write_path(&run_dir.join(files::REGISTERED), &registration.path)?;
    std::fs::write(
        run_dir.join(files::REGISTRATION),
        serde_json::to_string_pretty(&registration.report)?,
    )?;
    print!("{}", summary::registration(&registration.report));

    // Plan, without untrustworthy contours if asked.
    let untrusted: Vec<i64> = registration
        .report
        .contours
        .iter()
        .filter(|c| !c.trustworthy)
        .map(|c| c.id)
        .collect();
    let to_plan = if untrusted.is_empty() {
        registration.path.clone()
    } else if args.skip_untrusted {
        eprintln!(
            "trimctl run: planning without {} untrustworthy contour(s): {untrusted:?}",
            untrusted.len()
        );
        let kept: Vec<_> = registration
            .path
            .contours()
            .iter()
            .filter(|c| !untrusted.contains(&c.id()))
            .cloned()
            .collect();
        TrimPath::new(kept).context("no trustworthy contour left to plan")?
    } else {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "registration flags {} contour(s) untrustworthy: {untrusted:?} (see {}); refusing to start. Check the scan, or pass --skip-untrusted to trim the others",
                untrusted.len(),
                run_dir.join(files::REGISTRATION).display()
            ),
        ));
    };
    // Hatch tracks, on the registered scan, planned beside the contours.
    let to_plan = if inputs.hatch.is_empty() {
        to_plan
    } else {
        let t = Instant::now();
        let spinner = stage("hatching regions on the registered scan");
        let regions = crate::hatch::hatch_regions(
            &inputs.hatch,
            &inputs.scan,
            &|p| registration.scan_from_cad_point(p),
            &run_dir,
        )?;
        drop(spinner);
        timings.hatch_s = t.elapsed().as_secs_f64();
        let mut contours = to_plan.contours().to_vec();
        for r in regions {
            println!("{}", r.summary);
            contours.extend(r.tracks);
        }
        TrimPath::new(contours)?
    };
    let t = Instant::now();
    let spinner = stage("planning zones and layers");
    let plan = plan_with_report(&to_plan, &config.plan_settings()).context("planning")?;
    drop(spinner);
    timings.plan_s = t.elapsed().as_secs_f64();
    write_plan(&run_dir, &plan)?;
    print!("{}", summary::plan(&plan));

    if !plan.job.validation.passed {
        let lines = plan.job.validation.violations.join("\n  ");
        let unreachable = &plan.job.validation.unreachable_zones;
        if !unreachable.is_empty() {
            return Err(Failure::with_exit(
                Exit::Refused,
                anyhow::anyhow!(
                    "zone(s) {unreachable:?} cannot be reached within the axis limits; refusing to start (--allow-invalid does not override this):\n  {lines}"
                ),
            ));
        }
        if !args.allow_invalid {
            return Err(Failure::with_exit(
                Exit::Refused,
                anyhow::anyhow!(
                    "the plan fails validation; refusing to start (pass --allow-invalid to override):\n  {lines}"
                ),
            ));
        }
        eprintln!("trimctl run: WARNING: starting a plan that fails validation:\n  {lines}");
    }
    if args.dry_run {
        write_report(
            &run_dir,
            &config,
            &inputs.description,
            &registration,
            &plan,
            &timings,
            None,
            None,
            None,
        )?;
        println!(
            "dry run: nothing executed; run folder {}",
            run_dir.display()
        );
        return Ok(());
    }

    let t = Instant::now();
    let record = Some((&inputs, &registration));
    let outcome = execute(&config, args, &run_dir, &plan.job, record, false);
    timings.execute_s = t.elapsed().as_secs_f64();
    finish(
        &run_dir,
        &config,
        &inputs.description,
        &registration,
        &plan,
        &timings,
        outcome,
    )
}

fn write_plan(run_dir: &Path, plan: &PlanOutput) -> anyhow::Result<()> {
    std::fs::write(run_dir.join(files::PLAN), plan.job.to_json()?)?;
    std::fs::write(
        run_dir.join(files::PLAN_SVG),
        trim_plan::svg::job_svg(&plan.job),
    )?;
    Ok(())
}

fn finish(
    run_dir: &Path,
    config: &JobConfig,
    description: &str,
    registration: &Registration,
    plan: &PlanOutput,
    timings: &Timings,
    outcome: anyhow::Result<Executed>,
) -> anyhow::Result<()> {
    let (outcome, spots) = outcome?;
    let stopped = outcome.as_ref().err().map(ToString::to_string);
    write_report(
        run_dir,
        config,
        description,
        registration,
        plan,
        timings,
        outcome.as_ref().ok(),
        stopped.as_deref(),
        spots.as_ref(),
    )?;
    if let Some(r) = &spots {
        print!("{}", r.line());
    }
    match outcome {
        Ok(run) => {
            print!("{}", summary::execution(&run, &plan.job));
            println!("done: run folder {}", run_dir.display());
            Ok(())
        }
        Err(e) => Err(exec_failure(e, run_dir)),
    }
}

/// The exit code and message of a run that did not finish: interrupted 3; stopped by a fault
/// (a device, or the journal's disk) 2; refused before anything was switched on 1.
fn exec_failure(e: ExecError, run_dir: &Path) -> anyhow::Error {
    let exit = match &e {
        ExecError::Stopped(s) if s.cause == StopCause::Cancelled => Exit::Interrupted,
        ExecError::Stopped(_) => Exit::DeviceFault,
        _ => Exit::Refused,
    };
    match e {
        ExecError::Stopped(_) => Failure::with_exit(
            exit,
            anyhow::anyhow!(
                "{e}; the laser is off; continue with: trimctl run --resume {}",
                run_dir.display()
            ),
        ),
        ExecError::ResumeUnknown { .. } => Failure::with_exit(
            exit,
            anyhow::anyhow!(
                "{e}: trimctl run --resume {dir} --cut-layer redo, or trimctl run --resume {dir} --cut-layer skip",
                dir = run_dir.display()
            ),
        ),
        other => Failure::with_exit(exit, other),
    }
}

fn resume(run_dir: &Path, args: &Args) -> anyhow::Result<()> {
    let mut config = JobConfig::load(&run_dir.join(files::JOB))
        .with_context(|| format!("{} is not a run folder", run_dir.display()))?;
    apply_overrides(&mut config, args)?;
    let text = std::fs::read_to_string(run_dir.join(files::PLAN))
        .with_context(|| format!("cannot read {}", run_dir.join(files::PLAN).display()))?;
    let job = Job::from_json(&text)
        .with_context(|| format!("{}", run_dir.join(files::PLAN).display()))?;
    if !run_dir.join(files::JOURNAL).exists() {
        bail!(
            "{}: no journal: the run never started executing; start a new run instead",
            run_dir.display()
        );
    }
    eprintln!("trimctl run: resuming {}", run_dir.display());
    let t = Instant::now();
    let (outcome, spots) = execute(&config, args, run_dir, &job, None, true)?;
    let wall_s = t.elapsed().as_secs_f64();
    if let Some(r) = &spots {
        print!("{}", r.line());
    }
    // A refusal before anything was switched on leaves the run folder as it was.
    if !matches!(outcome, Err(ExecError::ResumeUnknown { .. })) {
        append_resume_report(run_dir, &job, &outcome, wall_s)?;
    }
    match outcome {
        Ok(run) => {
            print!("{}", summary::execution(&run, &job));
            println!(
                "done: resumed run finished in {wall_s:.1} s; run folder {}",
                run_dir.display()
            );
            Ok(())
        }
        Err(e) => Err(exec_failure(e, run_dir)),
    }
}

/// What an execution gave: the executor's outcome and, with the digital twin, the spot
/// errors on the true part.
type Executed = (Result<RunSummary, ExecError>, Option<SpotReport>);

/// Appends a resume's outcome to the run's report (`report.md`) and records it in
/// `summary.json` under `resumes`.
fn append_resume_report(
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
    if let Some(list) = resumes.as_array_mut() {
        list.push(serde_json::json!({
            "wall_s": wall_s,
            "run": outcome.as_ref().ok(),
            "stopped": outcome.as_ref().err().map(ToString::to_string),
        }));
    }
    std::fs::write(&report_path, report)
        .with_context(|| format!("cannot write {}", report_path.display()))?;
    std::fs::write(&summary_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    Ok(())
}

/// Connects the cell (starting simulators where the config says "sim"), then runs or resumes.
/// The outer error: the cell could not be set up; the inner: the execution stopped.
fn execute(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    job: &Job,
    record: Option<(&Inputs, &Registration)>,
    resuming: bool,
) -> anyhow::Result<Executed> {
    // The twin lands the galvo simulator's vectors on the true part ([sim.truth]).
    let (twin, line_ids) = match truth_line(config, run_dir)? {
        Some(line) if config.cell.galvo == SIM => (
            Some(Twin::new(
                TrueCell::new(&config.sim.truth, &config.plan_settings()),
                TruePart::new(&line),
            )),
            line.contours().iter().map(trim_geom::Contour::id).collect(),
        ),
        _ => (None, std::collections::HashSet::new()),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async {
        let profile = Profile::builtin(&config.cell.laser_profile)
            .map_err(|e| anyhow::anyhow!("cell.laser_profile: {e}"))?;
        let any_sim = [&config.cell.cnc, &config.cell.galvo, &config.cell.laser]
            .iter()
            .any(|v| v.as_str() == SIM);
        let sim = if any_sim {
            let mut options = SimOptions::new(profile.clone());
            options.galvo_time_scale = args.sim_time_scale;
            options.cnc_time_scale = args.sim_time_scale;
            options.twin = twin.clone();
            Some(
                SimCell::start(options)
                    .await
                    .context("starting the simulated cell")?,
            )
        } else {
            None
        };
        let addresses = cell_addresses(config, sim.as_ref(), profile)?;
        let recorder = open_recorder(run_dir, resuming)?;
        if let (Some(rec), Some((inputs, registration))) = (&recorder, record) {
            record_inputs(rec, inputs, registration, job)?;
        }
        if let Some(rec) = &recorder {
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
        }
        let tap = recorder.as_ref().map_or_else(Tap::none, device_tap);
        let timeouts = Timeouts::default();
        let cell = Cell::connect(&addresses, &timeouts, tap)
            .await
            .map_err(|e| {
                Failure::with_exit(
                    Exit::DeviceFault,
                    anyhow::anyhow!("connecting the cell: {e}"),
                )
            })?;
        let cancel = CancellationToken::new();
        let on_ctrl_c = cancel.clone();
        tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                eprintln!("\ntrimctl run: interrupted: switching the laser off and stopping");
                on_ctrl_c.cancel();
            }
        });
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
        let bars = tokio::spawn(draw_progress(rx, job.clone()));
        let executor = Executor::new(
            job.clone(),
            cell,
            run_dir.join(files::JOURNAL),
            recorder.clone(),
        )
        .with_options(ExecOptions {
            timeouts,
            cut_layer: args.cut_layer.map(CutLayer::from),
            ..ExecOptions::default()
        });
        let result = if resuming {
            executor.resume(cancel, Some(tx)).await
        } else {
            executor.run(cancel, Some(tx)).await
        };
        let _ = bars.await;
        let spots = twin
            .as_ref()
            .map(|t| SpotReport::new(&t.spots(), &run_dir.join(files::JOURNAL), job, &line_ids))
            .filter(|r| r.overall.spots > 0);
        if let Some(rec) = recorder {
            if let Some(report) = &spots {
                rec.lock()
                    .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
                    .json(
                        "/twin/spot_error",
                        "trimctl.SpotError",
                        0,
                        &serde_json::to_value(report)?,
                    )?;
            }
            finish_recorder(rec)?;
        }
        if let Some(sim) = &sim {
            let violations = sim.monitor.violations();
            if !violations.is_empty() {
                bail!("safety monitor found interlock violations: {violations:?}");
            }
        }
        Ok((result, spots))
    })
}

fn cell_addresses(
    config: &JobConfig,
    sim: Option<&SimCell>,
    profile: Profile,
) -> anyhow::Result<CellAddresses> {
    let sim_addresses = sim.map(SimCell::addresses);
    let pick = |value: &str, key: &str| -> anyhow::Result<Option<std::net::SocketAddr>> {
        if value == SIM {
            Ok(None)
        } else {
            value
                .parse()
                .map(Some)
                .map_err(|_| anyhow::anyhow!("{key}: expected HOST:PORT, got {value:?}"))
        }
    };
    let from_sim = |what: &str| anyhow::anyhow!("{what} is \"sim\" but no simulator was started");
    let galvo = match pick(&config.cell.galvo, "cell.galvo")? {
        Some(a) => a,
        None => {
            sim_addresses
                .as_ref()
                .ok_or_else(|| from_sim("cell.galvo"))?
                .galvo
        }
    };
    let cnc = match pick(&config.cell.cnc, "cell.cnc")? {
        Some(a) => a,
        None => {
            sim_addresses
                .as_ref()
                .ok_or_else(|| from_sim("cell.cnc"))?
                .cnc
        }
    };
    let laser_path = if config.cell.laser == SIM {
        sim_addresses
            .as_ref()
            .ok_or_else(|| from_sim("cell.laser"))?
            .laser_path
            .clone()
    } else {
        PathBuf::from(&config.cell.laser)
    };
    Ok(CellAddresses {
        galvo,
        laser_path,
        laser_profile: profile,
        cnc,
    })
}

fn open_recorder(run_dir: &Path, resuming: bool) -> anyhow::Result<Option<SharedRecorder>> {
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

fn record_inputs(
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

fn finish_recorder(rec: SharedRecorder) -> anyhow::Result<()> {
    // Closing writes the summary and index; a device tap that still holds the recorder gets
    // its late messages refused rather than written after the end.
    rec.lock()
        .map_err(|_| anyhow::anyhow!("recorder lock poisoned"))?
        .finish()
        .context("closing the run record")
}

async fn draw_progress(mut rx: tokio::sync::mpsc::UnboundedReceiver<Progress>, job: Job) {
    let vectors_total: u64 = job
        .layers()
        .map(|(_, _, l)| {
            l.polylines
                .iter()
                .map(|p| p.points.len().saturating_sub(1) as u64)
                .sum::<u64>()
        })
        .sum();
    let layers_total = job.layers().count() as u64;
    let mut bars = JobProgress::new(job.zones.len() as u64, layers_total, vectors_total);
    let vectors_of = |key: trim_plan::LayerKey| -> u64 {
        job.layers()
            .find(|(k, _, _)| *k == key)
            .map_or(0, |(_, _, l)| {
                l.polylines
                    .iter()
                    .map(|p| p.points.len().saturating_sub(1) as u64)
                    .sum()
            })
    };
    let zone_index = |zone: usize| job.zones.iter().position(|z| z.id == zone).unwrap_or(0) as u64;
    let mut current_zone = None;
    while let Some(p) = rx.recv().await {
        match p {
            Progress::Phase { key, .. } if current_zone != Some(key.zone) => {
                current_zone = Some(key.zone);
                bars.zone_started(key.zone, zone_index(key.zone));
            }
            Progress::LayerDone { key, .. } => {
                bars.layer_done(key.zone, key.layer, vectors_of(key))
            }
            Progress::LayerSkipped { key } => bars.skip_layers(1, vectors_of(key)),
            _ => {}
        }
    }
    bars.finish();
}

#[expect(
    clippy::too_many_arguments,
    reason = "the report gathers every stage's result"
)]
fn write_report(
    run_dir: &Path,
    config: &JobConfig,
    description: &str,
    registration: &Registration,
    plan: &PlanOutput,
    timings: &Timings,
    run: Option<&RunSummary>,
    stopped: Option<&str>,
    spots: Option<&SpotReport>,
) -> anyhow::Result<()> {
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
            ("hatch", timings.hatch_s),
            ("plan", timings.plan_s),
            ("execute", timings.execute_s),
        ],
    );
    if let Some(s) = spots {
        report.push_str(&s.markdown());
    }
    std::fs::write(run_dir.join(files::REPORT), report)?;
    let json = serde_json::json!({
        "timings_s": timings,
        "run": run,
        "stopped": stopped,
        "validation": plan.job.validation,
        "estimate": plan.job.estimate,
        "cycle_s": run.map(summary::cycle_split),
        "spot_error": spots,
        "calibration": config.calibration,
        "lens": plan.job.settings.lens,
    });
    std::fs::write(
        run_dir.join(files::SUMMARY),
        serde_json::to_string_pretty(&json)?,
    )?;
    Ok(())
}
