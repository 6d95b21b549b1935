//! `trimctl run`: the whole job from one command. Register, plan, show what will be done,
//! execute on the cell, and leave a complete run folder.
//!
//! With no job file it runs the built-in demo part (a synthetic ceramic core, see
//! `trim_synth`) against the built-in simulated cell.
//!
//! The command's parts: [`inputs`] loads the part (the demo's or the job's files), [`cell`]
//! connects the cell (simulators where the job says "sim", the digital twin) and executes,
//! [`record`] writes the MCAP record, [`report`] writes `report.md` and `summary.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use serde::Serialize;
use trim_cell::{Job, LayerKey};
use trim_geom::Path as TrimPath;
use trim_geom::formats;
use trim_geom::mesh::Mesh;
use trim_io::executor::{ExecError, RunSummary, StopCause};
use trim_io::journal::CutLayer;
use trim_io::live::{DEFAULT_LIVE_ADDR, LiveAddr, LiveServer};
use trim_plan::planner::{PlanOutput, plan_with_sides};
use trim_register::regional::{Registration, register};

use crate::config::JobConfig;
use crate::exit::{Exit, Failure};
use crate::progress::stage;
use crate::summary;

use execute::{TwinLink, execute, twin_link};
pub(crate) use execute::{connect, start_simulators};
use inputs::{DemoSpec, load_inputs};
use lock::RunLock;
pub(crate) use report::SpotReport;
use report::{
    BeamBlock, RunNotes, append_resume_report, shutdown_of, shutdown_sentence, write_report,
};

mod blocked;
mod detect;
mod execute;
mod inputs;
mod lock;
mod record;
mod report;
#[cfg(feature = "sim")]
mod rescan;
#[cfg(feature = "sim")]
mod twin_cuts;
#[cfg(feature = "sim")]
mod verify;
#[cfg(feature = "sim")]
mod verify_state;

#[cfg(feature = "sim")]
use twin_cuts::CutsLog;

/// No twin, so no landed cuts to keep, in a build without the simulators.
#[cfg(not(feature = "sim"))]
enum CutsLog {}

#[cfg(not(feature = "sim"))]
impl CutsLog {
    fn finish(self) -> anyhow::Result<()> {
        match self {}
    }
}

/// Files of a run folder.
pub mod files {
    /// The effective job file (what resume re-reads).
    pub const JOB: &str = "job.toml";
    /// The registered path.
    pub const REGISTERED: &str = "registered.csv";
    /// The registration quality report.
    pub const REGISTRATION: &str = "registration.json";
    /// The registration's picture: contours by predicted bound, the flagged ones marked.
    pub const REGISTRATION_SVG: &str = "registration.svg";
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
    /// The first scan's inspection under `[trim] only_detected`.
    pub const DETECT: &str = "detect";
    /// `--verify`'s rounds.
    pub const VERIFY: &str = "verify.json";
    /// What `--verify` needs to go on after a stop: `--rounds` and the demo part's spec.
    pub const VERIFY_STATE: &str = "verify_state.json";
    /// The digital twin's landed cuts of a `--verify` run's executions, in each run folder
    /// (the job's and every `retrim_<k>/`).
    #[cfg_attr(
        not(feature = "sim"),
        expect(dead_code, reason = "written by --verify, which needs the simulators")
    )]
    pub const TWIN_CUTS: &str = "twin_cuts.jsonl";
    /// The run folder's lock, held by the one process writing it; holds that process's id.
    pub const LOCK: &str = ".lock";
}

/// The most retrim rounds `--verify --rounds` allows.
pub const MAX_VERIFY_ROUNDS: u32 = 5;

/// The simulated cell's default speed: real seconds per simulated second. The demo runs the
/// galvo and the CNC 20× faster than real time so it ends in seconds, not minutes.
pub const DEFAULT_SIM_TIME_SCALE: f64 = 0.05;

/// `--cnc`, `--galvo` and `--laser` of `run` and `frame`: the cell's addresses from the command
/// line.
#[derive(clap::Args, Debug)]
pub struct CellOverrides {
    /// The CNC (LinuxCNC linuxcncrsh) as HOST:PORT, overriding `cell.cnc`.
    #[arg(long, value_name = "HOST:PORT")]
    cnc: Option<String>,
    /// The galvo controller as HOST:PORT, overriding `cell.galvo`.
    #[arg(long, value_name = "HOST:PORT")]
    galvo: Option<String>,
    /// The laser's serial device, overriding `cell.laser`.
    #[arg(long, value_name = "DEVICE")]
    laser: Option<String>,
    /// Allow trimctl to reset the CNC's E-stop and switch the machine on. Without it a machine
    /// in E-stop or switched off is refused (exit 1), naming its state.
    #[arg(long)]
    enable_machine: bool,
    /// Allow trimctl to home the CNC (the axes move). Without it an unhomed machine is refused
    /// (exit 1).
    #[arg(long)]
    home: bool,
}

impl CellOverrides {
    /// What preparing the CNC may do (`--enable-machine`, `--home`).
    pub fn enable_steps(&self) -> trim_io::cnc::EnableSteps {
        trim_io::cnc::EnableSteps {
            enable_machine: self.enable_machine,
            home: self.home,
        }
    }

    /// Puts the given addresses into `config.cell`.
    pub fn apply(&self, config: &mut JobConfig) {
        if let Some(c) = &self.cnc {
            config.cell.cnc.clone_from(c);
        }
        if let Some(g) = &self.galvo {
            config.cell.galvo.clone_from(g);
        }
        if let Some(l) = &self.laser {
            config.cell.laser.clone_from(l);
        }
    }
}

