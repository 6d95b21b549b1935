//! The executor end to end against the three simulators (galvo on loopback TCP, laser on a pty,
//! CNC speaking linuxcncrsh on loopback TCP): whole runs, cancel and resume, and the
//! fault-injection matrix.

mod common;

use std::time::{Duration, Instant};

use common::{
    assert_marked_exactly_once, connect, demo_job, sim_cell, sim_cell_scaled, test_timeouts,
};
use tokio_util::sync::CancellationToken;
use trim_cell::job::{Job, LayerKey};
use trim_io::executor::{ExecError, ExecOptions, Executor, OffPort, Phase, Progress, RunSummary};
use trim_io::journal;
use trim_io::record::{Recorder, device_tap};
use trim_io::tap::{Device, Tap};
use trim_sim::SimCell;
use trim_sim::fault::{Fault, FaultKind, Trigger};

/// The laser must be off (light path closed) within this of the fault's injection. The slowest
/// cases: a galvo that hangs mid-list (its own heartbeat watchdog, 400 ms, closes the gate) and a
/// laser that stops answering mid-list (the executor sees the reply timeout, 500 ms, and closes
/// the galvo gate).
const LASER_OFF_BOUND: Duration = Duration::from_millis(1500);
/// The matrix's galvo clock: real seconds per modelled second.
const MATRIX_GALVO_TIME_SCALE: f64 = 10.0;
/// Fault-matrix cases run at once.
const MATRIX_CONCURRENCY: usize = 4;
/// Modelled galvo time vs the timing model's estimate (relative): both use the same model, the
/// difference is bits rounding and ns rounding of delays.
const ESTIMATE_REL_TOLERANCE: f64 = 1e-3;

fn options() -> ExecOptions {
    ExecOptions {
        timeouts: test_timeouts(),
        laser_power_pct: Some(80.0),
        // One laser check per layer (right after EXECUTE), so fault triggers count exactly.
        laser_poll: Duration::from_secs(60),
        // One CNC check per layer (right after EXECUTE), so fault triggers count exactly.
        cnc_poll: Duration::from_secs(60),
        cut_layer: None,
        // The in-process simulated CNC stands ready: no step needs allowing.
        enable: trim_io::cnc::EnableSteps::default(),
        machine: None,
    }
}

async fn run_fresh(
    sim: &SimCell,
    job: &Job,
    journal: &std::path::Path,
    cancel: CancellationToken,
) -> Result<RunSummary, ExecError> {
    let cell = connect(sim, Tap::none()).await;
    Executor::new(job.clone(), cell, journal, None)
        .with_options(options())
        .run(cancel, None)
        .await
}

async fn resume(sim: &SimCell, job: &Job, journal: &std::path::Path) -> RunSummary {
    let cell = connect(sim, Tap::none()).await;
    Executor::new(job.clone(), cell, journal, None)
        .with_options(options())
        .resume(CancellationToken::new(), None)
        .await
        .unwrap_or_else(|e| panic!("resume failed: {e}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn whole_job_marks_every_vector_once_with_both_laser_profiles() {
    for profile in ["monaco", "ipg"] {
        let sim = sim_cell(profile).await;
        let job = demo_job(3);
        let dir = tempfile::tempdir().unwrap();
        let rec = Recorder::create(&dir.path().join("run.mcap"))
            .unwrap()
            .shared();
        let cell = connect(&sim, device_tap(&rec)).await;
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let summary = Executor::new(
            job.clone(),
            cell,
            dir.path().join("run.journal"),
            Some(rec.clone()),
        )
        .with_options(options())
        .run(CancellationToken::new(), Some(tx))
        .await
        .unwrap_or_else(|e| panic!("{profile}: {e}"));
        assert_eq!(summary.layers_marked, 6);
        assert_eq!(summary.vectors_marked, 30);
        assert_eq!(assert_marked_exactly_once(&job, &sim.galvo.marks()), 0);
        assert!(
            sim.monitor.violations().is_empty(),
            "{:?}",
            sim.monitor.violations()
        );
        assert!(!sim.laser.state().emission, "emission left on");
        assert!((sim.laser.state().power_pct - 80.0).abs() < 1e-9);
        let st = journal::read(&dir.path().join("run.journal")).unwrap();
        assert_eq!(st.finished.len(), 6);

        // Time: the simulator's modelled clock against the estimate from the polylines.
        let rel =
            (summary.galvo_modelled_s - summary.galvo_estimate_s).abs() / summary.galvo_estimate_s;
        assert!(
            rel < ESTIMATE_REL_TOLERANCE,
            "modelled {} s vs estimate {} s",
            summary.galvo_modelled_s,
            summary.galvo_estimate_s
        );
        let overhead: Vec<f64> = summary.layers.iter().map(|l| l.overhead_s * 1e3).collect();
        let mean = overhead.iter().sum::<f64>() / overhead.len() as f64;
        let max = overhead.iter().copied().fold(0.0, f64::max);
        let list_ratio: Vec<f64> = summary
            .layers
            .iter()
            .map(|l| l.list_s / l.modelled_s)
            .collect();
        eprintln!(
            "[{profile}] galvo modelled {:.6} s, estimate {:.6} s (rel {rel:.2e}); per-layer overhead mean {mean:.1} ms max {max:.1} ms; list wall/modelled {:?}; wall {:.2} s",
            summary.galvo_modelled_s,
            summary.galvo_estimate_s,
            list_ratio
                .iter()
                .map(|r| format!("{r:.2}"))
                .collect::<Vec<_>>(),
            summary.wall_s
        );

        // Progress events: every layer done in order, vectors counted up to the layer size.
        let mut events = Vec::new();
        while let Ok(e) = rx.try_recv() {
            events.push(e);
        }
        let done: Vec<usize> = events
            .iter()
            .filter_map(|e| match e {
                Progress::LayerDone { index, .. } => Some(*index),
                _ => None,
            })
            .collect();
        assert_eq!(done, vec![0, 1, 2, 3, 4, 5]);
        assert!(events.iter().any(|e| matches!(
            e,
            Progress::Vectors {
                done: 5,
                total: 5,
                ..
            }
        )));

        // The record holds every device's traffic.
        rec.lock().unwrap().finish().unwrap();
        let bytes = std::fs::read(dir.path().join("run.mcap")).unwrap();
        let mut topics = std::collections::BTreeMap::<String, usize>::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            *topics.entry(m.unwrap().channel.topic.clone()).or_default() += 1;
        }
        for t in [
            "/device/galvo",
            "/device/laser",
            "/device/cnc",
            "/layer",
            "/tf",
            "/log",
        ] {
            assert!(
                topics.get(t).copied().unwrap_or(0) > 0,
                "{profile}: no {t} in {topics:?}"
            );
        }
        assert_eq!(topics["/tf"], 2);
    }
}

/// Runs `job` on `sim` from scratch and cancels it once layer `target` has marked 2 vectors
/// (the galvo clock slow enough that the watcher sees it midway): the stop, and when the cancel
/// was given.
async fn cancel_after_two_vectors(
    sim: &SimCell,
    job: &Job,
    path: &std::path::Path,
    target: LayerKey,
) -> (trim_io::executor::Stopped, Instant) {
    let cancel = CancellationToken::new();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let c2 = cancel.clone();
    let watcher = tokio::spawn(async move {
        while let Some(p) = rx.recv().await {
            if let Progress::Vectors { key, done, .. } = p
                && key == target
                && done >= 2
            {
                c2.cancel();
                return Instant::now();
            }
        }
        panic!("never reached the target layer");
    });
    let cell = connect(sim, Tap::none()).await;
    let err = Executor::new(job.clone(), cell, path, None)
        .with_options(options())
        .run(cancel, Some(tx))
        .await
        .expect_err("cancelled");
    let cancelled_at = watcher.await.expect("the watcher ends");
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    (*s, cancelled_at)
}

/// A resume on the repaired cell continues the cut layer at `from` (layer, vectors done), each
/// vector of the job marked once, with no safety violation.
async fn resume_continues_the_layer(
    sim: &SimCell,
    job: &Job,
    path: &std::path::Path,
    from: (LayerKey, u32),
) {
    let summary = resume(sim, job, path).await;
    assert_eq!(summary.resumed_from, Some(from));
    let partial = assert_marked_exactly_once(job, &sim.galvo.marks());
    assert!(partial <= 1, "{partial} partly marked vectors");
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
}

/// A cut layer's count known only from the galvo (the journal's cut entry has none: the host
/// died mid-layer) is journaled as soon as a resume reads it, before anything is switched on:
/// framing replaces the galvo's list, so a stop before the layer began again (here a stop
/// right after the resume started) left the layer of unknown progress, redo or skip only.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cut_count_known_only_from_the_galvo_is_journaled_before_anything_else() {
    let sim = sim_cell_scaled("monaco", MATRIX_GALVO_TIME_SCALE).await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let target = LayerKey { zone: 1, layer: 0 };
    let (s, _) = cancel_after_two_vectors(&sim, &job, &path, target).await;
    let done = s
        .vectors_done
        .expect("the galvo says how far the layer got");
    // The host died before the cut entry: the journal ends at the layer's begin.
    let text = std::fs::read_to_string(&path).unwrap();
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| !l.contains("\"layer_cut\""))
        .collect();
    std::fs::write(&path, kept.join("\n") + "\n").unwrap();
    assert!(journal::read(&path).unwrap().open_cut.is_none());
    // A resume stopped before the layer begins again (the CNC refuses its first command): it
    // has journaled the galvo's count first.
    sim.clear_faults();
    sim.cnc.faults().arm(Fault {
        kind: FaultKind::Refuse,
        trigger: Trigger::Command {
            name: "mdi".into(),
            nth: 1,
        },
    });
    let cell = connect(&sim, Tap::none()).await;
    let first = Executor::new(job.clone(), cell, &path, None)
        .with_options(options())
        .resume(CancellationToken::new(), None)
        .await;
    assert!(
        matches!(first, Err(ExecError::Stopped(_))),
        "the resume was to stop at the CNC's refusal: {first:?}"
    );
    sim.clear_faults();
    let st = journal::read(&path).unwrap();
    assert!(
        matches!(st.open_cut, Some(journal::Entry::LayerCut { vectors_done: Some(v), .. }) if v == done),
        "{:?}",
        st.open_cut
    );
    // The galvo's list replaced (as framing does): the journal still knows, and the resume
    // continues the layer where it stopped, each vector marked once.
    sim.galvo.forget_list();
    resume_continues_the_layer(&sim, &job, &path, (target, done)).await;
}

