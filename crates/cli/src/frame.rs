//! `trimctl frame`: red-light framing. For each zone (or the one `--zone` names), the CNC moves
//! to the layer's pose and the galvo traces the outline of the layer's commands (convex hull or
//! bounding box) with its pointer on, the process laser's emission off and the galvo's laser
//! signals disabled, so its gate cannot open (docs/protocols/galvo.md §5a). The trace repeats
//! until Enter (a terminal), or for `--passes N` / `--seconds S` (scripts, tests).
//!
//! Also the operator's zone gate of `trimctl run --frame` ([`OperatorGate`]): before each zone
//! the zone is framed and the operator answers on stdin.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::time::Duration;

use anyhow::{Context, bail};
use tokio::sync::mpsc::UnboundedReceiver;
use tokio_util::sync::CancellationToken;
use trim_cell::{Job, LayerKey};
use trim_io::cell_devices::{Cell, Timeouts};
use trim_io::executor::{StopCause, ZoneDecision, ZoneGate};
use trim_io::framing::{FrameSettings, Framed, frame_layer, rearm};
use trim_io::galvo::outline::OutlineKind;
use trim_io::tap::Tap;

use crate::config::JobConfig;
use crate::exit::{Exit, Failure};
use crate::run::{CellOverrides, DEFAULT_SIM_TIME_SCALE, files};
use crate::simulated::SimCell;

/// How long `run --frame` waits for an answer before it quits the run (s): the pointer is not
/// left tracing unattended.
pub const PROMPT_TIMEOUT_S: u64 = 600;

/// Arguments of `trimctl frame`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A planned Job (JSON, `trimctl plan`'s output) or a run folder (its plan.json and
    /// job.toml).
    #[arg(value_name = "JOB_OR_RUN")]
    target: PathBuf,
    /// Frame only this zone (its id). Without it: every zone, in job order.
    #[arg(long, value_name = "N")]
    zone: Option<usize>,
    /// With --zone: frame this layer (its index). Default: the zone's first (top) layer.
    #[arg(long, value_name = "M", requires = "zone")]
    layer: Option<usize>,
    /// The outline traced: the convex hull of the layer's galvo commands, or their bounding box.
    #[arg(long, value_enum, default_value = "hull")]
    outline: OutlineArg,
    /// Trace each layer this many times, then go on (no Enter needed).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    passes: Option<u32>,
    /// Trace each layer for this long (s), then go on (no Enter needed).
    #[arg(long, value_name = "S")]
    seconds: Option<f64>,
    /// For a Job JSON: the job file whose [cell] to use (default: the built-in simulated cell).
    #[arg(long, value_name = "JOB.toml")]
    config: Option<PathBuf>,
    #[command(flatten)]
    cell: CellOverrides,
    /// Write what was framed (outlines in bits; with the simulated cell, every traced vector
    /// and the light path's events) as JSON.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Simulated devices: real seconds per simulated second (1 = real time).
    #[arg(long, default_value_t = DEFAULT_SIM_TIME_SCALE)]
    sim_time_scale: f64,
}

/// `--outline`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutlineArg {
    /// The convex hull.
    Hull,
    /// The bounding box.
    Box,
}

impl From<OutlineArg> for OutlineKind {
    fn from(a: OutlineArg) -> OutlineKind {
        match a {
            OutlineArg::Hull => OutlineKind::Hull,
            OutlineArg::Box => OutlineKind::Box,
        }
    }
}

/// The job and the cell configuration of JOB_OR_RUN.
fn load(args: &Args) -> anyhow::Result<(Job, JobConfig)> {
    let (plan, config) = if args.target.is_dir() {
        let config = JobConfig::load(&args.target.join(files::JOB))
            .with_context(|| format!("{} is not a run folder", args.target.display()))?;
        (args.target.join(files::PLAN), config)
    } else {
        let config = match &args.config {
            Some(p) => JobConfig::load(p)?,
            None => JobConfig::default(),
        };
        (args.target.clone(), config)
    };
    let text = std::fs::read_to_string(&plan)
        .with_context(|| format!("cannot read {}", plan.display()))?;
    let job = Job::from_json(&text).with_context(|| plan.display().to_string())?;
    let mut config = config;
    args.cell.apply(&mut config);
    config
        .validate()
        .context("after applying --cnc/--galvo/--laser")?;
    Ok((job, config))
}