/// Arguments of `trimctl run`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The job file. Without one: the built-in demo part on the built-in simulated cell.
    #[arg(value_name = "JOB.toml")]
    job: Option<PathBuf>,
    /// The run folder (default: a new time-stamped folder under `output.runs_dir`).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Continue the interrupted run in RUN_DIR at its first unfinished layer. A run started with
    /// --verify is carried to the end: its job finished, then its verify loop from where it
    /// stopped (the unfinished retrim finished, the next inspection, further retrims), with
    /// the outputs and exit code of a run never stopped. RUN_DIR/retrim_<k> of such a run
    /// resumes the whole run (RUN_DIR).
    #[arg(long, value_name = "RUN_DIR", conflicts_with_all = ["job", "out", "verify"])]
    resume: Option<PathBuf>,
    /// With --resume: what to do with a layer cut at a point nobody can tell (the galvo lost
    /// its list to a restart, or trimctl was killed mid-layer): `redo` marks it again (the
    /// vectors it had marked are marked twice), `skip` leaves it out (the report lists it).
    /// The choice is journaled. Not used when the cut point is known.
    #[arg(long, value_enum, value_name = "redo|skip", requires = "resume")]
    cut_layer: Option<CutLayerArg>,
    #[command(flatten)]
    cell: CellOverrides,
    /// Start even if the plan fails validation (the violations are printed and recorded);
    /// never with an unreachable zone or a stretch of a contour marked twice.
    #[arg(long)]
    allow_invalid: bool,
    /// Plan without the contours registration flags untrustworthy (they are listed in the
    /// report) instead of refusing to start.
    #[arg(long)]
    skip_untrusted: bool,
    /// A timing file from `trimctl calibrate timing`: its [machine] move keys and [timing]
    /// replace the job file's (the estimate; the run folder's job.toml keeps them).
    #[arg(long, value_name = "timing.toml")]
    timing: Option<PathBuf>,
    /// Register and plan, write the run folder, execute nothing.
    #[arg(long)]
    dry_run: bool,
    /// Red-light framing before each zone: the zone's outline is traced with the galvo's
    /// pointer (the laser gate shut) and the run asks on stdin: Enter marks the zone, r traces
    /// it again, q quits (the normal stop; --resume continues there). Answers may be piped;
    /// end of input, or no answer within 10 minutes, quits.
    #[arg(long, conflicts_with = "dry_run")]
    frame: bool,
    /// After the job, rescan the part, inspect every contour (as `trimctl inspect`) and retrim
    /// what failed, up to --rounds times; a part that still fails ends the run with exit 1.
    /// The built-in demo part then carries burrs (30 % of its contours) and the digital twin
    /// trims and rescans it; a part of the job's own files is rescanned by job.toml's
    /// `[verify]` (a scan command, or a file waited for), at each pose of `[part] scans`.
    #[arg(long, conflicts_with = "dry_run")]
    verify: bool,
    /// With --verify: the most retrim rounds.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_VERIFY_ROUNDS)), requires = "verify")]
    rounds: u32,
    /// Fault injection on the simulated cell, to show that inspection catches an under-trimmed
    /// part: the digital twin's beam is blocked while layer ZONE:LAYER of the job (plan.json's
    /// zone id and layer index) marks. The galvo, the laser and the journal see the layer marked;
    /// nothing reaches the twin's part. Needs the simulated galvo with the twin (refused
    /// otherwise, before anything moves); the report and summary.json record it.
    #[arg(long, value_name = "ZONE:LAYER", value_parser = parse_layer_key, conflicts_with_all = ["dry_run", "resume"])]
    sim_block_beam: Option<LayerKey>,
    /// The demo part's seed.
    #[arg(long, default_value_t = 1)]
    demo_seed: u64,
    /// The share of the demo part's holes and slots (0-1) that carry a blockage, a film 50-200
    /// µm thick over part of the opening (the synthetic part's `--blockages`). With `[trim]
    /// only_detected` or --verify the inspection finds them and `[trim] hatch_blocked` hatches
    /// them. Ignored with a job naming its own part.
    #[arg(long, default_value_t = 0.0, value_parser = parse_share)]
    demo_blockages: f64,
    /// Simulated devices: real seconds per simulated second (1 = real time).
    #[arg(long, default_value_t = DEFAULT_SIM_TIME_SCALE)]
    sim_time_scale: f64,
    /// Serve the run live over the Foxglove WebSocket protocol while it runs: the record's
    /// channels, the static scene sent again to each viewer that subscribes late, the layer
    /// being marked highlighted. Open ws://HOST:PORT in Foxglove (Open connection → Foxglove
    /// WebSocket). A viewer never slows the run: a slow one loses its oldest messages.
    #[arg(
        long,
        value_name = "HOST:PORT",
        num_args = 0..=1,
        default_missing_value = DEFAULT_LIVE_ADDR,
        value_parser = parse_live_addr,
        conflicts_with = "dry_run"
    )]
    live: Option<LiveAddr>,
}

/// `--live`'s value, with a hint when a job file was taken for it.
fn parse_live_addr(s: &str) -> Result<LiveAddr, String> {
    s.parse::<LiveAddr>().map_err(|e| {
        if s.ends_with(".toml") {
            format!("{e} (give the job file before --live, or write --live=HOST:PORT)")
        } else {
            e.to_string()
        }
    })
}

/// A share in [0, 1].
fn parse_share(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("expected a number in [0, 1], got {s:?}"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("expected a number in [0, 1], got {v}"))
    }
}

/// `--sim-block-beam`'s value: ZONE:LAYER.
fn parse_layer_key(s: &str) -> Result<LayerKey, String> {
    let (zone, layer) = s
        .split_once(':')
        .ok_or_else(|| format!("expected ZONE:LAYER (e.g. 3:0), got {s:?}"))?;
    let number = |what: &str, v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("{what} in {s:?}: expected a whole number, got {v:?}"))
    };
    Ok(LayerKey {
        zone: number("ZONE", zone)?,
        layer: number("LAYER", layer)?,
    })
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
pub(super) struct Timings {
    load_s: f64,
    register_s: f64,
    detect_s: f64,
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
    // Listening starts first, so a taken port is refused before anything else is done.
    let live = match &args.live {
        Some(addr) => {
            let server = LiveServer::start(addr).map_err(|e| anyhow::anyhow!("--live: {e}"))?;
            eprintln!(
                "trimctl run: live view on {} (Foxglove: Open connection → Foxglove WebSocket)",
                server.url()
            );
            Some(server)
        }
        None => None,
    };
    match args.resume.clone() {
        Some(dir) => resume(&dir, &args, live.as_ref()),
        None => fresh(&args, live.as_ref()),
    }
}

fn apply_overrides(config: &mut JobConfig, args: &Args) -> anyhow::Result<()> {
    args.cell.apply(config);
    if let Some(file) = &args.timing {
        crate::calibrate_timing::TimingFile::load(file)?
            .apply(&mut config.plan.machine, &mut config.plan.timing);
    }
    config
        .validate()
        .context("after applying --cnc/--galvo/--laser")?;
    Ok(())
}

/// The fresh run's folder (`--out`, or a time-stamped one under `[output] runs_dir`), made
/// and locked for this process; refused when another process holds it or it already holds a
/// run.
fn new_run_dir(config: &JobConfig, args: &Args) -> anyhow::Result<(PathBuf, RunLock)> {
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let stamp = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
                .to_string()
                .replace(':', "-");
            config.output.runs_dir.join(stamp)
        }
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    // Locked before the journal is looked for: a run still writing the folder is named as
    // such, not as one to resume.
    let lock = RunLock::acquire(&dir)?;
    if dir.join(files::JOURNAL).exists() {
        bail!(
            "{} already holds a run (journal present): use --resume {} to continue it, or another --out",
            dir.display(),
            dir.display()
        );
    }
    Ok((dir, lock))
}