/// A galvo link lost mid-list (the connection dropped): the way down opens a new session, so
/// its `LASER_SIGNALS off`, `STOP` and `STATUS` are still sent and answered, the cut count is
/// read from the galvo and journaled, and the resume continues the layer where it stopped.
/// Before, the link marked lost refused the way down's own requests and the cut was journaled
/// as of unknown progress.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_galvo_link_gets_a_new_session_on_the_way_down_and_the_cut_count_is_journaled() {
    let sim = sim_cell_scaled("monaco", MATRIX_GALVO_TIME_SCALE).await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let target = LayerKey { zone: 1, layer: 0 };
    sim.galvo.faults().arm(Fault {
        kind: FaultKind::DropLink,
        trigger: Trigger::AfterMarks {
            marks: 2,
            nth_list: 3,
        },
    });
    let err = run_fresh(&sim, &job, &path, CancellationToken::new())
        .await
        .expect_err("the link drops mid-list");
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    assert_eq!(s.key, Some(target), "{:?}", s.cause);
    let r = &s.shutdown;
    assert!(r.galvo_reopened, "{r:?}");
    assert!(r.galvo_signals_off_ok && r.galvo_stop_ok, "{r:?}");
    assert!(r.all_acknowledged(), "{r:?}");
    let done = s
        .vectors_done
        .expect("the new session's STATUS says how far the layer got");
    assert!((2..=3).contains(&done), "{done} vectors marked");
    assert!(!sim.monitor.light());
    let st = journal::read(&path).unwrap();
    assert!(
        matches!(st.open_cut, Some(journal::Entry::LayerCut { vectors_done: Some(v), .. }) if v == done),
        "{:?}",
        st.open_cut
    );
    sim.clear_faults();
    resume_continues_the_layer(&sim, &job, &path, (target, done)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_mid_layer_turns_the_laser_off_and_resume_finishes_without_remarking() {
    // A slow galvo clock (vectors of about 0.1 s) so the progress watcher sees the layer midway.
    let sim = sim_cell_scaled("monaco", MATRIX_GALVO_TIME_SCALE).await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let target = LayerKey { zone: 1, layer: 0 };
    let (s, cancelled_at) = cancel_after_two_vectors(&sim, &job, &path, target).await;
    assert_eq!(s.cause, trim_io::executor::StopCause::Cancelled);
    assert_eq!(s.key, Some(target));
    assert_eq!(s.phase, Phase::WaitDone);
    let done = s
        .vectors_done
        .expect("the galvo says how far the layer got");
    assert!((2..5).contains(&done), "{done}");
    let closed = sim
        .monitor
        .light_closed_since(cancelled_at)
        .expect("light off");
    eprintln!(
        "cancel: light off {:.1} ms after the cancel; serial+galvo laser-off commands {:.1} ms; cut after {done} of 5 vectors",
        (closed - cancelled_at).as_secs_f64() * 1e3,
        s.shutdown.laser_off_s * 1e3
    );
    assert!(closed - cancelled_at < LASER_OFF_BOUND);
    assert!(
        s.shutdown.laser_off_ok
            && s.shutdown.galvo_signals_off_ok
            && s.shutdown.galvo_stop_ok
            && s.shutdown.cnc_abort_ok,
        "{:?}",
        s.shutdown
    );
    let st = journal::read(&path).unwrap();
    assert_eq!(st.finished.len(), 2);
    assert!(
        matches!(st.open_cut, Some(journal::Entry::LayerCut { vectors_done: Some(v), .. }) if v == done)
    );

    let summary = resume(&sim, &job, &path).await;
    assert_eq!(summary.layers_skipped, 2);
    assert_eq!(summary.layers_marked, 2);
    assert_eq!(summary.resumed_from, Some((target, done)));
    let partial = assert_marked_exactly_once(&job, &sim.galvo.marks());
    assert!(partial <= 1, "{partial} partly marked vectors");
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
    assert_eq!(journal::read(&path).unwrap().finished.len(), 4);

    // A third run is refused (journal exists) and a resume of a finished run marks nothing.
    let again = run_fresh(&sim, &job, &path, CancellationToken::new()).await;
    assert!(matches!(
        again,
        Err(ExecError::Journal(journal::JournalError::Exists(_)))
    ));
    let before = sim.galvo.marks().len();
    let s = resume(&sim, &job, &path).await;
    assert_eq!((s.layers_marked, s.layers_skipped), (0, 4));
    assert_eq!(sim.galvo.marks().len(), before);
}

/// Whether the light path was open at an instant, from the monitor's event log.
fn light_on_at(sim: &SimCell, at: Instant) -> bool {
    let (mut emission, mut gate) = (false, false);
    for (t, e) in sim.monitor.events() {
        if t > at {
            break;
        }
        match e {
            trim_sim::safety::CellEvent::Emission(on) => emission = on,
            trim_sim::safety::CellEvent::Gate(on) => gate = on,
            _ => {}
        }
    }
    emission && gate
}

/// Where each device is hit in layer index 2 (zone 1, layer 0) of `demo_job(2)`: the trigger
/// and the phase the executor must stop in. Arrival counts include the preparation's commands.
fn matrix_cases() -> Vec<(Device, &'static str, Trigger, Phase)> {
    let cmd = |name: &str, nth: u32| Trigger::Command {
        name: name.into(),
        nth,
    };
    vec![
        // CNC: `set mdi M428` and its `set wait done` come first, in enable.
        (Device::Cnc, "move", cmd("mdi", 4), Phase::Move),
        (
            Device::Cnc,
            "wait in position",
            cmd("wait", 4),
            Phase::WaitInPosition,
        ),
        (
            Device::Galvo,
            "load list",
            cmd("LOAD_LIST", 3),
            Phase::LoadList,
        ),
        (Device::Galvo, "execute", cmd("EXECUTE", 3), Phase::Execute),
        (
            Device::Galvo,
            "mid-list",
            Trigger::AfterMarks {
                marks: 2,
                nth_list: 3,
            },
            Phase::WaitDone,
        ),
        (
            Device::Laser,
            "enable emission",
            cmd("emission_on", 3),
            Phase::EnableEmission,
        ),
        // The laser's fault check right after EXECUTE (preparation checks once).
        (
            Device::Laser,
            "fault check mid-list",
            cmd("faults", 4),
            Phase::WaitDone,
        ),
        // Preparation switches emission off once.
        (
            Device::Laser,
            "gate off",
            cmd("emission_off", 4),
            Phase::GateOff,
        ),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fault_matrix_laser_off_journal_intact_resume_marks_each_vector_once() {
    let target = LayerKey { zone: 1, layer: 0 };
    // The target layer starts with a 10-vector zig-zag (15 vectors in all): that one mark run
    // takes about 1.1 s at the matrix's galvo clock, longer than every detection delay, so a
    // fault mid-list meets the light on and the latency measured is that of the way down, not
    // of the list reaching a jump or its end.
    let mut job = demo_job(2);
    job.zones[1].layers[0].polylines.insert(
        0,
        trim_cell::job::Polyline::from_points(
            99,
            (0..=10)
                .map(|i| {
                    [
                        -10.0 + 2.0 * f64::from(i),
                        if i % 2 == 0 { -15.0 } else { -11.0 },
                    ]
                })
                .collect(),
        ),
    );
    // The cases run MATRIX_CONCURRENCY at a time, each against its own simulated cell: they
    // wait on device clocks and timeouts far more than they compute, and the bound on the laser's
    // way down is asserted for every case under that load. They share this thread (a LocalSet):
    // the executor's future is not Send (its zone gate).
    let job = std::rc::Rc::new(job);
    let slots = std::rc::Rc::new(tokio::sync::Semaphore::new(MATRIX_CONCURRENCY));
    let local = tokio::task::LocalSet::new();
    let mut table = local
        .run_until(async {
            let mut cases = tokio::task::JoinSet::new();
            for (device, where_, trigger, phase) in matrix_cases() {
                for kind in FaultKind::ALL {
                    let (job, slots, trigger) = (job.clone(), slots.clone(), trigger.clone());
                    cases.spawn_local(async move {
                        let _slot = slots.acquire().await.expect("semaphore open");
                        matrix_case(&job, target, device, where_, trigger, phase, kind).await
                    });
                }
            }
            let mut table = Vec::new();
            while let Some(row) = cases.join_next().await {
                match row {
                    Ok(row) => table.push(row),
                    Err(e) => std::panic::resume_unwind(e.into_panic()),
                }
            }
            table
        })
        .await;
    table.sort();
    eprintln!(
        "fault matrix ({} cases):\n{}",
        table.len(),
        table.join("\n")
    );
    assert_eq!(table.len(), 32);
}

/// One case of the fault matrix: `kind` injected into `device` at `trigger` while the job's
/// `target` layer runs. Asserts the way down, the journal and the resume; returns the table row.
async fn matrix_case(
    job: &Job,
    target: LayerKey,
    device: Device,
    where_: &str,
    trigger: Trigger,
    phase: Phase,
    kind: FaultKind,
) -> String {
    let label = format!("{device} {kind:?} at {where_}");
    eprintln!("case: {label}");
    // The galvo runs 10× slower than modelled.
    let sim = sim_cell_scaled("monaco", MATRIX_GALVO_TIME_SCALE).await;
    let fault = Fault { kind, trigger };
    match device {
        Device::Galvo => sim.galvo.faults().arm(fault),
        Device::Laser => sim.laser.faults().arm(fault),
        Device::Cnc => sim.cnc.faults().arm(fault),
    }
    let dir = tempfile::tempdir().expect("temporary folder");
    let path = dir.path().join("run.journal");
    let t_run = Instant::now();
    let err = run_fresh(&sim, job, &path, CancellationToken::new())
        .await
        .expect_err(&label);
    let ExecError::Stopped(s) = err else {
        panic!("{label}: {err}")
    };
    let fired = match device {
        Device::Galvo => sim.galvo.faults().fired(),
        Device::Laser => sim.laser.faults().fired(),
        Device::Cnc => sim.cnc.faults().fired(),
    };
    assert_eq!(fired.len(), 1, "{label}: the fault did not fire: {s:?}");
    let injected_at = fired[0].0;
    assert_eq!(s.key, Some(target), "{label}: {:?}", s.cause);
    assert_eq!(s.phase, phase, "{label}: {:?}", s.cause);
    let detected_at = s.detected_at.expect("detection time");

    // The laser is off (light path closed) within the bound of the injection.
    let light_at_injection = light_on_at(&sim, injected_at);
    let closed = sim
        .monitor
        .light_closed_since(injected_at)
        .unwrap_or_else(|| panic!("{label}: light still on"));
    let from_injection = closed.saturating_duration_since(injected_at);
    let from_detection = closed.saturating_duration_since(detected_at);
    assert!(
        from_injection < LASER_OFF_BOUND,
        "{label}: light off {from_injection:?} after the fault"
    );
    assert!(!sim.monitor.light(), "{label}");
    assert!(
        sim.monitor.violations().is_empty(),
        "{label}: {:?}",
        sim.monitor.violations()
    );
    // The laser's own emission is off, not only the light path closed; only a laser
    // that answers nothing (stalled, cable pulled) leaves it unknown, and the report
    // says so.
    let laser_unreachable =
        device == Device::Laser && matches!(kind, FaultKind::Stall | FaultKind::DropLink);
    assert_eq!(
        s.shutdown.laser_off_ok, !laser_unreachable,
        "{label}: {:?}",
        s.shutdown
    );
    if laser_unreachable {
        assert!(
            s.shutdown
                .failures
                .iter()
                .any(|f| f.step == trim_io::executor::ShutdownStep::EmissionOff),
            "{label}: {:?}",
            s.shutdown
        );
        assert!(s.shutdown.emission_off.len() >= 2, "{label}: no retry");
    } else {
        assert!(!sim.laser.state().emission, "{label}: emission left on");
    }

    // The journal is intact: every line parses, the two layers before are finished.
    let st = journal::read(&path).unwrap_or_else(|e| panic!("{label}: {e}"));
    assert!(!st.torn_tail, "{label}");
    assert_eq!(st.finished.len(), 2, "{label}");
    assert!(!st.finished.contains(&target), "{label}");

    // Resume on a repaired cell finishes the job, each vector marked once. A laser that
    // never acknowledged its emission-off got one more from the client's drop guard as
    // the run ended: the stalled simulator reads it (every 10 ms) before the repair, so
    // its reply does not reach the next client.
    if laser_unreachable {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    sim.clear_faults();
    let summary = resume(&sim, job, &path).await;
    assert_eq!(summary.layers_skipped, 2, "{label}");
    let partial = assert_marked_exactly_once(job, &sim.galvo.marks());
    assert!(partial <= 1, "{label}: {partial} partly marked vectors");
    assert!(
        sim.monitor.violations().is_empty(),
        "{label}: {:?}",
        sim.monitor.violations()
    );
    assert_eq!(
        journal::read(&path).expect("journal").finished.len(),
        4,
        "{label}"
    );
    format!(
        "{label:<40} detected {:>5.0} ms after injection; light off {:>6.1} ms after injection, {:>5.1} ms after detection; laser-off cmds {:>5.1} ms (serial ok {}, galvo ok {}); cut at {:?}/{}; partial {partial}; light on at injection {light_at_injection}; {:.2} s",
        detected_at
            .saturating_duration_since(injected_at)
            .as_secs_f64()
            * 1e3,
        from_injection.as_secs_f64() * 1e3,
        from_detection.as_secs_f64() * 1e3,
        s.shutdown.laser_off_s * 1e3,
        s.shutdown.laser_off_ok,
        s.shutdown.galvo_signals_off_ok,
        s.vectors_done,
        s.vectors,
        t_run.elapsed().as_secs_f64(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_monitor_catches_emission_during_motion_in_the_simulated_cell() {
    // Drive the devices in a wrong order by hand: the cell's monitor must see it.
    let sim = sim_cell("ipg").await;
    let mut cell = connect(&sim, Tap::none()).await;
    cell.cnc
        .enable(trim_io::cnc::EnableSteps::default())
        .await
        .unwrap()
        .unwrap();
    cell.laser.emission(true).await.unwrap().unwrap();
    let mut pose = trim_cell::job::Pose::default();
    pose.0.insert("x".into(), 20.0);
    cell.cnc.start_move(&pose).await.unwrap().unwrap();
    cell.cnc
        .wait_in_position(Duration::from_secs(5))
        .await
        .unwrap()
        .unwrap();
    let v = sim.monitor.violations();
    assert_eq!(v.len(), 1, "{v:?}");
    assert_eq!(v[0].what, "laser emission enabled while the CNC moves");
    cell.laser.emission(false).await.unwrap().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_planned_job_runs_and_the_simulated_galvo_time_matches_the_planners_estimate() {
    let path = trim_synth::testing::synthetic_core_path(12, 7);
    let mut job = trim_plan::planner::plan(&path, &trim_plan::planner::PlanSettings::default())
        .expect("plan");
    // Every third contour marked three times: the estimate follows the passes (and the
    // simulator's clock below checks it).
    let once = job.estimate.clone();
    job.set_passes(|c| if c % 3 == 0 { 3 } else { 1 });
    assert!(
        job.estimate.marking_s > once.marking_s * 1.2,
        "{:?} vs {once:?}",
        job.estimate
    );
    assert!(
        (job.estimate.total_s
            - job.estimate.per_zone_s.iter().sum::<f64>()
            - (once.total_s - once.per_zone_s.iter().sum::<f64>()))
        .abs()
            < 1e-9
    );
    let layers = job.layers().count();
    // Fast clocks: the galvo as fast as it can, the CNC 100× faster than real.
    let mut o = trim_sim::SimOptions::new(trim_io::laser::Profile::builtin("monaco").unwrap());
    o.galvo_time_scale = 0.0;
    o.cnc_time_scale = 0.01;
    let sim = SimCell::start(o).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let t = Instant::now();
    let summary = Executor::new(
        job.clone(),
        connect(&sim, Tap::none()).await,
        dir.path().join("j"),
        None,
    )
    .with_options(options())
    .run(CancellationToken::new(), None)
    .await
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(summary.layers_marked, layers);
    assert_eq!(assert_marked_exactly_once(&job, &sim.galvo.marks()), 0);
    assert!(sim.monitor.violations().is_empty());
    // The planner's estimate (its own implementation of the timing model) against the
    // simulator's clock, which runs on the list in bits.
    let planned_s = job.estimate.marking_s + job.estimate.jumping_s;
    let rel = (summary.galvo_modelled_s - planned_s).abs() / planned_s;
    let overhead: Vec<f64> = summary.layers.iter().map(|l| l.overhead_s * 1e3).collect();
    let mean = overhead.iter().sum::<f64>() / overhead.len() as f64;
    eprintln!(
        "planned job: {} zones, {layers} layers, {} vectors; galvo simulated {:.6} s vs planner estimate {planned_s:.6} s (rel {rel:.2e}); per-layer overhead mean {mean:.1} ms max {:.1} ms; wall {:.2} s",
        job.zones.len(),
        summary.vectors_marked,
        summary.galvo_modelled_s,
        overhead.iter().copied().fold(0.0, f64::max),
        t.elapsed().as_secs_f64()
    );
    assert!(
        rel < ESTIMATE_REL_TOLERANCE,
        "simulated {} s vs planned {planned_s} s",
        summary.galvo_modelled_s
    );
}

/// A journal on a disk that fills up: lines from the `fail_from`-th (0-based) on fail with
/// ENOSPC; the time of the first failure is kept.
struct FullDisk {
    inner: Box<dyn journal::JournalSink>,
    lines: usize,
    fail_from: usize,
    failed_at: std::sync::Arc<std::sync::Mutex<Option<Instant>>>,
}

impl journal::JournalSink for FullDisk {
    fn append_line(&mut self, line: &[u8]) -> std::io::Result<()> {
        let i = self.lines;
        self.lines += 1;
        if i >= self.fail_from {
            self.failed_at
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .get_or_insert_with(Instant::now);
            return Err(std::io::Error::from_raw_os_error(28)); // ENOSPC
        }
        self.inner.append_line(line)
    }
}

/// Position of the first tapped command after `after` that satisfies `pred`.
fn first_command(
    log: &[(Instant, trim_io::tap::DeviceIo)],
    after: Instant,
    pred: impl Fn(&trim_io::tap::DeviceIo) -> bool,
) -> usize {
    log.iter()
        .position(|(t, io)| {
            *t >= after && io.direction == trim_io::tap::Direction::Command && pred(io)
        })
        .unwrap_or_else(|| panic!("no such command after the failure: {log:#?}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_journal_write_failure_mid_run_takes_the_way_down_laser_first() {
    // Journal lines of `demo_job(2)` after the start line (written before the sink is
    // wrapped): 0–1 layer index 0, 2–3 layer index 1, then layer index 2 (zone 1 layer 0): 4 its
    // layer_begin (the CNC is at its pose, laser signals on), 5 its layer_done (its 5 vectors
    // marked, the galvo's laser signals still on).
    let target = LayerKey { zone: 1, layer: 0 };
    for (fail_from, phase, done) in [(5, Phase::Journal, Some(5)), (4, Phase::LoadList, None)] {
        let label = format!("journal full from line {fail_from}");
        let sim = sim_cell("monaco").await;
        let job = demo_job(2);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let log = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let log2 = log.clone();
        let tap = Tap::new(move |io| log2.lock().unwrap().push((Instant::now(), io)));
        let failed_at = std::sync::Arc::new(std::sync::Mutex::new(None));
        let failed2 = failed_at.clone();
        let err = Executor::new(job.clone(), connect(&sim, tap).await, &path, None)
            .with_options(options())
            .with_journal_sink(move |inner| {
                Box::new(FullDisk {
                    inner,
                    lines: 0,
                    fail_from,
                    failed_at: failed2,
                })
            })
            .run(CancellationToken::new(), None)
            .await
            .expect_err(&label);
        let ExecError::Stopped(s) = err else {
            panic!("{label}: not stopped through the way down: {err}")
        };
        assert!(
            matches!(&s.cause, trim_io::executor::StopCause::Journal { message } if message.contains("os error 28")),
            "{label}: {:?}",
            s.cause
        );
        // The layer it stopped in is reported with how far it got (the galvo's count).
        assert_eq!(
            (s.key, s.phase, s.vectors_done, s.vectors),
            (Some(target), phase, done, 5),
            "{label}"
        );
        assert_eq!(s.layers_finished, 2, "{label}");
        assert!(
            s.shutdown.laser_off_ok
                && s.shutdown.galvo_signals_off_ok
                && s.shutdown.galvo_stop_ok
                && s.shutdown.cnc_abort_ok,
            "{label}: {:?}",
            s.shutdown
        );
        // The way down in order: laser off (serial and galvo signals), then galvo stop, then
        // motion stop; nothing else was sent to a device in between.
        let failed = failed_at.lock().unwrap().expect("the sink failed");
        let log = log.lock().unwrap().clone();
        let laser_off = first_command(&log, failed, |io| io.device == Device::Laser);
        let signals_off = first_command(&log, failed, |io| {
            io.device == Device::Galvo && io.text.starts_with("LaserSignals { enable: false }")
        });
        let galvo_stop = first_command(&log, failed, |io| {
            io.device == Device::Galvo && io.text.starts_with("Stop")
        });
        let cnc = first_command(&log, failed, |io| io.device == Device::Cnc);
        assert_eq!(log[laser_off].1.text, "L=0", "{label}");
        assert!(
            laser_off.max(signals_off) < galvo_stop && galvo_stop < cnc,
            "{label}: laser off #{laser_off}, signals off #{signals_off}, galvo stop #{galvo_stop}, CNC #{cnc}"
        );
        assert!(!sim.laser.state().emission, "{label}: emission left on");
        assert!(!sim.monitor.light(), "{label}");
        assert!(
            sim.monitor.violations().is_empty(),
            "{label}: {:?}",
            sim.monitor.violations()
        );
        // The journal holds what was written before the disk filled up.
        let st = journal::read(&path).unwrap();
        assert_eq!(st.entries.len(), 1 + fail_from, "{label}");
        assert_eq!(st.finished.len(), 2, "{label}");

        // With room on the disk again, resume finishes; nothing is marked twice (the galvo
        // still reports the target layer's list when its layer_done was lost).
        let summary = resume(&sim, &job, &path).await;
        assert_eq!(summary.layers_skipped, 2, "{label}");
        if fail_from == 5 {
            assert_eq!(summary.resumed_from, Some((target, 5)), "{label}");
        }
        assert_eq!(
            assert_marked_exactly_once(&job, &sim.galvo.marks()),
            0,
            "{label}"
        );
        assert_eq!(journal::read(&path).unwrap().finished.len(), 4, "{label}");
    }
}

/// Per-layer overhead with the next list preloaded while the CNC moves (cycle-time issue part
/// 3). A layer's overhead is its wall time minus the CNC's motion (the move command to "in
/// position"; the `LOAD_LIST` runs meanwhile) minus the galvo's list (`EXECUTE` sent to done
/// seen): emission on, `EXECUTE`, emission off, the journal's write and fsync and the record. Of
/// that, the laser's replies to emission on and off (on the pty) and the journal's write + fsync
/// (the disk) are the devices' own time; the rest (progress events, bookkeeping, scheduling) is
/// the host's. Bounds, each the median over the layers (so one scheduling hiccup on a shared
/// machine does not decide): the host's share ≤ 1 ms per layer, and the whole overhead, the
/// devices' time included, ≤ 10 ms per layer (measured 1.37–1.54 ms on the demo with the
/// simulators, the laser on a pty and the journal on a local disk; 10 ms leaves room for a slow
/// fsync on a loaded machine and still catches a layer end that waits on something it should
/// not); and every load is hidden behind its move.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn preloading_hides_the_list_load_and_the_host_share_of_the_overhead_is_at_most_1_ms() {
    const HOST_OVERHEAD_BOUND_S: f64 = 1e-3;
    const WHOLE_OVERHEAD_BOUND_S: f64 = 10e-3;
    let sim = sim_cell("monaco").await;
    let job = demo_job(10);
    let dir = tempfile::tempdir().unwrap();
    let summary = run_fresh(
        &sim,
        &job,
        &dir.path().join("run.journal"),
        CancellationToken::new(),
    )
    .await
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(summary.layers_marked, 20);
    assert_eq!(assert_marked_exactly_once(&job, &sim.galvo.marks()), 0);
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let ms = |f: &dyn Fn(&trim_io::executor::LayerTiming) -> f64| {
        summary
            .layers
            .iter()
            .map(|l| f(l) * 1e3)
            .collect::<Vec<_>>()
    };
    let overhead = ms(&|l| l.overhead_s);
    let host = ms(&|l| l.overhead_s - l.device_replies_s - l.journal_s);
    let fsync = ms(&|l| l.journal_s);
    let to_execute = ms(&|l| l.to_execute_s);
    let after_done = ms(&|l| l.after_done_s);
    let load = ms(&|l| l.load_s);
    let motion = ms(&|l| l.motion_s);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    eprintln!(
        "preloading: per layer (ms, mean / median / max): whole overhead {:.3} / {:.3} / {:.3}; host share {:.3} / {:.3} / {:.3}; in position → EXECUTE acked {:.3} / {:.3}; done → journaled {:.3} / {:.3} (of it the journal write + fsync {:.3} / {:.3}); load {:.3} (hidden in motion {:.1})",
        mean(&overhead),
        median(overhead.clone()),
        overhead.iter().copied().fold(0.0, f64::max),
        mean(&host),
        median(host.clone()),
        host.iter().copied().fold(0.0, f64::max),
        mean(&to_execute),
        median(to_execute.clone()),
        mean(&after_done),
        median(after_done.clone()),
        mean(&fsync),
        median(fsync.clone()),
        mean(&load),
        mean(&motion),
    );
    for l in &summary.layers {
        assert!(
            l.load_s < l.motion_s,
            "{}: load {} s not hidden behind the move {} s",
            l.key,
            l.load_s,
            l.motion_s
        );
    }
    let host_median_s = median(host) * 1e-3;
    assert!(
        host_median_s <= HOST_OVERHEAD_BOUND_S,
        "host share of the overhead {host_median_s} s per layer (median)"
    );
    let whole_median_s = median(overhead) * 1e-3;
    assert!(
        whole_median_s <= WHOLE_OVERHEAD_BOUND_S,
        "whole overhead {whole_median_s} s per layer (median), devices' time included"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_with_an_unreachable_zone_is_refused_before_anything_moves_or_emits() {
    let sim = sim_cell("monaco").await;
    let mut job = demo_job(2);
    job.zones[1].unreachable = Some("A would be 180°, outside -100..50".to_owned());
    let dir = tempfile::tempdir().unwrap();
    let e = run_fresh(
        &sim,
        &job,
        &dir.path().join("run.journal"),
        CancellationToken::new(),
    )
    .await
    .expect_err("an unreachable zone must be refused");
    assert!(matches!(e, ExecError::Job(_)), "{e}");
    assert!(e.to_string().contains("zone 1"), "{e}");
    assert!(sim.galvo.marks().is_empty(), "marked before refusing");
    assert!(
        !sim.monitor
            .events()
            .iter()
            .any(|(_, e)| matches!(e, trim_sim::safety::CellEvent::Emission(true))),
        "emission switched on before refusing"
    );
}

/// A job whose galvo speed is 0 or not finite (a hand-edited job file, or another tool's) is
/// refused before anything moves or emits, naming the key: its lists' modelled time would be
/// infinite, and the wait for a list's end (its deadline taken while the laser emits) with it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_with_a_galvo_speed_of_zero_is_refused_before_anything_moves_or_emits() {
    for (key, set) in [
        (
            "galvo.mark_speed_mm_per_s",
            (|g: &mut trim_cell::job::GalvoSettings| g.mark_speed_mm_per_s = 0.0)
                as fn(&mut trim_cell::job::GalvoSettings),
        ),
        ("galvo.jump_speed_mm_per_s", |g| {
            g.jump_speed_mm_per_s = f64::NAN;
        }),
    ] {
        let sim = sim_cell("monaco").await;
        let mut job = demo_job(2);
        set(&mut job.settings.plan.galvo);
        let dir = tempfile::tempdir().unwrap();
        let e = run_fresh(
            &sim,
            &job,
            &dir.path().join("run.journal"),
            CancellationToken::new(),
        )
        .await
        .expect_err("a speed of zero must be refused");
        assert!(matches!(e, ExecError::Job(_)), "{key}: {e}");
        assert!(e.to_string().contains(key), "{key}: {e}");
        assert_eq!(sim.cnc.moves(), 0, "{key}: moved before refusing");
        assert!(
            sim.galvo.marks().is_empty(),
            "{key}: marked before refusing"
        );
        assert!(
            !sim.monitor
                .events()
                .iter()
                .any(|(_, e)| matches!(e, trim_sim::safety::CellEvent::Emission(true))),
            "{key}: emission switched on before refusing"
        );
    }
}

/// A hand-edited job with a pose outside `[machine]`'s limits (a layer of zone 1 moved to
/// X = 250 mm, past the X travel of ±200 mm; or C made non-finite) is refused before anything
/// moves or emits, naming the layer and the axis; with the limits unknown (`machine: None`) it
/// would be sent to the CNC.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pose_outside_the_machine_limits_is_refused_before_anything_moves() {
    let machine = trim_cell::kinematics::MachineSettings::default();
    // The untouched job passes the check.
    trim_io::limits::check_poses(&demo_job(2), &machine, None).expect("demo poses inside");
    for (axis, value, names) in [
        ("x", 250.0, "X = 250.000 mm"),
        ("c", f64::NAN, "axis c = NaN"),
    ] {
        let sim = sim_cell("monaco").await;
        let mut job = demo_job(2);
        job.zones[1].layers[1].pose.0.insert(axis.into(), value);
        let dir = tempfile::tempdir().unwrap();
        let cell = connect(&sim, Tap::none()).await;
        let e = Executor::new(job.clone(), cell, dir.path().join("run.journal"), None)
            .with_options(ExecOptions {
                machine: Some(machine),
                ..options()
            })
            .run(CancellationToken::new(), None)
            .await
            .expect_err("a pose outside the limits must be refused");
        assert!(matches!(e, ExecError::Job(_)), "{e}");
        let text = e.to_string();
        assert!(
            text.contains("zone 1 layer 1") && text.contains(names),
            "{text}"
        );
        assert_eq!(sim.cnc.moves(), 0, "{axis}: moved before refusing");
        assert!(
            sim.galvo.marks().is_empty(),
            "{axis}: marked before refusing"
        );
        assert!(
            !dir.path().join("run.journal").exists(),
            "{axis}: a journal was started"
        );
        assert!(
            !sim.monitor
                .events()
                .iter()
                .any(|(_, e)| matches!(e, trim_sim::safety::CellEvent::Emission(true))),
            "{axis}: emission switched on before refusing"
        );
    }
}

/// A laser that misses one reply mid-list and then answers again: the stop path still sends the
/// emission-off (the link is marked broken for ordinary commands, not for the way down), and
/// when that emission-off is lost too, it reopens the port and sends it again. The laser's
/// emission is off at the end in both cases.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missed_laser_reply_does_not_disable_the_emission_off() {
    let drop_one = |name: &str, nth: u32| Fault {
        kind: FaultKind::DropOne,
        trigger: Trigger::Command {
            name: name.into(),
            nth,
        },
    };
    // The fault check right after layer 0's EXECUTE is the 2nd `faults` query (preparation
    // checks once); the way down's emission-off is the 2nd `emission_off` (preparation's first).
    for (label, lost_offs, want_ports) in [
        ("status reply lost", 0, vec![OffPort::Open]),
        (
            "status reply and the first emission-off lost",
            1,
            vec![OffPort::Open, OffPort::Reopened],
        ),
    ] {
        let sim = sim_cell_scaled("monaco", 20.0).await;
        sim.laser.faults().arm(drop_one("faults", 2));
        for i in 0..lost_offs {
            sim.laser.faults().arm(drop_one("emission_off", 2 + i));
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let err = run_fresh(&sim, &demo_job(2), &path, CancellationToken::new())
            .await
            .expect_err(label);
        let ExecError::Stopped(s) = err else {
            panic!("{label}: {err}")
        };
        assert_eq!(s.phase, Phase::WaitDone, "{label}: {:?}", s.cause);
        assert!(
            matches!(&s.cause, trim_io::executor::StopCause::Link { device: Device::Laser, message } if message.contains("no reply")),
            "{label}: {:?}",
            s.cause
        );
        assert!(s.shutdown.laser_off_ok, "{label}: {:?}", s.shutdown);
        let ports: Vec<OffPort> = s.shutdown.emission_off.iter().map(|a| a.port).collect();
        assert_eq!(ports, want_ports, "{label}: {:?}", s.shutdown.emission_off);
        assert!(
            s.shutdown.emission_off.last().unwrap().error.is_none(),
            "{label}"
        );
        assert!(!sim.laser.state().emission, "{label}: emission left on");
        assert!(!sim.monitor.light(), "{label}");
        assert!(
            sim.monitor.violations().is_empty(),
            "{label}: {:?}",
            sim.monitor.violations()
        );
        assert_eq!(
            sim.laser.faults().armed(),
            vec![],
            "{label}: a fault did not fire"
        );
    }
}

/// The laser's pty vanishes mid-list (a USB adapter pulled): the stop names the I/O error,
/// the way down tries the emission-off on the old port and on reopening it until the budget is
/// spent, and reports it NOT acknowledged; the galvo's laser signals close the light path.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_vanished_laser_port_is_named_and_the_emission_off_reported_unacknowledged() {
    let mut sim = sim_cell_scaled("monaco", 20.0).await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let cell = connect(&sim, Tap::none()).await;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let run = Executor::new(job.clone(), cell, path.clone(), None)
        .with_options(options())
        .run(CancellationToken::new(), Some(tx));
    let laser = &mut sim.laser;
    let unplug = async {
        // Layer 0's list runs and its one laser check (right after EXECUTE) is answered: the
        // laser's next command is the emission-off after the list.
        while let Some(p) = rx.recv().await {
            if matches!(p, Progress::Vectors { key, .. } if key == LayerKey { zone: 0, layer: 0 }) {
                break;
            }
        }
        let emitting = laser.state().emission;
        laser.vanish();
        emitting
    };
    let (result, emitting) = tokio::join!(run, unplug);
    assert!(emitting, "layer 0 marks with emission on");
    let err = result.expect_err("the laser vanished");
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    assert_eq!(s.phase, Phase::GateOff, "{:?}", s.cause);
    assert!(
        matches!(&s.cause, trim_io::executor::StopCause::Link { device: Device::Laser, message } if message.contains("os error 5")),
        "the I/O error is not named: {:?}",
        s.cause
    );
    assert!(!s.shutdown.laser_off_ok, "{:?}", s.shutdown);
    let failure = s
        .shutdown
        .failures
        .iter()
        .find(|f| f.step == trim_io::executor::ShutdownStep::EmissionOff)
        .unwrap_or_else(|| panic!("no emission-off failure: {:?}", s.shutdown));
    assert!(!failure.error.is_empty());
    let attempts = &s.shutdown.emission_off;
    assert!(attempts.len() >= 2, "{attempts:?}");
    assert_eq!(attempts[0].port, OffPort::Open);
    assert!(
        attempts[1..]
            .iter()
            .all(|a| a.port == OffPort::Reopened && a.error.is_some())
    );
    // Within the budget (plus one reply timeout for the attempt running when it ran out).
    let t = test_timeouts();
    assert!(
        attempts.last().unwrap().after_s <= (t.laser_off_budget + t.laser_reply).as_secs_f64(),
        "{attempts:?}"
    );
    // The rest of the way down was done and acknowledged.
    assert!(
        s.shutdown.galvo_signals_off_ok && s.shutdown.galvo_stop_ok && s.shutdown.cnc_abort_ok,
        "{:?}",
        s.shutdown
    );
    assert!(!sim.galvo.status().laser_signals);
    assert!(!sim.monitor.light());
}

/// A cancel that lands after the last layer's emission-off (the operator's Ctrl-C as the run
/// ends) does not skip the final galvo laser signals off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_cancel_still_switches_the_laser_signals_off_at_the_end() {
    let sim = sim_cell("monaco").await;
    let job = demo_job(2);
    let layers = job.layers().count();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let cancel = CancellationToken::new();
    // Cancelled as the last emission-off's reply arrives (emission-offs: preparation's, then
    // one per layer; monaco's `?L` query is answered "L=0" too, so commands are counted).
    let (c, sent) = (
        cancel.clone(),
        std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0)),
    );
    let tap = Tap::new(move |io| {
        if io.device != Device::Laser || io.text != "L=0" {
            return;
        }
        match io.direction {
            trim_io::tap::Direction::Command => {
                sent.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            }
            trim_io::tap::Direction::Reply => {
                if sent.load(std::sync::atomic::Ordering::SeqCst) == 1 + layers {
                    c.cancel();
                }
            }
        }
    });
    let summary = Executor::new(job.clone(), connect(&sim, tap).await, &path, None)
        .with_options(options())
        .run(cancel.clone(), None)
        .await
        .expect("the last layer was journaled before the cancel was looked at");
    assert!(cancel.is_cancelled(), "the tap never cancelled");
    assert_eq!(summary.layers_marked, layers);
    assert!(
        !sim.galvo.status().laser_signals,
        "the galvo's laser signals were left on at the end"
    );
    assert!(!sim.laser.state().emission);
}

/// A panic on the executor's task while the laser emits (here in the device tap, at the laser's
/// fault check right after layer 0's `EXECUTE`) unwinds through the executor: the laser client's
/// guard writes the emission-off as it is dropped, and the galvo, its session closed, drops its
/// laser signals.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_panic_on_the_executor_with_the_emission_on_switches_the_laser_off() {
    let sim = sim_cell_scaled("monaco", 20.0).await;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    // Preparation asks `?F` once; the second is the check right after EXECUTE.
    let queries = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let tap = Tap::new(move |io| {
        if io.device == Device::Laser
            && io.direction == trim_io::tap::Direction::Command
            && io.text == "?F"
            && queries.fetch_add(1, std::sync::atomic::Ordering::SeqCst) == 1
        {
            panic!("injected: a bug on the executor's task mid-layer");
        }
    });
    let run = Executor::new(demo_job(2), connect(&sim, tap).await, path, None)
        .with_options(options())
        .run(CancellationToken::new(), None);
    // As a panic unwinds through the executor's task: caught, the future dropped.
    let caught = futures::FutureExt::catch_unwind(std::panic::AssertUnwindSafe(run)).await;
    assert!(caught.is_err(), "the executor did not panic");
    assert!(
        sim.monitor
            .events()
            .iter()
            .any(|(_, e)| *e == trim_sim::safety::CellEvent::Emission(true)),
        "the panic came before the emission was on"
    );
    // The simulator reads the pty every 10 ms.
    let t = Instant::now();
    while sim.laser.state().emission && t.elapsed() < Duration::from_secs(2) {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(
        !sim.laser.state().emission,
        "emission left on after the panic"
    );
    while sim.galvo.status().laser_signals && t.elapsed() < Duration::from_secs(2) {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(!sim.monitor.light());
}

/// A journal on a disk that hangs: the `hang_at`-th line (0-based, after the start line) takes
/// `hang` before it is written through (the disk recovers later).
struct SlowDisk {
    inner: Box<dyn journal::JournalSink>,
    lines: usize,
    hang_at: usize,
    hang: Duration,
    hung_at: std::sync::Arc<std::sync::Mutex<Option<Instant>>>,
}

impl journal::JournalSink for SlowDisk {
    fn append_line(&mut self, line: &[u8]) -> std::io::Result<()> {
        let i = self.lines;
        self.lines += 1;
        if i == self.hang_at {
            *self
                .hung_at
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(Instant::now());
            std::thread::sleep(self.hang);
        }
        self.inner.append_line(line)
    }
}

/// A journal write (with its fsync) that hangs past the journal-write timeout takes the way
/// down at the timeout, laser first, instead of hanging the run; the stop names the hung
/// journal. Once the disk has recovered, resume finishes with every vector marked once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hung_journal_write_takes_the_way_down_at_its_timeout() {
    let target = LayerKey { zone: 1, layer: 0 };
    let t = test_timeouts();
    let hang = t.journal_write * 3;
    // Line 4 is layer index 2's layer_begin (before its move ends), line 5 its layer_done.
    for (hang_at, phase) in [(4, Phase::LoadList), (5, Phase::Journal)] {
        let label = format!("journal line {hang_at} hangs");
        let sim = sim_cell("monaco").await;
        let job = demo_job(2);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let hung_at = std::sync::Arc::new(std::sync::Mutex::new(None));
        let hung2 = hung_at.clone();
        let err = Executor::new(job.clone(), connect(&sim, Tap::none()).await, &path, None)
            .with_options(options())
            .with_journal_sink(move |inner| {
                Box::new(SlowDisk {
                    inner,
                    lines: 0,
                    hang_at,
                    hang,
                    hung_at: hung2,
                })
            })
            .run(CancellationToken::new(), None)
            .await
            .expect_err(&label);
        let stopped_at = Instant::now();
        let ExecError::Stopped(s) = err else {
            panic!("{label}: not stopped through the way down: {err}")
        };
        assert!(
            matches!(&s.cause, trim_io::executor::StopCause::Journal { message } if message.contains("did not return within 1000 ms")),
            "{label}: {:?}",
            s.cause
        );
        assert_eq!((s.key, s.phase), (Some(target), phase), "{label}");
        // Detected at the timeout, not when the disk came back.
        let hung = hung_at.lock().unwrap().expect("the sink hung");
        let detected = s.detected_at.unwrap().saturating_duration_since(hung);
        // The timeout starts as the write's thread is started, a moment before the sink hangs.
        assert!(
            detected + Duration::from_millis(50) >= t.journal_write
                && detected < t.journal_write + Duration::from_millis(500),
            "{label}: detected {detected:?} after the hang began"
        );
        assert!(
            stopped_at.saturating_duration_since(hung) < hang,
            "{label}: waited for the disk"
        );
        assert!(s.shutdown.all_acknowledged(), "{label}: {:?}", s.shutdown);
        assert!(!sim.laser.state().emission, "{label}");
        assert!(!sim.galvo.status().laser_signals, "{label}");
        assert!(!sim.monitor.light(), "{label}");
        assert!(sim.monitor.violations().is_empty(), "{label}");

        // The disk comes back (the hung write lands); resume finishes, each vector once.
        tokio::time::sleep(hang).await;
        let st = journal::read(&path).unwrap();
        assert!(!st.torn_tail, "{label}");
        let summary = resume(&sim, &job, &path).await;
        assert!(summary.layers_skipped >= 2, "{label}");
        assert_eq!(
            assert_marked_exactly_once(&job, &sim.galvo.marks()),
            0,
            "{label}"
        );
        assert_eq!(journal::read(&path).unwrap().finished.len(), 4, "{label}");
    }
}

/// A CNC in E-stop, or unhomed, is refused before anything is switched on unless the operator
/// allowed the step (`--enable-machine`, `--home`); the refusal names the state, nothing is
/// journaled, the machine is left as it was. Allowed, the run resets and homes it and finishes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_machine_in_estop_or_unhomed_is_refused_unless_the_step_is_allowed() {
    let power_only = trim_io::cnc::EnableSteps {
        enable_machine: true,
        home: false,
    };
    for (label, allowed, says) in [
        (
            "E-stop, nothing allowed",
            trim_io::cnc::EnableSteps::default(),
            "in E-stop",
        ),
        ("E-stop, only --enable-machine", power_only, "not homed"),
    ] {
        let sim = sim_cell("monaco").await;
        sim.cnc.set_estop(true);
        sim.cnc.set_unhomed();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let e = Executor::new(demo_job(2), connect(&sim, Tap::none()).await, &path, None)
            .with_options(ExecOptions {
                enable: allowed,
                ..options()
            })
            .run(CancellationToken::new(), None)
            .await
            .expect_err(label);
        assert!(matches!(e, ExecError::MachineNotReady(_)), "{label}: {e}");
        assert!(e.to_string().contains(says), "{label}: {e}");
        assert_eq!(sim.cnc.machine_state(), (true, false, false), "{label}");
        assert!(!path.exists(), "{label}: journaled");
        assert_eq!(
            sim.laser.state().lines_received,
            0,
            "{label}: the laser was addressed"
        );
        assert!(!sim.galvo.status().laser_signals, "{label}");
    }
    let sim = sim_cell("monaco").await;
    sim.cnc.set_estop(true);
    sim.cnc.set_unhomed();
    let dir = tempfile::tempdir().unwrap();
    let summary = Executor::new(
        demo_job(2),
        connect(&sim, Tap::none()).await,
        dir.path().join("run.journal"),
        None,
    )
    .with_options(ExecOptions {
        enable: trim_io::cnc::EnableSteps::ALL,
        ..options()
    })
    .run(CancellationToken::new(), None)
    .await
    .expect("both steps allowed");
    assert_eq!(summary.layers_marked, 4);
    assert_eq!(sim.cnc.machine_state(), (false, true, true));
}

/// Another session moves the machine (an MDI move, as a jog would) or puts it in E-stop while a
/// layer marks: the executor's poll of the CNC sees the machine leave the layer's pose or its
/// enabled state and takes the way down, laser first, within the poll period plus the way
/// down's laser-off; the cut is journaled and resume finishes the job. (The move itself is
/// outside trimctl's control: the monitor records emission during it, which is what the poll
/// bounds.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cnc_leaving_the_layers_pose_or_its_enabled_state_mid_layer_takes_the_way_down() {
    use trim_io::cnc::Cnc as _;
    use trim_io::cnc::linuxcnc::{LinuxCnc, LinuxCncConfig};
    const POLL: Duration = Duration::from_millis(20);
    for intrusion in ["move", "estop"] {
        let sim = sim_cell_scaled("monaco", 20.0).await;
        let job = demo_job(2);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let run = Executor::new(job.clone(), connect(&sim, Tap::none()).await, &path, None)
            .with_options(ExecOptions {
                cnc_poll: POLL,
                ..options()
            })
            .run(CancellationToken::new(), Some(tx));
        let cnc_addr = sim.cnc.addr();
        let intrude = async {
            // Layer 0's list runs (its first vectors reported), then the second session acts.
            while let Some(p) = rx.recv().await {
                if matches!(p, Progress::Vectors { key, .. } if key == LayerKey { zone: 0, layer: 0 })
                {
                    break;
                }
            }
            let mut other = LinuxCnc::connect(cnc_addr, LinuxCncConfig::default(), Tap::none())
                .await
                .unwrap()
                .unwrap();
            let at = Instant::now();
            match intrusion {
                "move" => {
                    let mut p = trim_cell::job::Pose::default();
                    p.0.insert("x".into(), 30.0);
                    other.start_move(&p).await.unwrap().unwrap();
                }
                _ => other.estop().await.unwrap().unwrap(),
            }
            at
        };
        let (result, intruded_at) = tokio::join!(run, intrude);
        let err = result.expect_err(intrusion);
        let ExecError::Stopped(s) = err else {
            panic!("{intrusion}: {err}")
        };
        assert_eq!(s.phase, Phase::WaitDone, "{intrusion}: {:?}", s.cause);
        assert_eq!(s.key, Some(LayerKey { zone: 0, layer: 0 }), "{intrusion}");
        let want = if intrusion == "move" {
            "the machine moved while the layer marked: x at"
        } else {
            "left its enabled state while the layer marked (E-stop)"
        };
        assert!(
            matches!(&s.cause, trim_io::executor::StopCause::Fault { device: Device::Cnc, message } if message.contains(want)),
            "{intrusion}: {:?}",
            s.cause
        );
        // Laser first: the light path closed within a poll period plus the way down's laser
        // off of the intrusion.
        let closed = sim
            .monitor
            .light_closed_since(intruded_at)
            .unwrap_or_else(|| panic!("{intrusion}: light still on"));
        let after = closed.saturating_duration_since(intruded_at);
        assert!(
            after < POLL + Duration::from_millis(200),
            "{intrusion}: light off {after:?} after the intrusion"
        );
        assert!(s.shutdown.laser_off_ok, "{intrusion}: {:?}", s.shutdown);
        assert!(!sim.laser.state().emission, "{intrusion}");
        let st = journal::read(&path).unwrap();
        assert!(!st.torn_tail && st.finished.is_empty(), "{intrusion}");

        // The operator puts the machine back; resume (allowed to enable it again) finishes.
        let summary = Executor::new(job.clone(), connect(&sim, Tap::none()).await, &path, None)
            .with_options(ExecOptions {
                enable: trim_io::cnc::EnableSteps::ALL,
                ..options()
            })
            .resume(CancellationToken::new(), None)
            .await
            .unwrap_or_else(|e| panic!("{intrusion}: resume: {e}"));
        assert_eq!(summary.layers_marked, 4, "{intrusion}");
        assert!(
            assert_marked_exactly_once(&job, &sim.galvo.marks()) <= 1,
            "{intrusion}"
        );
    }
}

/// A record file whose flush hangs once `hang` is set (the disk under the MCAP record stops
/// answering).
struct HangingFile {
    inner: std::io::BufWriter<std::fs::File>,
    hang: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl std::io::Write for HangingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.inner.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        if self.hang.load(std::sync::atomic::Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(trim_io::record::FLUSH_TIMEOUT_MS * 2));
        }
        self.inner.flush()
    }
}

impl std::io::Seek for HangingFile {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(to)
    }
}