/// The layers to frame: `--zone`'s (its `--layer`, or its first), or every zone's first.
fn targets(job: &Job, args: &Args, plan: &Path) -> anyhow::Result<Vec<LayerKey>> {
    let zones: Vec<_> = match args.zone {
        Some(id) => vec![job.zones.iter().find(|z| z.id == id).with_context(|| {
            format!(
                "{}: no zone {id} (zones {:?})",
                plan.display(),
                job.zones.iter().map(|z| z.id).collect::<Vec<_>>()
            )
        })?],
        None => job.zones.iter().collect(),
    };
    let mut keys = Vec::new();
    for z in zones {
        let layer = match args.layer {
            Some(m) => m,
            None => {
                z.layers
                    .first()
                    .with_context(|| format!("{}: zone {} has no layer", plan.display(), z.id))?
                    .index
            }
        };
        keys.push(LayerKey { zone: z.id, layer });
    }
    Ok(keys)
}

/// The longest `--seconds` a layer is traced for: a day.
pub const MAX_TRACE_SECONDS: f64 = 86_400.0;

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.sim_time_scale.is_finite() && args.sim_time_scale > 0.0) {
        bail!(
            "--sim-time-scale: must be a number > 0, got {}",
            args.sim_time_scale
        );
    }
    if let Some(s) = args.seconds
        && !(s.is_finite() && s > 0.0 && s <= MAX_TRACE_SECONDS)
    {
        // 1e300 s panicked in the timer (a Duration holds about 5.8e11 years).
        bail!(
            "--seconds: must be a number > 0 and at most {MAX_TRACE_SECONDS} (a day), got {}",
            trim_geom::Num(s)
        );
    }
    let interactive = args.passes.is_none() && args.seconds.is_none();
    if interactive && !std::io::stdin().is_terminal() {
        bail!(
            "stdin is not a terminal, so nobody can press Enter to end a trace: give --passes N or --seconds S"
        );
    }
    let (job, config) = load(&args)?;
    let plan = if args.target.is_dir() {
        args.target.join(files::PLAN)
    } else {
        args.target.clone()
    };
    let keys = targets(&job, &args, &plan)?;
    // Every layer is checked before anything moves: its pose inside `[machine]`'s limits, ...
    trim_io::limits::check_poses(&job, &config.plan.machine, Some(&keys))
        .map_err(|e| anyhow::anyhow!("{}: {e}; refusing to move there", plan.display()))?;
    for key in &keys {
        trim_io::framing::find_layer(&job, *key)
            .map_err(|e| anyhow::anyhow!("{}: {e}", plan.display()))?;
        let (_, _, layer) = job
            .layers()
            .find(|(k, _, _)| k == key)
            .with_context(|| format!("zone {} has no layer {}", key.zone, key.layer))?;
        trim_io::galvo::outline::layer_outline(
            layer,
            &job.settings.plan.galvo,
            args.outline.into(),
        )
        .map_err(|e| {
            anyhow::anyhow!(
                "{}: zone {} layer {}: {e}",
                plan.display(),
                key.zone,
                key.layer
            )
        })?;
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(frame_all(&args, &job, &config, &keys, interactive))
}