/// A fresh run: the pipeline's steps in order. Each step writes its output into the run
/// folder, prints its summary and times itself; a refusal returns before anything moves.
fn fresh(args: &Args, live: Option<&LiveServer>) -> anyhow::Result<()> {
    let mut timings = Timings::default();
    let t0 = Instant::now();
    // Held until the run ends: this process alone writes the folder and its retrims.
    let (config, run_dir, _lock) = open_run(args)?;
    let spinner = stage("loading the part");
    let demo = DemoSpec {
        seed: args.demo_seed,
        blockages: args.demo_blockages,
        burred: args.verify || config.plan.trim.only_detected,
    };
    let inputs = load_inputs(&config, &demo, &run_dir, true)?;
    drop(spinner);
    timings.load_s = t0.elapsed().as_secs_f64();
    println!("part: {}", inputs.description);
    // Detection and --verify measure against the CAD's surface: a job without a mesh is
    // refused before anything moves.
    let mesh = if config.plan.trim.only_detected || args.verify {
        Some(detect::cad_mesh(&config, &inputs).map_err(|e| Failure::with_exit(Exit::Refused, e))?)
    } else {
        None
    };
    let registration = register_part(&inputs, &config, &run_dir, &mut timings)?;
    let mut contours = trusted_contours(&registration, args, &run_dir)?
        .contours()
        .to_vec();
    let trusted: std::collections::BTreeSet<i64> =
        contours.iter().map(trim_geom::Contour::id).collect();
    let mut detection = if let Some(mesh) = mesh.as_ref().filter(|_| config.plan.trim.only_detected)
    {
        let mut d = detect::detect(
            &config,
            &inputs,
            mesh,
            &registration,
            &run_dir,
            &mut timings,
        )?;
        d.leave_out_untrusted(&contours.iter().map(trim_geom::Contour::id).collect());
        println!("{}", d.line());
        let keep = d.trimmed();
        contours.retain(|c| keep.contains(&c.id()));
        Some(d)
    } else {
        None
    };
    let blocked = match &mut detection {
        Some(d) => {
            let b = blocked::hatch_blocked(
                &d.inspected,
                &trim_inspect::InspectSettings::default(),
                &registration.path,
                &trusted,
                inputs.hatch.len(),
                &config,
                &run_dir,
            )?;
            d.blocked_hatched.clone_from(&b.openings);
            b
        }
        None => blocked::BlockedHatches::default(),
    };
    if let Some(line) = blocked.line() {
        println!("{line}");
    }
    let mut notes = RunNotes {
        detection: detection.as_ref(),
        beam_block: None,
    };
    if contours.is_empty() && inputs.hatch.is_empty() && blocked.tracks.is_empty() {
        return nothing_to_trim(&run_dir, &config, &inputs.description, &timings, &notes);
    }
    contours.extend(blocked.tracks.iter().cloned());
    let to_plan = with_hatch_tracks(contours, &inputs, &registration, &run_dir, &mut timings)?;
    let passes = detection.as_ref().map(|d| {
        let mut p = d.passes();
        p.extend(&blocked.passes);
        p
    });
    let plan = plan_part(
        &to_plan,
        &registration.path,
        passes.as_ref(),
        &config,
        &run_dir,
        &mut timings,
    )?;
    check_plan(&plan, args)?;
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
            &notes,
        )?;
        println!(
            "dry run: nothing executed; run folder {}",
            run_dir.display()
        );
        return Ok(());
    }

    let t = Instant::now();
    let record = Some((&inputs, &registration));
    let twin = twin_link(&config, &run_dir)?;
    notes.beam_block = args
        .sim_block_beam
        .map(|key| block_beam(&plan.job, key, &twin))
        .transpose()?;
    let cuts_log = if args.verify {
        start_verify(args, &run_dir, &inputs, &demo, &twin)?
    } else {
        None
    };
    let outcome = execute(
        &config, args, &run_dir, &plan.job, record, false, live, &twin,
    );
    let logged = cuts_log.map_or(Ok(()), CutsLog::finish);
    timings.execute_s = t.elapsed().as_secs_f64();
    if let Some(b) = &mut notes.beam_block {
        b.marks_blocked = crate::simulated::marks_blocked(twin.twin.as_ref());
        println!("{}", b.line());
    }
    finish(
        &run_dir,
        &config,
        &inputs.description,
        &registration,
        &plan,
        &timings,
        outcome,
        &notes,
    )?;
    logged?;
    if let Some(mesh) = mesh.as_ref().filter(|_| args.verify) {
        continue_verify(&config, args, &run_dir, &inputs, mesh, &registration)?;
    }
    Ok(())
}

/// No contour to trim and no region to hatch: nothing is planned and the machine is not
/// moved; report.md and summary.json say so.
fn nothing_to_trim(
    run_dir: &Path,
    config: &JobConfig,
    description: &str,
    timings: &Timings,
    notes: &RunNotes<'_>,
) -> anyhow::Result<()> {
    let why = if config.plan.trim.only_detected {
        "the first scan's inspection found no contour to trim ([trim] only_detected)"
    } else {
        "no contour is left to plan"
    };
    report::write_nothing_to_trim(run_dir, description, why, timings, notes)?;
    println!(
        "nothing to trim: {why}; nothing was planned and the machine was not moved; run folder {}",
        run_dir.display()
    );
    Ok(())
}

/// `--sim-block-beam`: blocks the twin's beam during `key`'s list (its place in the job's
/// execution order); refused, before anything moves, without the twin or for a layer the job
/// does not have.
fn block_beam(job: &Job, key: LayerKey, twin: &TwinLink) -> anyhow::Result<BeamBlock> {
    let Some(t) = &twin.twin else {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "--sim-block-beam: needs the digital twin in the simulated galvo (cell.galvo = \"sim\" with the demo part or [sim.truth] path); a real cell's beam is not blocked by trimctl"
            ),
        ));
    };
    let Some((i, (_, _, layer))) = job.layers().enumerate().find(|(_, (k, _, _))| *k == key) else {
        let keys: Vec<String> = job
            .layers()
            .map(|(k, _, _)| format!("{}:{}", k.zone, k.layer))
            .collect();
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "--sim-block-beam {}:{}: the plan has no such layer (its layers: {})",
                key.zone,
                key.layer,
                keys.join(", ")
            ),
        ));
    };
    let nth_list = u32::try_from(i + 1).context("--sim-block-beam: too many layers")?;
    crate::simulated::block_beam(t, nth_list);
    let contours: std::collections::BTreeSet<i64> =
        layer.polylines.iter().map(|p| p.contour).collect();
    let block = BeamBlock {
        layer: key,
        nth_list,
        contours: contours.into_iter().collect(),
        marks_blocked: 0,
    };
    eprintln!(
        "trimctl run: FAULT INJECTED (simulation): the twin's beam is blocked while {key} marks (contours {:?})",
        block.contours
    );
    Ok(block)
}

