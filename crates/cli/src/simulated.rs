//! The simulated cell as the CLI uses it: the simulators started where the job says "sim", the
//! digital twin in the galvo simulator and the spot error it measures (trim-sim, cargo feature
//! `sim`, on by default). A build without the feature has no simulators: a job that asks for
//! one is refused, naming the feature; the rest of the CLI is the same.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use trim_cell::Job;
use trim_geom::Path as TrimPath;
use trim_io::cell_devices::CellAddresses;
use trim_io::laser::Profile;

use crate::config::JobConfig;
use crate::run::SpotReport;

#[cfg(feature = "sim")]
pub(crate) use trim_sim::SimCell;
#[cfg(feature = "sim")]
pub(crate) use trim_sim::twin::Twin;

/// No simulated cell in a build without the simulators: none can be made.
#[cfg(not(feature = "sim"))]
pub(crate) enum SimCell {}

/// No digital twin in a build without the simulators: none can be made.
#[cfg(not(feature = "sim"))]
pub(crate) enum Twin {}

/// Why a build without the simulators refuses "sim".
#[cfg(not(feature = "sim"))]
const NOT_BUILT: &str = "this trimctl was built without the simulators (cargo feature `sim`)";

/// Starts the three simulators with the laser `profile`, at `time_scale`, the galvo simulator
/// carrying `twin`.
#[cfg(feature = "sim")]
pub(crate) async fn start(
    profile: &Profile,
    time_scale: f64,
    twin: Option<Arc<Twin>>,
) -> anyhow::Result<SimCell> {
    use anyhow::Context;
    let mut options = trim_sim::SimOptions::new(profile.clone());
    options.galvo_time_scale = time_scale;
    options.cnc_time_scale = time_scale;
    options.twin = twin;
    SimCell::start(options)
        .await
        .context("starting the simulated cell")
}

/// Refuses: there are no simulators to start.
#[cfg(not(feature = "sim"))]
pub(crate) async fn start(
    _profile: &Profile,
    _time_scale: f64,
    _twin: Option<Arc<Twin>>,
) -> anyhow::Result<SimCell> {
    anyhow::bail!("a device of [cell] is \"sim\", but {NOT_BUILT}")
}

/// The simulators' addresses.
pub(crate) fn addresses(sim: &SimCell) -> CellAddresses {
    #[cfg(feature = "sim")]
    return sim.addresses();
    #[cfg(not(feature = "sim"))]
    match *sim {}
}

/// Refuses a run in which the simulated cell's safety monitor saw an interlock broken.
pub(crate) fn check_interlocks(sim: &SimCell) -> anyhow::Result<()> {
    #[cfg(feature = "sim")]
    {
        let violations = sim.monitor.violations();
        if !violations.is_empty() {
            anyhow::bail!("safety monitor found interlock violations: {violations:?}");
        }
        Ok(())
    }
    #[cfg(not(feature = "sim"))]
    match *sim {}
}

/// The twin that lands the galvo simulator's vectors on the true part (`[sim.truth]`), when the
/// galvo is simulated and there is a true trimming line, with the ids of that line's contours.
#[cfg(feature = "sim")]
pub(crate) fn twin(
    config: &JobConfig,
    line: Option<TrimPath>,
) -> (Option<Arc<Twin>>, HashSet<i64>) {
    use trim_sim::twin::{TrueCell, TruePart};
    match line {
        Some(line) if config.cell.galvo == crate::config::SIM => (
            Some(Twin::new(
                TrueCell::new(&config.sim.truth, &config.plan),
                TruePart::new(&line),
            )),
            line.contours().iter().map(trim_geom::Contour::id).collect(),
        ),
        _ => (None, HashSet::new()),
    }
}

/// No twin without the simulators.
#[cfg(not(feature = "sim"))]
pub(crate) fn twin(
    _config: &JobConfig,
    _line: Option<TrimPath>,
) -> (Option<Arc<Twin>>, HashSet<i64>) {
    (None, HashSet::new())
}

/// `--sim-block-beam`: the twin lands nothing of the run's `nth_list`-th list
/// ([`trim_sim::twin::Twin::block_beam`]).
pub(crate) fn block_beam(twin: &Arc<Twin>, nth_list: u32) {
    #[cfg(feature = "sim")]
    twin.block_beam(nth_list);
    #[cfg(not(feature = "sim"))]
    {
        let _ = nth_list;
        match **twin {}
    }
}

/// The mark vectors the twin's blocked beam kept off the part (0 without a twin).
pub(crate) fn marks_blocked(twin: Option<&Arc<Twin>>) -> u64 {
    #[cfg(feature = "sim")]
    return twin.map_or(0, |t| t.marks_blocked());
    #[cfg(not(feature = "sim"))]
    twin.map_or(0, |t| match **t {})
}

/// The twin's spot errors of a run, if it landed any spot (the journal finds each spot's
/// layer).
pub(crate) fn spot_report(
    twin: Option<&Arc<Twin>>,
    journal: &Path,
    job: &Job,
    line_ids: &HashSet<i64>,
) -> Option<SpotReport> {
    #[cfg(feature = "sim")]
    return twin
        .map(|t| SpotReport::new(&t.spots(), journal, job, line_ids))
        .filter(|r| r.overall.spots > 0);
    #[cfg(not(feature = "sim"))]
    {
        let _ = (journal, job, line_ids);
        twin.map(|t| match **t {})
    }
}

/// The scanner's view of the work piece through the true cell (`[sim.truth]`) at a scan pose:
/// how the demo part's scan is made.
#[cfg(feature = "sim")]
pub(crate) fn true_scanner_from_workpiece(
    config: &JobConfig,
) -> anyhow::Result<nalgebra::Isometry3<f64>> {
    let truth_cell = trim_sim::twin::TrueCell::new(&config.sim.truth, &config.plan);
    Ok(truth_cell.scanner_from_workpiece(&config.part.scan_pose))
}

/// Refuses: the demo part is scanned by the digital twin's true scanner.
#[cfg(not(feature = "sim"))]
pub(crate) fn true_scanner_from_workpiece(
    _config: &JobConfig,
) -> anyhow::Result<nalgebra::Isometry3<f64>> {
    anyhow::bail!("the built-in demo part is scanned through the digital twin, but {NOT_BUILT}")
}
