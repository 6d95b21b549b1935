//! The cell of a run: its addresses, the simulators started where the job says "sim" (with the
//! digital twin in the galvo simulator), the execution with its progress display.

use std::path::{Path, PathBuf};

use anyhow::Context;
use trim_cell::Job;
use trim_geom::Path as TrimPath;
use trim_geom::formats;
use trim_io::cell_devices::{Cell, CellAddresses, Timeouts};
use trim_io::executor::{ExecOptions, Executor, Progress};
use trim_io::galvo::list::vector_count;
use trim_io::journal::CutLayer;
use trim_io::laser::Profile;
use trim_io::live::LiveServer;
use trim_io::record::{SharedRecorder, device_tap};
use trim_io::tap::Tap;
use trim_register::regional::Registration;

use super::inputs::Inputs;
use super::record::{
    ProgressRecord, finish_recorder, open_recorder, record_calibration, record_inputs,
    record_spot_error,
};
use super::{Args, Executed, files};
use crate::config::{JobConfig, SIM};
use crate::exit::{Exit, Failure};
use crate::progress::JobProgress;
use crate::simulated::{self, SimCell, Twin};

/// Connects the cell (starting simulators where the config says "sim"), then runs or resumes,
/// recording (and with `live`, serving) the run.
/// The outer error: the cell could not be set up; the inner: the execution stopped.
#[expect(
    clippy::too_many_arguments,
    reason = "the run's parts, each a different thing; grouping them would only rename them"
)]
pub(super) fn execute(
    config: &JobConfig,
    args: &Args,
    run_dir: &Path,
    job: &Job,
    record: Option<(&Inputs, &Registration)>,
    resuming: bool,
    live: Option<&LiveServer>,
    twin: &TwinLink,
) -> anyhow::Result<Executed> {
    let (twin, line_ids) = (twin.twin.clone(), &twin.line_ids);
    refuse_after_stop(run_dir)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async {
        let (sim, addresses) = start_simulators(config, args.sim_time_scale, twin.clone()).await?;
        let recorder = open_recorder(run_dir, resuming, live)?;
        if let (Some(rec), Some((inputs, registration))) = (&recorder, record) {
            record_inputs(rec, inputs, registration, job)?;
        }
        if let Some(rec) = &recorder {
            let none = Vec::new();
            let scan_poses = record.map_or(&none, |(inputs, _)| &inputs.scan_poses);
            record_calibration(rec, config, job, scan_poses)?;
        }
        let tap = recorder.as_ref().map_or_else(Tap::none, device_tap);
        let timeouts = Timeouts::default();
        let mut cell = connect(&addresses, &timeouts, tap).await?;
        // Where the machine starts, for the timing record's first move.
        let start_pose = match cell.cnc.positions().await {
            Ok(Ok(p)) => Some(p.world),
            _ => None,
        };
        // The process's handlers, shared by every execution of this run (the job and each
        // retrim): a signal between two executions stops the run before the next one starts.
        let cancel = process_stop()?.token();
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
        let bars = tokio::spawn(draw_progress(rx, job.clone(), recorder.clone()));
        let executor = Executor::new(
            job.clone(),
            cell,
            run_dir.join(files::JOURNAL),
            recorder.clone(),
        )
        .with_options(ExecOptions {
            timeouts,
            cut_layer: args.cut_layer.map(CutLayer::from),
            machine: Some(config.plan.machine),
            enable: args.cell.enable_steps(),
            ..ExecOptions::default()
        });
        let executor = if args.frame {
            executor.with_zone_gate(Box::new(crate::frame::OperatorGate::new(timeouts)))
        } else {
            executor
        };
        let result = if resuming {
            executor.resume(cancel, Some(tx)).await
        } else {
            executor.run(cancel, Some(tx)).await
        };
        let _ = bars.await;
        if let Ok(run) = &result {
            let scale = |device: &str| {
                if device == SIM {
                    args.sim_time_scale
                } else {
                    1.0
                }
            };
            let clocks = crate::timing_record::Clocks {
                cnc: config.cell.cnc.clone(),
                cnc_time_scale: scale(&config.cell.cnc),
                galvo: config.cell.galvo.clone(),
                galvo_time_scale: scale(&config.cell.galvo),
            };
            let record = crate::timing_record::record(
                job,
                &config.plan.machine,
                &config.plan.timing,
                run,
                start_pose,
                &clocks,
            );
            crate::timing_record::write(run_dir, &record, resuming)?;
        }
        let spots =
            simulated::spot_report(twin.as_ref(), &run_dir.join(files::JOURNAL), job, line_ids);
        if let Some(rec) = recorder {
            if let Some(report) = &spots {
                record_spot_error(&rec, report)?;
            }
            finish_recorder(rec)?;
        }
        if let Some(sim) = &sim {
            simulated::check_interlocks(sim)?;
        }
        Ok((result, spots))
    })
}