/// `--verify`, before the job's first layer: `verify_state.json` written (`--rounds`, the demo
/// part's spec) and, on the demo part, the twin's landed cuts kept in the run folder as they
/// land, so a stop anywhere can be continued (`--resume`). The demo part needs the twin
/// (the simulated galvo): refused, before anything moves, without it.
#[cfg(feature = "sim")]
fn start_verify(
    args: &Args,
    run_dir: &Path,
    inputs: &inputs::Inputs,
    demo: &DemoSpec,
    twin: &TwinLink,
) -> anyhow::Result<Option<CutsLog>> {
    if inputs.demo.is_some() && twin.twin.is_none() {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "--verify on the demo part: the galvo is not simulated (cell.galvo), so nothing tells what the laser removed; the digital twin in the simulated galvo trims and rescans the demo part"
            ),
        ));
    }
    verify_state::VerifyState {
        version: verify_state::VERIFY_STATE_VERSION,
        rounds: args.rounds,
        demo: inputs.demo.as_ref().map(|_| *demo),
    }
    .save(run_dir)?;
    if inputs.demo.is_some() {
        twin_cuts::attach(twin, run_dir)
    } else {
        Ok(None)
    }
}

/// Without the simulators there is no twin to rescan the part: refused before anything moves.
#[cfg(not(feature = "sim"))]
fn start_verify(
    _args: &Args,
    _run_dir: &Path,
    _inputs: &inputs::Inputs,
    _demo: &DemoSpec,
    _twin: &TwinLink,
) -> anyhow::Result<Option<CutsLog>> {
    Err(Failure::with_exit(
        Exit::Refused,
        anyhow::anyhow!(
            "--verify: this trimctl was built without the simulators (cargo feature `sim`)"
        ),
    ))
}

/// `--verify` after the job: the rounds of inspection and retrim from where `run_dir` says the
/// loop stands (`verify_state.json`, `verify.json`, the retrims' folders; none yet in a fresh
/// run), then report.md's section and summary.json's `verify` written over any earlier ones;
/// a part that still fails is exit 1.
#[cfg(feature = "sim")]
fn continue_verify(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    inputs: &inputs::Inputs,
    mesh: &Mesh,
    registration: &Registration,
) -> anyhow::Result<()> {
    let state = verify_state::VerifyState::load(run_dir)?.with_context(|| {
        format!(
            "{} is missing: the verify loop cannot go on",
            run_dir.join(files::VERIFY_STATE).display()
        )
    })?;
    // A stop signal from here on (a rescan, an inspection, a retrim) stops the loop: the waits,
    // the scan command and the inspection check the flag, and no retrim starts after it.
    let stop = execute::process_stop()?;
    let rounds = trim_geom::cancel::run_cancellable(stop.flag(), || {
        verify::verify(&verify::VerifyRun {
            config,
            args,
            run_dir,
            inputs,
            mesh,
            registration,
            state: &state,
        })
    })
    .map_err(|e| match stop.stopped_by() {
        // A stopped retrim already carries its exit code (3, or 4 when the laser's state is
        // unknown); anything else a stop cut short is an interruption.
        Some(signal) if e.downcast_ref::<Failure>().is_none() => Failure::with_exit(
            Exit::Interrupted,
            anyhow::anyhow!(
                "stopped by {signal}: {e:#}; nothing more was executed (resume with --resume {})",
                run_dir.display()
            ),
        ),
        _ => e,
    })?;
    write_verify_report(run_dir, &rounds)?;
    match rounds.last() {
        Some(last) if last.fail > 0 => Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "the part still fails inspection after {} retrim(s): contours {:?} (see {})",
                rounds.len() - 1,
                last.failing,
                run_dir
                    .join(format!("verify_{}", last.inspection))
                    .display()
            ),
        )),
        _ => {
            println!(
                "verified: every contour passes or is undecided; run folder {}",
                run_dir.display()
            );
            Ok(())
        }
    }
}

/// Without the simulators there is no twin to rescan the part.
#[cfg(not(feature = "sim"))]
fn continue_verify(
    _config: &JobConfig,
    _args: &Args,
    _run_dir: &Path,
    _inputs: &inputs::Inputs,
    _mesh: &Mesh,
    _registration: &Registration,
) -> anyhow::Result<()> {
    bail!("--verify: this trimctl was built without the simulators (cargo feature `sim`)")
}

/// The rounds in report.md ("Verify and retrim", replacing the section an earlier, stopped
/// attempt wrote) and in summary.json (`verify`, as verify.json has them).
#[cfg(feature = "sim")]
fn write_verify_report(run_dir: &Path, rounds: &[verify::Round]) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    let mut md = String::from(
        "\n## Verify and retrim\n\nEach inspection of the rescanned part (`verify_<k>/report.html`), and the digital twin's truth.\n\n| inspection | pass | fail | undecided | failing contours | true residual web P95 / max (µm) | true gouge P95 / max (µm) | true film cover max (%) | retrimmed | blocked openings hatched |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rounds {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:?} | {} | {} | {} | {} | {:?} |",
            r.inspection,
            r.pass,
            r.fail,
            r.undecided,
            r.failing,
            pair(r.true_residual_p95_um, r.true_residual_max_um),
            pair(r.true_gouge_p95_um, r.true_gouge_max_um),
            r.true_film_covered_max
                .map_or_else(|| "—".to_owned(), |f| format!("{:.0}", 100.0 * f)),
            if r.retrimmed { "yes" } else { "no" },
            r.hatched
        );
    }
    let report = run_dir.join(files::REPORT);
    let text = std::fs::read_to_string(&report).unwrap_or_default();
    trim_geom::fs::write_atomic(&report, with_section(&text, "## Verify and retrim", &md))
        .with_context(|| format!("cannot write {}", report.display()))?;
    let summary_path = run_dir.join(files::SUMMARY);
    let mut json: serde_json::Value = std::fs::read_to_string(&summary_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_else(|| serde_json::json!({}));
    json.as_object_mut()
        .context("summary.json is not a JSON object")?
        .insert("verify".to_owned(), serde_json::to_value(rounds)?);
    trim_geom::fs::write_atomic(&summary_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    Ok(())
}

/// `text` with its section under `heading` (a line of its own, up to the next `## ` heading
/// or the end) replaced by `section` (which begins with a blank line and `heading`), or with
/// `section` appended when it has none.
#[cfg_attr(
    all(not(feature = "sim"), not(test)),
    expect(dead_code, reason = "used by --verify, which needs the simulators")
)]
fn with_section(text: &str, heading: &str, section: &str) -> String {
    let marker = format!("\n{heading}\n");
    match text.find(&marker) {
        Some(start) => {
            let after = start + marker.len();
            let end = text[after..]
                .find("\n## ")
                .map_or(text.len(), |i| after + i);
            format!("{}{section}{}", &text[..start], &text[end..])
        }
        None => format!("{text}{section}"),
    }
}