async fn frame_all(
    args: &Args,
    job: &Job,
    config: &JobConfig,
    keys: &[LayerKey],
    interactive: bool,
) -> anyhow::Result<()> {
    let (sim, addresses) = crate::run::start_simulators(config, args.sim_time_scale, None).await?;
    let timeouts = Timeouts::default();
    let mut cell = crate::run::connect(&addresses, &timeouts, Tap::none()).await?;
    let cancel = CancellationToken::new();
    crate::stop_signal::StopSignals::install()?.cancel_on_first(
        cancel.clone(),
        "trimctl frame",
        "interrupted: pointer off, stopping",
    );
    let mut lines = interactive.then(stdin_lines);
    let settings = FrameSettings {
        timeouts,
        enable: args.cell.enable_steps(),
        ..FrameSettings::new(args.outline.into())
    };
    // A machine in E-stop, off or unhomed is refused before anything is switched on, unless
    // the operator allowed the step.
    let state = tokio::time::timeout(timeouts.cnc_reply * 3, cell.cnc.state())
        .await
        .map_err(|_| anyhow::anyhow!("the CNC did not report its state"))
        .and_then(|r| r.map_err(anyhow::Error::from))
        .and_then(|r| r.map_err(anyhow::Error::from))
        .map_err(|e| Failure::with_exit(Exit::DeviceFault, e))?;
    if let Some(refusal) = settings.enable.refusal(state) {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!("the CNC: {refusal}; nothing was switched on"),
        ));
    }
    let mut framed = Vec::new();
    for (i, key) in keys.iter().enumerate() {
        if interactive {
            eprintln!(
                "trimctl frame: tracing zone {} layer {} ({} of {}): Enter: {}, q Enter: stop",
                key.zone,
                key.layer,
                i + 1,
                keys.len(),
                if i + 1 < keys.len() {
                    "next zone"
                } else {
                    "done"
                }
            );
        }
        let hold = async {
            if let Some(lines) = lines.as_mut() {
                lines.recv().await
            } else if let Some(s) = args.seconds {
                tokio::time::sleep(Duration::from_secs_f64(s)).await;
                None
            } else {
                std::future::pending().await
            }
        };
        let passes = args.passes.unwrap_or(0);
        let (f, held) = frame_layer(&mut cell, job, *key, &settings, passes, hold, &cancel)
            .await
            .map_err(stop_failure)?;
        println!("{}", framed_line(&f, job));
        framed.push(f);
        if matches!(held, Some(Some(ref l)) if l.trim() == "q") {
            break;
        }
    }
    let sim_report = sim.as_ref().map(sim_report);
    if let Some(r) = &sim_report {
        println!("{}", r.line());
    }
    if let Some(path) = &args.report {
        let report = serde_json::json!({ "framed": framed, "sim": sim_report });
        trim_geom::fs::write_atomic(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(r) = &sim_report
        && !r.violations().is_empty()
    {
        bail!(
            "safety monitor found interlock violations: {:?}",
            r.violations()
        );
    }
    Ok(())
}

/// The exit code of a framing failure: interrupted 3, a device 2, the job 1.
fn stop_failure(stop: trim_io::framing::FramingStop) -> anyhow::Error {
    let exit = match stop.cause {
        _ if !stop.laser_off_ok => Exit::LaserStateUnknown,
        StopCause::Cancelled => Exit::Interrupted,
        StopCause::Job { .. } => Exit::Refused,
        _ => Exit::DeviceFault,
    };
    let state = if stop.laser_off_ok {
        "the pointer is off, the laser gate was kept shut"
    } else {
        "laser emission-off NOT acknowledged: switch the laser off at its key"
    };
    Failure::with_exit(
        exit,
        anyhow::anyhow!("framing stopped: {}; {state}", stop.cause),
    )
}

fn framed_line(f: &Framed, job: &Job) -> String {
    let [w, h] = f.outline.extent_mm(&job.settings.plan.galvo);
    format!(
        "zone {} layer {}: {} of {} points, {} vertices, {w:.2} × {h:.2} mm; {} passes ({} vectors) in {:.2} s, gate shut",
        f.key.zone,
        f.key.layer,
        f.outline.kind,
        f.outline.points,
        f.outline.vertices_bits.len(),
        f.passes_done,
        f.vectors_traced,
        f.traced_s
    )
}

/// What the simulated cell saw while framing.
#[cfg(feature = "sim")]
#[derive(Debug, serde::Serialize)]
struct SimReport {
    /// Every traced vector (bits), with the pointer, gate and emission during it.
    traces: Vec<trim_sim::galvo::TraceRecord>,
    /// Traced vectors with the pointer off.
    traced_without_pointer: usize,
    /// Vectors marked (with or without light): framing marks none.
    marked_vectors: usize,
    /// Times the galvo's gate opened.
    gate_opened: usize,
    /// Times the laser's emission went on.
    emission_on: usize,
    /// Times the pointer went on.
    pointer_on: usize,
    /// The pointer at the end.
    pointer_on_at_end: bool,
    /// Interlock violations.
    violations: Vec<String>,
}

#[cfg(feature = "sim")]
impl SimReport {
    fn violations(&self) -> &[String] {
        &self.violations
    }

    fn line(&self) -> String {
        format!(
            "simulator: {} vectors traced ({} without the pointer), pointer on {} times and off at the end: {}, gate opened {} times, emission on {} times, {} vectors marked, {} safety violations",
            self.traces.len(),
            self.traced_without_pointer,
            self.pointer_on,
            if self.pointer_on_at_end { "no" } else { "yes" },
            self.gate_opened,
            self.emission_on,
            self.marked_vectors,
            self.violations.len()
        )
    }
}

#[cfg(feature = "sim")]
fn sim_report(sim: &SimCell) -> SimReport {
    use trim_sim::safety::CellEvent;
    let events = sim.monitor.events();
    let count = |e: CellEvent| events.iter().filter(|(_, x)| *x == e).count();
    let traces = sim.galvo.traces();
    SimReport {
        traced_without_pointer: traces.iter().filter(|t| !t.pointer).count(),
        traces,
        marked_vectors: sim.galvo.marks().len(),
        gate_opened: count(CellEvent::Gate(true)),
        emission_on: count(CellEvent::Emission(true)),
        pointer_on: count(CellEvent::Pointer(true)),
        pointer_on_at_end: sim.monitor.pointer(),
        violations: sim
            .monitor
            .violations()
            .into_iter()
            .map(|v| v.what)
            .collect(),
    }
}

/// Nothing simulated to report in a build without the simulators.
#[cfg(not(feature = "sim"))]
#[derive(Debug, serde::Serialize)]
enum SimReport {}

#[cfg(not(feature = "sim"))]
impl SimReport {
    fn violations(&self) -> &[String] {
        match *self {}
    }

    fn line(&self) -> String {
        match *self {}
    }
}

#[cfg(not(feature = "sim"))]
fn sim_report(sim: &SimCell) -> SimReport {
    match *sim {}
}

/// Lines typed on stdin, read by a thread of their own (stdin cannot be read asynchronously);
/// the channel closes at end of input.
pub fn stdin_lines() -> UnboundedReceiver<String> {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    std::thread::spawn(move || {
        for line in std::io::stdin().lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// `run --frame`: before each zone, the zone's first layer to be marked is framed (the trace
/// runs until the answer) and the operator answers on stdin: Enter (or `m`) marks the zone, `r`
/// traces it again, `q` quits the run (the normal way down, resumable). End of input or no
/// answer within [`PROMPT_TIMEOUT_S`] quits too: nothing is marked unconfirmed.
pub struct OperatorGate {
    lines: UnboundedReceiver<String>,
    timeouts: Timeouts,
}

impl OperatorGate {
    /// Answers from stdin; the run's timeouts.
    #[must_use]
    pub fn new(timeouts: Timeouts) -> OperatorGate {
        OperatorGate {
            lines: stdin_lines(),
            timeouts,
        }
    }
}

type GateFuture<'a> =
    Pin<Box<dyn std::future::Future<Output = Result<ZoneDecision, StopCause>> + Send + 'a>>;

impl ZoneGate for OperatorGate {
    fn before_zone<'a>(
        &'a mut self,
        cell: &'a mut Cell,
        job: &'a Job,
        key: LayerKey,
        cancel: &'a CancellationToken,
    ) -> GateFuture<'a> {
        Box::pin(async move {
            let settings = FrameSettings {
                timeouts: self.timeouts,
                prepare: false,
                ..FrameSettings::new(OutlineKind::Hull)
            };
            loop {
                eprintln!(
                    "frame zone {} (layer {}): [Enter] mark, r reframe, q quit",
                    key.zone, key.layer
                );
                let lines = &mut self.lines;
                let hold =
                    tokio::time::timeout(Duration::from_secs(PROMPT_TIMEOUT_S), lines.recv());
                let (f, answer) = frame_layer(cell, job, key, &settings, 0, hold, cancel).await?;
                println!("framed {}", framed_line(&f, job));
                let line = match answer {
                    Some(Ok(Some(line))) => line,
                    Some(Ok(None)) => {
                        eprintln!(
                            "trimctl run: stdin closed: quitting before zone {}",
                            key.zone
                        );
                        return Ok(ZoneDecision::Quit);
                    }
                    Some(Err(_)) | None => {
                        eprintln!(
                            "trimctl run: no answer within {PROMPT_TIMEOUT_S} s: quitting before zone {}",
                            key.zone
                        );
                        return Ok(ZoneDecision::Quit);
                    }
                };
                match line.trim() {
                    "" | "m" => {
                        rearm(cell, &self.timeouts, cancel).await?;
                        return Ok(ZoneDecision::Mark);
                    }
                    "r" => {}
                    "q" => return Ok(ZoneDecision::Quit),
                    other => eprintln!("unknown answer {other:?}: tracing again"),
                }
            }
        })
    }
}
