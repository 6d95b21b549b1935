//! Runs a job to its end on a fresh simulated cell whose galvo carries a digital twin (galvo
//! instant, CNC 500× faster than real), for the twin tests.

use std::sync::Arc;

use tokio_util::sync::CancellationToken;
use trim_cell::job::Job;
use trim_io::executor::{ExecOptions, Executor};
use trim_io::tap::Tap;
use trim_sim::SimCell;
use trim_sim::twin::Twin;

use super::common::{connect, test_timeouts};

/// Runs `job` with `twin` in the galvo simulator; the safety monitor must see no violation.
pub async fn run_on_twin(job: Job, twin: &Arc<Twin>) {
    let mut o = trim_sim::SimOptions::new(
        trim_io::laser::Profile::builtin("monaco").expect("built-in laser profile"),
    );
    o.galvo_time_scale = 0.0;
    o.cnc_time_scale = 0.002;
    o.twin = Some(Arc::clone(twin));
    let sim = SimCell::start(o).await.expect("simulators");
    let dir = tempfile::tempdir().expect("temporary folder");
    Executor::new(
        job,
        connect(&sim, Tap::none()).await,
        dir.path().join("j"),
        None,
    )
    .with_options(ExecOptions {
        timeouts: test_timeouts(),
        ..ExecOptions::default()
    })
    .run(CancellationToken::new(), None)
    .await
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
}