/// The stop signals' handlers of `trimctl run`, installed once for the process
/// ([`crate::stop_signal::ProcessStop`]).
pub(super) fn process_stop() -> anyhow::Result<&'static crate::stop_signal::ProcessStop> {
    crate::stop_signal::ProcessStop::install(
        "trimctl run",
        "interrupted: switching the laser off and stopping",
    )
}

/// After a stop signal no execution starts (exit 3): the operator asked the run to stop, and a
/// retrim after a rescan is a new execution.
pub(super) fn refuse_after_stop(run_dir: &Path) -> anyhow::Result<()> {
    match crate::stop_signal::ProcessStop::installed().and_then(|s| s.stopped_by()) {
        Some(signal) => Err(Failure::with_exit(
            Exit::Interrupted,
            anyhow::anyhow!(
                "stopped by {signal}: the execution in {} was not started (nothing was switched on)",
                run_dir.display()
            ),
        )),
        None => Ok(()),
    }
}

/// The simulators for the devices the config calls "sim" (none when it names none), at
/// `time_scale`, the galvo simulator carrying `twin`; and every device's address.
pub(crate) async fn start_simulators(
    config: &JobConfig,
    time_scale: f64,
    twin: Option<std::sync::Arc<Twin>>,
) -> anyhow::Result<(Option<SimCell>, CellAddresses)> {
    let profile = Profile::builtin(&config.cell.laser_profile)
        .map_err(|e| anyhow::anyhow!("cell.laser_profile: {e}"))?;
    let any_sim = [&config.cell.cnc, &config.cell.galvo, &config.cell.laser]
        .iter()
        .any(|v| v.as_str() == SIM);
    let sim = if any_sim {
        Some(simulated::start(&profile, time_scale, twin).await?)
    } else {
        None
    };
    let addresses = cell_addresses(config, sim.as_ref(), profile)?;
    Ok((sim, addresses))
}

/// Connects the cell; a failure is a device fault (its exit code).
pub(crate) async fn connect(
    addresses: &CellAddresses,
    timeouts: &Timeouts,
    tap: Tap,
) -> anyhow::Result<Cell> {
    Cell::connect(addresses, timeouts, tap).await.map_err(|e| {
        Failure::with_exit(
            Exit::DeviceFault,
            anyhow::anyhow!("connecting the cell: {e}"),
        )
    })
}

fn cell_addresses(
    config: &JobConfig,
    sim: Option<&SimCell>,
    profile: Profile,
) -> anyhow::Result<CellAddresses> {
    let sim_addresses = sim.map(simulated::addresses);
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

/// The digital twin a run's galvo simulator carries (none on a real galvo or without a true
/// line), with the ids of the true line's contours.
pub(super) struct TwinLink {
    pub(super) twin: Option<std::sync::Arc<Twin>>,
    pub(super) line_ids: std::collections::HashSet<i64>,
}

/// The twin that lands the galvo simulator's vectors on the true part ([sim.truth]), the
/// demo's true line read from `run_dir`. Its spot error is measured against the line the plan
/// means to draw: the true line offset out of the material as `[trim]` offsets the registered
/// one (the landed line itself comes from the galvo commands, offset once, by the planner).
pub(super) fn twin_link(config: &JobConfig, run_dir: &Path) -> anyhow::Result<TwinLink> {
    let line = truth_line(config, run_dir)?
        .map(|l| trim_plan::kerf::intended_line(&l, config.plan.kerf_offset_mm()))
        .transpose()
        .context("sim.truth.path: the true line's kerf compensation")?;
    let (twin, line_ids) = simulated::twin(config, line);
    Ok(TwinLink { twin, line_ids })
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

/// Draws the progress bars and records `/progress`.
async fn draw_progress(
    mut rx: tokio::sync::mpsc::UnboundedReceiver<Progress>,
    job: Job,
    recorder: Option<SharedRecorder>,
) {
    let mut record = recorder.map(|r| ProgressRecord::new(r, &job));
    let vectors_total: u64 = job
        .layers()
        .map(|(_, _, l)| u64::from(vector_count(l)))
        .sum();
    let layers_total = job.layers().count() as u64;
    let mut bars = JobProgress::new(job.zones.len() as u64, layers_total, vectors_total);
    let vectors_of = |key: trim_cell::LayerKey| -> u64 {
        job.layers()
            .find(|(k, _, _)| *k == key)
            .map_or(0, |(_, _, l)| u64::from(vector_count(l)))
    };
    let zone_index = |zone: usize| job.zones.iter().position(|z| z.id == zone).unwrap_or(0) as u64;
    let mut current_zone = None;
    while let Some(p) = rx.recv().await {
        if let Some(r) = &mut record {
            r.on(&p);
        }
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