/// `P95 / max` of the twin's truth, or a dash where there is none (a real part).
#[cfg(feature = "sim")]
fn pair(p95: Option<f64>, max: Option<f64>) -> String {
    match (p95, max) {
        (Some(p), Some(m)) => format!("{p:.1} / {m:.1}"),
        _ => "—".to_owned(),
    }
}

/// The job read (overrides applied) and the run folder made and locked (the lock is returned
/// to be held while the run writes), with the run's own copy of the field correction it uses
/// (the Job records its checksum), so the folder alone can be resumed and audited, and the
/// effective job file naming that copy relative to itself and the part's other files
/// absolutely.
fn open_run(args: &Args) -> anyhow::Result<(JobConfig, PathBuf, RunLock)> {
    let mut config = match &args.job {
        Some(p) => JobConfig::load(p)?,
        None => JobConfig::default(),
    };
    apply_overrides(&mut config, args)?;
    let (run_dir, lock) = new_run_dir(&config, args)?;
    if let Some(src) = config.plan.calibration.field_correction.clone() {
        let copy = run_dir.join(files::FIELD);
        std::fs::copy(&src, &copy).with_context(|| {
            format!(
                "calibration.field_correction: cannot copy {}",
                src.display()
            )
        })?;
        config.plan.calibration.field_correction = Some(copy);
    }
    let mut effective = config.clone();
    if effective.plan.calibration.field_correction.is_some() {
        effective.plan.calibration.field_correction = Some(PathBuf::from(files::FIELD));
    }
    // The files the job names are read relative to the job file, and the run folder's copy
    // lies elsewhere: it names them absolutely, so a resume finds them (a `--verify` run's
    // loop loads the part again, the twin reads `[sim.truth] path`).
    let part = &mut effective.part;
    for (key, file) in [
        ("part.cad", &mut part.cad),
        ("part.path", &mut part.path),
        ("part.scan", &mut part.scan),
        ("part.poses", &mut part.poses),
        ("sim.truth.path", &mut effective.sim.truth.path),
    ]
    .into_iter()
    .filter_map(|(key, file)| file.as_mut().map(|f| (key, f)))
    .chain(part.scans.iter_mut().map(|f| ("part.scans", f)))
    {
        *file = std::path::absolute(&*file)
            .with_context(|| format!("{key}: cannot make {} absolute", file.display()))?;
    }
    for (i, h) in effective.hatch.iter_mut().enumerate() {
        h.boundary = std::path::absolute(&h.boundary).with_context(|| {
            format!(
                "hatch[{i}].boundary: cannot make {} absolute",
                h.boundary.display()
            )
        })?;
    }
    trim_geom::fs::write_atomic(
        run_dir.join(files::JOB),
        toml::to_string(&effective).context("serialising the job file")?,
    )?;
    eprintln!("trimctl run: recording to {}", run_dir.display());
    Ok((config, run_dir, lock))
}

/// The registration of the run's inputs under its job, with a spinner saying `what`.
fn register_inputs(
    inputs: &inputs::Inputs,
    config: &JobConfig,
    what: &str,
) -> anyhow::Result<Registration> {
    let _spinner = stage(what);
    register(
        &inputs.cad,
        &inputs.scan,
        &inputs.path,
        &inputs.scan_from_cad_initial,
        &config.register,
    )
    .context("registration")
}

/// Registration of the path onto the scan, written and summarised; refuses a part the
/// registration refuses as a whole.
fn register_part(
    inputs: &inputs::Inputs,
    config: &JobConfig,
    run_dir: &Path,
    timings: &mut Timings,
) -> anyhow::Result<Registration> {
    let t = Instant::now();
    let registration = register_inputs(inputs, config, "registering the path onto the scan")?;
    timings.register_s = t.elapsed().as_secs_f64();
    formats::write_path(&run_dir.join(files::REGISTERED), &registration.path)?;
    trim_geom::fs::write_atomic(
        run_dir.join(files::REGISTRATION),
        serde_json::to_string_pretty(&registration.report)?,
    )?;
    crate::register::write_svg(
        &run_dir.join(files::REGISTRATION_SVG),
        &registration,
        &inputs.scan,
        config.register.quality.tolerance_um,
    )?;
    print!("{}", summary::registration(&registration.report));
    if let Some(reason) = &registration.report.global.refused {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "registration refuses the part: {reason} (see {} and the picture {}); --skip-untrusted does not override this",
                run_dir.join(files::REGISTRATION).display(),
                run_dir.join(files::REGISTRATION_SVG).display()
            ),
        ));
    }
    Ok(registration)
}

/// The registered path to plan: whole when every contour is trustworthy, without the
/// untrustworthy ones with `--skip-untrusted`, else refused.
fn trusted_contours(
    registration: &Registration,
    args: &Args,
    run_dir: &Path,
) -> anyhow::Result<TrimPath> {
    let untrusted: Vec<i64> = registration
        .report
        .contours
        .iter()
        .filter(|c| !c.trustworthy)
        .map(|c| c.id)
        .collect();
    if untrusted.is_empty() {
        return Ok(registration.path.clone());
    }
    let global = &registration.report.global;
    let doubt = match (
        &global.in_doubt,
        &global.edges_in_doubt,
        &global.region_in_doubt,
    ) {
        (Some(r), ..) => format!(" (the part is in doubt: {r})"),
        (None, Some(e), Some(r)) => {
            format!(" (edges in doubt: {e}; a stretch of the part in doubt: {r})")
        }
        (None, Some(e), None) => format!(" (edges in doubt: {e})"),
        (None, None, Some(r)) => format!(" (a stretch of the part in doubt: {r})"),
        (None, None, None) => String::new(),
    };
    if !args.skip_untrusted {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "registration flags {} contour(s) untrustworthy: {untrusted:?}{doubt} (see {}, and {} for where they are); refusing to start. Check the scan, or pass --skip-untrusted to trim the others",
                untrusted.len(),
                run_dir.join(files::REGISTRATION).display(),
                run_dir.join(files::REGISTRATION_SVG).display()
            ),
        ));
    }
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
    TrimPath::new(kept).context("no trustworthy contour left to plan")
}