/// The MCAP record's disk hangs after layer 0: the flush during the next move is bounded by
/// the record's flush timeout and takes the way down (laser first) instead of hanging the run;
/// the journal is intact and resume finishes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hung_record_flush_takes_the_way_down_at_its_timeout() {
    let sim = sim_cell("monaco").await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let hang = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let file = HangingFile {
        inner: std::io::BufWriter::new(std::fs::File::create(dir.path().join("run.mcap")).unwrap()),
        hang: hang.clone(),
    };
    let recorder = Recorder::create_on(file, &dir.path().join("run.mcap"))
        .unwrap()
        .shared();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let t0 = Instant::now();
    // The CLI keeps its own handle (it finishes the record after the run): so does the test, so
    // the executor's end does not close the file.
    let run = Executor::new(
        job.clone(),
        connect(&sim, Tap::none()).await,
        &path,
        Some(recorder.clone()),
    )
    .with_options(options())
    .run(CancellationToken::new(), Some(tx));
    let arm = async {
        while let Some(p) = rx.recv().await {
            if matches!(p, Progress::LayerDone { index: 0, .. }) {
                hang.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        }
    };
    let (result, ()) = tokio::join!(run, arm);
    let err = result.expect_err("the record's disk hung");
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    assert!(
        matches!(&s.cause, trim_io::executor::StopCause::Record { message } if message.contains("did not flush within")),
        "{:?}",
        s.cause
    );
    // The next move after the disk hung (the hang is armed from the progress events, so it
    // may land a layer late).
    assert_eq!(s.phase, Phase::Move, "{:?}", s.key);
    assert!(s.layers_finished >= 1, "{s:?}");
    // Bounded: the flush timeout, not the disk's hang (twice as long), and no second wait.
    let took = t0.elapsed();
    assert!(
        took < Duration::from_millis(trim_io::record::FLUSH_TIMEOUT_MS * 2),
        "the run waited for the disk: {took:?}"
    );
    assert!(s.shutdown.all_acknowledged(), "{:?}", s.shutdown);
    assert!(!sim.laser.state().emission);
    assert!(!sim.monitor.light());
    let st = journal::read(&path).unwrap();
    assert_eq!(st.finished.len(), s.layers_finished);
    let summary = resume(&sim, &job, &path).await;
    assert_eq!(summary.layers_skipped, s.layers_finished);
    assert_eq!(assert_marked_exactly_once(&job, &sim.galvo.marks()), 0);
    // Closing the record on the hung disk is bounded too (one flush timeout).
    let t = Instant::now();
    drop(recorder);
    assert!(t.elapsed() < Duration::from_millis(trim_io::record::FLUSH_TIMEOUT_MS * 2));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_polyline_of_several_passes_is_marked_that_often_and_a_resume_mid_pass_remarks_nothing() {
    let sim = sim_cell_scaled("monaco", MATRIX_GALVO_TIME_SCALE).await;
    let mut job = demo_job(1);
    // Zone 1's zig-zag (3 vectors) three times: 9 vectors, then the corner's 2.
    job.zones[1].layers[0].polylines[0].passes = 3;
    let target = LayerKey { zone: 1, layer: 0 };
    assert_eq!(
        trim_io::galvo::list::vector_count(&job.zones[1].layers[0]),
        11
    );
    // The job file carries the count and reads back; a count of 0 is refused, naming it.
    assert_eq!(Job::from_json(&job.to_json().unwrap()).unwrap(), job);
    let mut zero = job.clone();
    zero.zones[1].layers[0].polylines[0].passes = 0;
    let e = Job::from_json(&zero.to_json().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("zone 1 layer 0 polyline 0 (contour 2): passes = 0"),
        "{e}"
    );

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.journal");
    let cancel = CancellationToken::new();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let c2 = cancel.clone();
    let watcher = tokio::spawn(async move {
        while let Some(p) = rx.recv().await {
            // Within the second pass.
            if let Progress::Vectors { key, done, .. } = p
                && key == target
                && done >= 4
            {
                c2.cancel();
                return;
            }
        }
        panic!("never reached the second pass");
    });
    let cell = connect(&sim, Tap::none()).await;
    let err = Executor::new(job.clone(), cell, &path, None)
        .with_options(options())
        .run(cancel, Some(tx))
        .await
        .expect_err("cancelled");
    watcher.await.unwrap();
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    let done = s.vectors_done.expect("how far the layer got");
    assert!((4..11).contains(&done), "{done}");
    let summary = resume(&sim, &job, &path).await;
    assert_eq!(summary.resumed_from, Some((target, done)));
    // Every planned vector (each pass's) marked exactly as often as planned: the zig-zag's
    // three vectors three times each, nothing a fourth time.
    let partial = assert_marked_exactly_once(&job, &sim.galvo.marks());
    assert!(partial <= 1, "{partial} partly marked vectors");
    assert!(sim.monitor.violations().is_empty());
}