/// The hatch regions' tracks, hatched on the registered scan, beside the contours.
fn with_hatch_tracks(
    contours: Vec<trim_geom::Contour>,
    inputs: &inputs::Inputs,
    registration: &Registration,
    run_dir: &Path,
    timings: &mut Timings,
) -> anyhow::Result<TrimPath> {
    if inputs.hatch.is_empty() {
        return Ok(TrimPath::new(contours)?);
    }
    let t = Instant::now();
    let spinner = stage("hatching regions on the registered scan");
    let regions = crate::hatch::hatch_regions(
        &inputs.hatch,
        &inputs.scan,
        &|p| registration.scan_from_cad_point(p),
        run_dir,
    )?;
    drop(spinner);
    timings.hatch_s = t.elapsed().as_secs_f64();
    let mut contours = contours;
    for r in regions {
        println!("{}", r.summary);
        contours.extend(r.tracks);
    }
    Ok(TrimPath::new(contours)?)
}

/// Zones and layers planned, written and summarised. Kerf compensation takes the material
/// sides from the whole `registered` path (an untrusted contour left out may be a hole's
/// outline). With `passes` (contour id → passes; contours not named, such as hatch tracks, 1),
/// each polyline gets its contour's count and the time estimate follows.
fn plan_part(
    to_plan: &TrimPath,
    registered: &TrimPath,
    passes: Option<&std::collections::BTreeMap<i64, u32>>,
    config: &JobConfig,
    run_dir: &Path,
    timings: &mut Timings,
) -> anyhow::Result<PlanOutput> {
    let t = Instant::now();
    let spinner = stage("planning zones and layers");
    let sides = config
        .plan
        .trim
        .kerf_compensation
        .then(|| trim_plan::kerf::material_sides(registered));
    let mut plan = plan_with_sides(to_plan, &config.plan, sides.as_ref()).context("planning")?;
    if let Some(passes) = passes {
        plan.job
            .set_passes(|id| passes.get(&id).copied().unwrap_or(1));
    }
    drop(spinner);
    timings.plan_s = t.elapsed().as_secs_f64();
    write_plan(run_dir, &plan)?;
    print!("{}", summary::plan(&plan));
    Ok(plan)
}

/// Refuses a plan that fails validation: always with an unreachable zone or a stretch of a
/// contour marked twice, otherwise unless `--allow-invalid` (then a warning).
fn check_plan(plan: &PlanOutput, args: &Args) -> anyhow::Result<()> {
    if plan.job.validation.passed {
        return Ok(());
    }
    let lines = plan.job.validation.violations.join("\n  ");
    // What no override starts.
    let (unreachable, twice) = (
        &plan.job.validation.unreachable_zones,
        &plan.job.validation.double_marked_contours,
    );
    let mut never = Vec::new();
    if !unreachable.is_empty() {
        never.push(format!(
            "zone(s) {unreachable:?} cannot be reached within the axis limits"
        ));
    }
    if !twice.is_empty() {
        never.push(format!(
            "contour(s) {twice:?} would be marked twice along a stretch (double ablation gouges the part)"
        ));
    }
    if !never.is_empty() {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "{}; refusing to start (--allow-invalid does not override this):\n  {lines}",
                never.join("; ")
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
    Ok(())
}

fn write_plan(run_dir: &Path, plan: &PlanOutput) -> anyhow::Result<()> {
    trim_geom::fs::write_atomic(run_dir.join(files::PLAN), plan.job.to_json()?)?;
    trim_geom::fs::write_atomic(
        run_dir.join(files::PLAN_SVG),
        trim_plan::svg::job_svg(&plan.job),
    )?;
    Ok(())
}

#[expect(
    clippy::too_many_arguments,
    reason = "the report gathers every stage's result"
)]
fn finish(
    run_dir: &Path,
    config: &JobConfig,
    description: &str,
    registration: &Registration,
    plan: &PlanOutput,
    timings: &Timings,
    outcome: anyhow::Result<Executed>,
    notes: &RunNotes<'_>,
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
        stopped.as_deref().map(|s| (s, shutdown_of(&outcome))),
        spots.as_ref(),
        notes,
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
/// (a device, or the journal's disk) 2; either of them with the laser's emission-off not
/// acknowledged 4 (its state is unknown); refused before anything was switched on 1. The
/// message says what the way down acknowledged and what it did not.
fn exec_failure(e: ExecError, run_dir: &Path) -> anyhow::Error {
    let exit = match &e {
        ExecError::Stopped(s) if !s.shutdown.laser_off_ok => Exit::LaserStateUnknown,
        ExecError::Stopped(s) if s.cause == StopCause::Cancelled => Exit::Interrupted,
        ExecError::Stopped(_) => Exit::DeviceFault,
        _ => Exit::Refused,
    };
    match e {
        ExecError::Stopped(ref s) => {
            let way_down = shutdown_sentence(&s.shutdown);
            Failure::with_exit(
                exit,
                anyhow::anyhow!(
                    "{e}; {way_down}; continue with: trimctl run --resume {}",
                    run_dir.display()
                ),
            )
        }
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

/// `--resume`: the job finished from its journal (no finished layer marked again), and a run
/// started with `--verify` carried to the end from where it stopped. `dir` may be a retrim's
/// folder of such a run: the whole run is resumed.
fn resume(dir: &Path, args: &Args, live: Option<&LiveServer>) -> anyhow::Result<()> {
    let run_dir = &resume_target(dir)?;
    let mut config = JobConfig::load(&run_dir.join(files::JOB))
        .with_context(|| format!("{} is not a run folder", run_dir.display()))?;
    // Held until the resume ends, before anything is read that a live writer could be
    // changing: a second process on the folder is refused at once.
    let _lock = RunLock::acquire(run_dir)?;
    apply_overrides(&mut config, args)?;
    let text = std::fs::read_to_string(run_dir.join(files::PLAN))
        .with_context(|| format!("cannot read {}", run_dir.join(files::PLAN).display()))?;
    let job = Job::from_json(&text)
        .with_context(|| format!("{}", run_dir.join(files::PLAN).display()))?;
    let journal = run_dir.join(files::JOURNAL);
    if !journal.exists() {
        bail!(
            "{}: no journal: the run never started executing; start a new run instead",
            run_dir.display()
        );
    }
    // The verify loop's state is read before anything moves: a corrupt one is refused.
    #[cfg(feature = "sim")]
    let state = verify_state::VerifyState::load(run_dir)?;
    #[cfg(not(feature = "sim"))]
    let state: Option<std::convert::Infallible> = if run_dir.join(files::VERIFY_STATE).exists() {
        bail!(
            "{}: a --verify run; continuing its verify loop needs the simulators (cargo feature `sim`), which this trimctl was built without",
            run_dir.display()
        );
    } else {
        None
    };
    match &state {
        None => refuse_verify_without_state(run_dir)?,
        #[cfg(feature = "sim")]
        Some(state) => verify::check_resumable(run_dir, state)?,
        #[cfg(not(feature = "sim"))]
        Some(never) => match *never {},
    }
    if state.is_none() && job_finished(&job, &journal)? {
        // Nothing is connected and the report is left as it was: resuming a finished run
        // appended a "Resume" section of 0 layers and negative-zero times to it.
        println!(
            "resume: every layer of the job in {} is finished (or left out by --cut-layer skip): \
             nothing to resume",
            run_dir.display()
        );
        if let Some(line) = summary::left_out_line(&trim_io::journal::read(&journal)?.left_out) {
            println!("{line}");
        }
        return Ok(());
    }
    if state.is_some() && job_finished(&job, &journal)? {
        println!(
            "resume: the job in {} is finished; its --verify loop goes on",
            run_dir.display()
        );
    } else {
        #[cfg(feature = "sim")]
        let keep_cuts = state.as_ref().is_some_and(|s| s.demo.is_some());
        #[cfg(not(feature = "sim"))]
        let keep_cuts = false;
        resume_job(&config, args, run_dir, &job, live, keep_cuts)?;
    }
    #[cfg(feature = "sim")]
    if let Some(state) = state {
        return resume_verify(&config, args, run_dir, &state);
    }
    Ok(())
}

/// The run folder `--resume DIR` continues: DIR, or for `RUN/retrim_<k>` of a `--verify` run
/// (RUN holds a journal), RUN, whose loop finishes the retrim and goes on. Refused, naming the
/// file, when such a RUN has no `verify_state.json`.
fn resume_target(dir: &Path) -> anyhow::Result<PathBuf> {
    let retrim = dir
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.strip_prefix("retrim_"))
        .and_then(|k| k.parse::<u32>().ok());
    let parent = match dir.parent() {
        Some(p) if p.as_os_str().is_empty() => Path::new("."),
        Some(p) => p,
        None => return Ok(dir.to_path_buf()),
    };
    let Some(k) = retrim.filter(|_| parent.join(files::JOURNAL).exists()) else {
        return Ok(dir.to_path_buf());
    };
    if !parent.join(files::VERIFY_STATE).exists() {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "{} is retrim {k} of the --verify run {}, but {} is missing (a run started by a trimctl that did not keep it, or the file was removed): its verify loop cannot be continued",
                dir.display(),
                parent.display(),
                parent.join(files::VERIFY_STATE).display()
            ),
        ));
    }
    eprintln!(
        "trimctl run: {} is retrim {k} of the --verify run {}: resuming that run (the retrim is finished, then its verify loop goes on)",
        dir.display(),
        parent.display()
    );
    Ok(parent.to_path_buf())
}

/// Refuses a run folder that holds `--verify` rounds but no `verify_state.json`: without it the
/// loop cannot go on, and resuming the job alone would leave the rounds unfinished silently.
fn refuse_verify_without_state(run_dir: &Path) -> anyhow::Result<()> {
    let round_folder = |name: &str| {
        ["verify_", "retrim_"].iter().any(|prefix| {
            name.strip_prefix(prefix)
                .is_some_and(|k| k.parse::<u32>().is_ok())
        })
    };
    let leftover = std::fs::read_dir(run_dir)
        .with_context(|| format!("cannot list {}", run_dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name == files::VERIFY || round_folder(name))
        .min();
    match leftover {
        Some(f) => Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "{} holds --verify rounds ({f}) but {} is missing (a run started by a trimctl that did not keep it, or the file was removed): its verify loop cannot be continued",
                run_dir.display(),
                run_dir.join(files::VERIFY_STATE).display()
            ),
        )),
        None => Ok(()),
    }
}

/// Whether the journal at `journal` has every layer of `job` finished or left out
/// (`--cut-layer skip`).
pub(super) fn job_finished(job: &Job, journal: &Path) -> anyhow::Result<bool> {
    let state = trim_io::journal::read(journal)?;
    Ok(job
        .layers()
        .all(|(key, _, _)| state.finished.contains(&key) || state.left_out.contains(&key)))
}

/// The job of `run_dir` resumed from its journal; with `keep_cuts` the twin's landed cuts are
/// added to the run folder's (`--verify` on the demo part). The resume is added to report.md
/// and summary.json; a stop is the run's failure.
fn resume_job(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    job: &Job,
    live: Option<&LiveServer>,
    keep_cuts: bool,
) -> anyhow::Result<()> {
    eprintln!("trimctl run: resuming {}", run_dir.display());
    let t = Instant::now();
    let twin = twin_link(config, run_dir)?;
    let log = if keep_cuts {
        attach_cuts(&twin, run_dir)?
    } else {
        None
    };
    let executed = execute(config, args, run_dir, job, None, true, live, &twin);
    let logged = log.map_or(Ok(()), CutsLog::finish);
    let (outcome, spots) = executed?;
    let wall_s = t.elapsed().as_secs_f64();
    if let Some(r) = &spots {
        print!("{}", r.line());
    }
    // A refusal before anything was switched on leaves the run folder as it was.
    if !matches!(outcome, Err(ExecError::ResumeUnknown { .. })) {
        append_resume_report(run_dir, job, &outcome, wall_s)?;
    }
    match outcome {
        Ok(run) => {
            print!("{}", summary::execution(&run, job));
            println!(
                "done: resumed run finished in {wall_s:.1} s; run folder {}",
                run_dir.display()
            );
            logged
        }
        Err(e) => Err(exec_failure(e, run_dir)),
    }
}

#[cfg(feature = "sim")]
use twin_cuts::attach as attach_cuts;

/// No twin to keep cuts of without the simulators.
#[cfg(not(feature = "sim"))]
fn attach_cuts(_twin: &TwinLink, _dir: &Path) -> anyhow::Result<Option<CutsLog>> {
    Ok(None)
}

/// The verify loop of a resumed `--verify` run: the part's inputs made again (the demo part
/// from its spec in `verify_state.json`, without writing its files again), its CAD mesh, the
/// run's registration redone and checked against `registered.csv`, then the loop from where it
/// stopped.
#[cfg(feature = "sim")]
fn resume_verify(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    state: &verify_state::VerifyState,
) -> anyhow::Result<()> {
    let state_file = run_dir.join(files::VERIFY_STATE);
    let demo = match (config.is_demo(), state.demo) {
        (true, Some(d)) => d,
        (false, None) => DemoSpec {
            seed: args.demo_seed,
            blockages: 0.0,
            burred: false,
        },
        (true, None) => bail!(
            "{}: demo is null, but {} names no part (the built-in demo part): the file does not belong to this run",
            state_file.display(),
            run_dir.join(files::JOB).display()
        ),
        (false, Some(_)) => bail!(
            "{}: holds the demo part's spec, but {} names its own part: the file does not belong to this run",
            state_file.display(),
            run_dir.join(files::JOB).display()
        ),
    };
    let spinner = stage("loading the part");
    let inputs = load_inputs(config, &demo, run_dir, false)?;
    drop(spinner);
    let mesh =
        detect::cad_mesh(config, &inputs).map_err(|e| Failure::with_exit(Exit::Refused, e))?;
    let registration = reregister(&inputs, config, run_dir)?;
    continue_verify(config, args, run_dir, &inputs, &mesh, &registration)
}

/// How far the registration redone on resume may lie from the run's own (`registered.csv`),
/// mm. The registration is deterministic (the same inputs give the same path to the last
/// bit); this leaves room for the text round trip only.
#[cfg(feature = "sim")]
const REREGISTER_TOLERANCE_MM: f64 = 1e-9;

/// The run's registration, redone on its inputs (no file written), refused unless its path is
/// the one in `registered.csv`: the rounds are inspected through the run's own fit (the part
/// has not moved), and a retrim already planned was planned on it.
#[cfg(feature = "sim")]
fn reregister(
    inputs: &inputs::Inputs,
    config: &JobConfig,
    run_dir: &Path,
) -> anyhow::Result<Registration> {
    let registration = register_inputs(inputs, config, "registering the path onto the scan again")?;
    let file = run_dir.join(files::REGISTERED);
    let stored =
        formats::read_path(&file).with_context(|| format!("cannot read {}", file.display()))?;
    let same_contours = stored.len() == registration.path.len()
        && stored
            .contours()
            .iter()
            .zip(registration.path.contours())
            .all(|(a, b)| a.id() == b.id() && a.points().len() == b.points().len());
    let off_mm = stored
        .contours()
        .iter()
        .zip(registration.path.contours())
        .flat_map(|(a, b)| a.points().iter().zip(b.points()))
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max);
    if !same_contours || off_mm > REREGISTER_TOLERANCE_MM {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "the registration redone to continue the verify loop differs from the run's own, {} ({}): the rounds must be inspected through the fit the run was planned on; was the part's input changed?",
                file.display(),
                if same_contours {
                    format!("a point {off_mm:.3e} mm off")
                } else {
                    "other contours or point counts".to_owned()
                }
            ),
        ));
    }
    Ok(registration)
}

/// What an execution gave: the executor's outcome and, with the digital twin, the spot
/// errors on the true part.
pub(super) type Executed = (Result<RunSummary, ExecError>, Option<SpotReport>);

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        run: Args,
    }

    /// A plan of one straight contour, its validation as given.
    fn plan_with(validation: impl FnOnce(&mut trim_cell::job::ValidationReport)) -> PlanOutput {
        let c = trim_geom::Contour::new(
            3,
            vec![
                trim_geom::Point3::origin(),
                trim_geom::Point3::new(1.0, 0.0, 0.0),
            ],
            trim_geom::Vector3::z(),
        )
        .expect("a contour");
        let path = TrimPath::new(vec![c]).expect("a path");
        let mut settings = trim_plan::PlanSettings::default();
        settings.trim.kerf_compensation = false;
        let mut plan = plan_with_sides(&path, &settings, None).expect("plans");
        validation(&mut plan.job.validation);
        plan
    }

    /// report.md's verify section is written over an earlier one (a resumed run writes it
    /// again), whatever follows it, and appended when there is none.
    #[test]
    fn the_verify_section_replaces_an_earlier_one() {
        let section = "\n## Verify and retrim\n\nnew\n";
        let fresh = with_section("# run\n", "## Verify and retrim", section);
        assert_eq!(fresh, "# run\n\n## Verify and retrim\n\nnew\n");
        assert_eq!(with_section(&fresh, "## Verify and retrim", section), fresh);
        let between = "# run\n\n## Verify and retrim\n\nold\n\n## Resume 1\n\nr\n";
        assert_eq!(
            with_section(between, "## Verify and retrim", section),
            "# run\n\n## Verify and retrim\n\nnew\n\n## Resume 1\n\nr\n"
        );
    }

    /// `--resume RUN/retrim_<k>` of a `--verify` run resumes RUN; without RUN's
    /// `verify_state.json` it is refused naming the file; any other folder is itself.
    #[test]
    fn a_retrim_folder_resumes_its_verify_run() {
        let tmp = tempfile::tempdir().expect("a temporary folder");
        let run = tmp.path().join("run");
        let retrim = run.join("retrim_2");
        std::fs::create_dir_all(&retrim).expect("folders");
        trim_geom::fs::write_atomic(run.join(files::JOURNAL), "").expect("a journal");
        let e = format!("{:#}", resume_target(&retrim).expect_err("no state"));
        assert!(
            e.contains("retrim 2") && e.contains(files::VERIFY_STATE),
            "{e}"
        );
        trim_geom::fs::write_atomic(run.join(files::VERIFY_STATE), "{}").expect("a state");
        assert_eq!(resume_target(&retrim).expect("the run"), run);
        assert_eq!(resume_target(&run).expect("itself"), run);
        let other = run.join("retrim_x");
        assert_eq!(resume_target(&other).expect("itself"), other);
        // A run with rounds but no state is refused too.
        std::fs::remove_file(run.join(files::VERIFY_STATE)).expect("removed");
        assert!(refuse_verify_without_state(&run).is_err());
        std::fs::remove_dir(&retrim).expect("removed");
        assert!(refuse_verify_without_state(&run).is_ok());
    }

    /// A stretch marked twice is refused with or without `--allow-invalid` (issue 24 point
    /// 12); another failed check only without it.
    #[test]
    fn a_contour_marked_twice_is_refused_even_with_allow_invalid() {
        let allow = Cli::parse_from(["run", "--allow-invalid"]).run;
        let strict = Cli::parse_from(["run"]).run;
        let twice = plan_with(|v| {
            v.passed = false;
            v.double_marked_contours = vec![3];
            v.violations = vec!["contour 3: 0.4–0.5 mm of its 1 mm marked twice".to_owned()];
        });
        for args in [&allow, &strict] {
            let e = check_plan(&twice, args).expect_err("refused");
            assert!(e.to_string().contains("marked twice"), "{e}");
            assert_eq!(
                e.downcast_ref::<Failure>().map(|f| f.exit),
                Some(Exit::Refused)
            );
        }
        let other = plan_with(|v| {
            v.passed = false;
            v.violations = vec!["zone 0 layer 0 contour 3 point 0: outside the field".to_owned()];
        });
        assert!(check_plan(&other, &allow).is_ok());
        assert!(check_plan(&other, &strict).is_err());
    }
}
