//! Red-light framing against the simulators: the galvo's pointer and `EXECUTE_FRAME` rules
//! (docs/protocols/galvo.md §5a), [`trim_io::framing::frame_layer`] on the simulated cell, and
//! the executor's zone gate (`run --frame`). Framing never opens the gate: no emission, no open
//! gate, no marked vector, while the traced outline covers every point of the layer.

mod common;

use std::time::{Duration, Instant};

use common::{
    assert_marked_exactly_once, connect, demo_job, planned_vectors, sim_cell, test_timeouts,
};
use futures::future::BoxFuture;
use tokio_util::sync::CancellationToken;
use trim_cell::job::{Job, LayerKey};
use trim_io::cell_devices::Cell;
use trim_io::executor::{
    ExecError, ExecOptions, Executor, Phase, StopCause, ZoneDecision, ZoneGate,
};
use trim_io::framing::{FrameSettings, frame_layer, rearm};
use trim_io::galvo::outline::OutlineKind;
use trim_io::galvo::protocol::{ControllerState, ListCommand, StatusCode};
use trim_io::galvo::{GalvoClient, GalvoClientConfig};
use trim_io::tap::Tap;
use trim_sim::SimCell;
use trim_sim::fault::{Fault, FaultKind, FaultSwitch, Trigger};
use trim_sim::galvo::{GalvoSim, GalvoSimConfig, TraceRecord};
use trim_sim::safety::{CellEvent, SafetyMonitor};

/// Liveness bound for things that happen within a few ms on an idle machine.
const GENEROUS: Duration = Duration::from_secs(5);

fn triangle() -> Vec<ListCommand> {
    vec![
        ListCommand::Speeds {
            jump_bits_per_ms: 20_000.0,
            mark_bits_per_ms: 20_000.0,
        },
        ListCommand::Jump { x: 0, y: 0 },
        ListCommand::Mark { x: 1000, y: 0 },
        ListCommand::Mark { x: 0, y: 1000 },
        ListCommand::Mark { x: 0, y: 0 },
    ]
}

async fn galvo(monitor: SafetyMonitor, faults: FaultSwitch) -> (GalvoSim, GalvoClient) {
    let sim = GalvoSim::start(
        ([127, 0, 0, 1], 0).into(),
        GalvoSimConfig {
            time_scale: 0.0,
            ..GalvoSimConfig::default()
        },
        monitor,
        faults,
    )
    .await
    .expect("galvo simulator");
    let client = GalvoClient::connect(sim.addr(), GalvoClientConfig::default(), Tap::none())
        .await
        .expect("link")
        .expect("hello");
    (sim, client)
}

fn refused<T: std::fmt::Debug>(r: trim_io::galvo::GalvoResult<T>) -> StatusCode {
    r.expect("link").expect_err("refused").code
}

async fn wait_frame_end(c: &GalvoClient) -> trim_io::galvo::protocol::FrameBlock {
    let t = Instant::now();
    loop {
        let f = c.frame_status().await.expect("link").expect("frame status");
        if !f.framing {
            return f;
        }
        assert!(t.elapsed() < GENEROUS, "frame never ended");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

fn assert_dark(traces: &[TraceRecord]) {
    assert!(!traces.is_empty(), "nothing traced");
    for t in traces {
        assert!(t.pointer, "traced without the pointer: {t:?}");
        assert!(
            !t.gate_open && !t.emission,
            "light path open while framing: {t:?}"
        );
    }
}

#[tokio::test]
async fn the_pointer_and_the_laser_signals_exclude_each_other_and_frames_stay_dark() {
    let monitor = SafetyMonitor::new();
    let (sim, c) = galvo(monitor.clone(), FaultSwitch::default()).await;
    c.load_list(0, 0xF000_0001, &triangle())
        .await
        .unwrap()
        .unwrap();

    // Armed process laser: no pointer, no frame.
    c.laser_signals(true).await.unwrap().unwrap();
    assert_eq!(refused(c.pointer(true).await), StatusCode::Refused);
    assert_eq!(refused(c.execute_frame(0, 1).await), StatusCode::Refused);

    // Pointer on: the laser signals cannot be enabled, a marking EXECUTE finds them off.
    c.laser_signals(false).await.unwrap().unwrap();
    c.pointer(true).await.unwrap().unwrap();
    assert_eq!(refused(c.laser_signals(true).await), StatusCode::Refused);
    assert_eq!(refused(c.execute(0).await), StatusCode::SignalsOff);

    // Three passes: 3 vectors each, traced with the pointer, never marked.
    c.execute_frame(0, 3).await.unwrap().unwrap();
    let f = wait_frame_end(&c).await;
    assert_eq!(
        (f.passes_done, f.vectors_traced, f.tag),
        (3, 9, 0xF000_0001)
    );
    assert!(f.pointer, "the pointer stays on after a bounded frame");
    let s = c.status().await.unwrap().unwrap();
    assert_eq!(
        (s.state, s.marks_done, s.gate_open),
        (ControllerState::Idle, 0, false)
    );
    let traces = sim.traces();
    assert_eq!(traces.len(), 9);
    assert_dark(&traces);
    assert_eq!(traces[0].from_bits, [0, 0]);
    assert_eq!(traces[0].to_bits, [1000, 0]);
    assert_eq!(traces[8].pass, 2);
    assert!(sim.marks().is_empty(), "a frame marked: {:?}", sim.marks());

    // Endless: until STOP, which also switches the pointer off.
    c.execute_frame(0, 0).await.unwrap().unwrap();
    assert_eq!(refused(c.execute_frame(0, 0).await), StatusCode::ListBusy);
    assert_eq!(
        refused(c.load_list(0, 1, &triangle()).await),
        StatusCode::ListBusy
    );
    let t = Instant::now();
    while c.frame_status().await.unwrap().unwrap().passes_done < 2 {
        assert!(t.elapsed() < GENEROUS, "endless frame not tracing");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    c.stop().await.unwrap().unwrap();
    let f = wait_frame_end(&c).await;
    assert!(!f.pointer && !f.framing);
    assert_eq!(
        c.status().await.unwrap().unwrap().state,
        ControllerState::Stopped
    );
    assert_dark(&sim.traces());
    assert!(
        monitor.violations().is_empty(),
        "{:?}",
        monitor.violations()
    );
    let events: Vec<CellEvent> = monitor.events().into_iter().map(|(_, e)| e).collect();
    assert!(!events.contains(&CellEvent::Gate(true)), "{events:?}");
    assert_eq!(
        events
            .iter()
            .filter(|e| **e == CellEvent::Framing(true))
            .count(),
        2
    );
    assert_eq!(
        events.last(),
        Some(&CellEvent::Framing(false)),
        "{events:?}"
    );

    // After framing, marking works again once the pointer is off.
    c.laser_signals(true).await.unwrap().unwrap();
    c.execute(0).await.unwrap().unwrap();
}

#[tokio::test]
async fn a_lost_link_ends_the_frame_and_switches_the_pointer_off() {
    let monitor = SafetyMonitor::new();
    let (sim, c) = galvo(monitor.clone(), FaultSwitch::default()).await;
    c.load_list(1, 7, &triangle()).await.unwrap().unwrap();
    c.pointer(true).await.unwrap().unwrap();
    c.execute_frame(1, 0).await.unwrap().unwrap();
    drop(c); // no heartbeat, connection closed
    let t = Instant::now();
    while sim.frame_status().framing || sim.frame_status().pointer {
        assert!(t.elapsed() < GENEROUS, "the watchdog never ended the frame");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert!(!monitor.pointer() && !monitor.framing());
    assert_eq!(sim.status().state, ControllerState::WatchdogTrip);
    assert!(monitor.violations().is_empty());
}

/// The polygon traced in pass 0 of the frame of `tag`, from the simulator's record.
fn traced_polygon(traces: &[TraceRecord], tag: u32) -> Vec<[i32; 2]> {
    traces
        .iter()
        .filter(|t| t.tag == tag && t.pass == 0)
        .map(|t| t.from_bits)
        .collect()
}

/// Whether `p` is inside or on the convex polygon `v` (either orientation), exactly.
fn inside(v: &[[i32; 2]], p: [i32; 2]) -> bool {
    let n = v.len();
    let cross = |a: [i32; 2], b: [i32; 2], c: [i32; 2]| {
        (i128::from(b[0]) - i128::from(a[0])) * (i128::from(c[1]) - i128::from(a[1]))
            - (i128::from(b[1]) - i128::from(a[1])) * (i128::from(c[0]) - i128::from(a[0]))
    };
    let signs: Vec<i128> = (0..n)
        .map(|i| cross(v[i], v[(i + 1) % n], p).signum())
        .collect();
    signs.iter().all(|s| *s >= 0) || signs.iter().all(|s| *s <= 0)
}

fn layer_points(job: &Job, key: LayerKey) -> Vec<[i32; 2]> {
    let (_, _, l) = job.layers().find(|(k, _, _)| *k == key).expect("layer");
    let mut single = job.clone();
    single.zones.retain(|z| z.id == key.zone);
    single.zones[0].layers = vec![l.clone()];
    planned_vectors(&single)
        .into_iter()
        .flat_map(|(a, b)| [a, b])
        .collect()
}

fn settings() -> FrameSettings {
    FrameSettings {
        timeouts: test_timeouts(),
        ..FrameSettings::new(OutlineKind::Hull)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn framing_a_layer_traces_its_hull_at_its_pose_with_the_light_path_shut() {
    let sim = sim_cell("monaco").await;
    let job = demo_job(2);
    let mut cell = connect(&sim, Tap::none()).await;
    // Emission left on by someone: framing switches it off before anything else.
    cell.laser.emission(true).await.unwrap().unwrap();
    let key = LayerKey { zone: 1, layer: 1 };
    let cancel = CancellationToken::new();
    for kind in [OutlineKind::Hull, OutlineKind::Box] {
        let s = FrameSettings {
            outline: kind,
            ..settings()
        };
        let (framed, held) = frame_layer(
            &mut cell,
            &job,
            key,
            &s,
            2,
            std::future::pending::<()>(),
            &cancel,
        )
        .await
        .unwrap_or_else(|e| panic!("{kind}: {e}"));
        assert!(held.is_none());
        assert_eq!(framed.passes_done, 2);
        let n = framed.outline.vertices_bits.len();
        assert_eq!(framed.vectors_traced as usize, 2 * n);
        assert!(
            matches!(
                (kind, n),
                (OutlineKind::Box, 4) | (OutlineKind::Hull, 3..=7)
            ),
            "{kind} {n}"
        );
    }
    let traces = sim.galvo.traces();
    assert_dark(&traces);
    let polygon = traced_polygon(&traces, trim_io::galvo::outline::frame_tag(1, 1));
    assert!(polygon.len() >= 3, "{polygon:?}");
    for p in layer_points(&job, key) {
        assert!(inside(&polygon, p), "{p:?} outside the traced {polygon:?}");
    }
    assert!(sim.galvo.marks().is_empty(), "framing marked");
    assert!(!sim.laser.state().emission);
    assert!(!sim.monitor.pointer() && !sim.monitor.framing());
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
    // The CNC stands at the layer's pose.
    let at = cell.cnc.positions().await.unwrap().unwrap();
    let (_, _, layer) = job.layers().find(|(k, _, _)| *k == key).unwrap();
    for (axis, want) in &layer.pose.0 {
        let got = at.world.0.get(axis).copied().unwrap_or(f64::NAN);
        assert!((got - want).abs() < 1e-3, "{axis}: {got} vs {want}");
    }
    // Emission went off before the first frame started.
    let events: Vec<CellEvent> = sim.monitor.events().into_iter().map(|(_, e)| e).collect();
    let first_frame = events
        .iter()
        .position(|e| *e == CellEvent::Framing(true))
        .unwrap();
    let last_emission = events[..first_frame]
        .iter()
        .rev()
        .find(|e| matches!(e, CellEvent::Emission(_)));
    assert_eq!(
        last_emission,
        Some(&CellEvent::Emission(false)),
        "{events:?}"
    );
}

/// A simulated cell whose galvo link drops at the third `FRAME_STATUS` (mid-trace), with
/// `laser` faults besides.
async fn cell_losing_the_galvo_while_framing(laser: Vec<Fault>) -> SimCell {
    let profile = trim_io::laser::Profile::builtin("monaco").expect("a built-in profile");
    let mut o = trim_sim::SimOptions::new(profile);
    o.cnc_time_scale = 0.1;
    o.faults.galvo = vec![Fault {
        kind: FaultKind::DropLink,
        trigger: Trigger::Command {
            name: "FRAME_STATUS".into(),
            nth: 3,
        },
    }];
    o.faults.laser = laser;
    SimCell::start(o).await.expect("the simulated cell starts")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_galvo_fault_while_framing_leaves_the_pointer_off_and_the_gate_shut() {
    let sim = cell_losing_the_galvo_while_framing(Vec::new()).await;
    let job = demo_job(1);
    let mut cell = connect(&sim, Tap::none()).await;
    let key = LayerKey { zone: 0, layer: 0 };
    let err = frame_layer(
        &mut cell,
        &job,
        key,
        &settings(),
        0,
        std::future::pending::<()>(),
        &CancellationToken::new(),
    )
    .await
    .expect_err("the link drops");
    assert!(matches!(err.cause, StopCause::Link { .. }), "{err}");
    assert!(err.laser_off_ok, "{err}");
    let t = Instant::now();
    while sim.monitor.pointer() || sim.monitor.framing() {
        assert!(t.elapsed() < GENEROUS, "pointer left on after the fault");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert!(sim.galvo.marks().is_empty());
    assert!(
        !sim.monitor
            .events()
            .iter()
            .any(|(_, e)| *e == CellEvent::Gate(true))
    );
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
}

/// A galvo fault while framing with a laser that no longer answers: the way down tries the
/// laser's emission-off first (before the galvo and the CNC), and framing says the laser's
/// state is unknown instead of "the laser gate was kept shut".
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn framing_says_when_the_lasers_emission_off_was_not_acknowledged() {
    // The preparation's emission-off is answered; the way down's is not.
    let sim = cell_losing_the_galvo_while_framing(vec![Fault {
        kind: FaultKind::DropLink,
        trigger: Trigger::Command {
            name: "emission_off".into(),
            nth: 2,
        },
    }])
    .await;
    let job = demo_job(1);
    let mut cell = connect(&sim, Tap::none()).await;
    let err = frame_layer(
        &mut cell,
        &job,
        LayerKey { zone: 0, layer: 0 },
        &settings(),
        0,
        std::future::pending::<()>(),
        &CancellationToken::new(),
    )
    .await
    .expect_err("the link drops");
    assert!(matches!(err.cause, StopCause::Link { .. }), "{err}");
    assert!(!err.laser_off_ok, "{err}");
    assert!(err.to_string().contains("NOT acknowledged"), "{err}");
    assert!(sim.galvo.marks().is_empty());
}

/// A scripted operator: frames each zone once, answers from a list.
struct Scripted {
    answers: Vec<ZoneDecision>,
    asked: Vec<LayerKey>,
}

impl ZoneGate for Scripted {
    fn before_zone<'a>(
        &'a mut self,
        cell: &'a mut Cell,
        job: &'a Job,
        key: LayerKey,
        cancel: &'a CancellationToken,
    ) -> BoxFuture<'a, Result<ZoneDecision, StopCause>> {
        Box::pin(async move {
            let s = FrameSettings {
                prepare: false,
                ..settings()
            };
            frame_layer(cell, job, key, &s, 1, std::future::pending::<()>(), cancel).await?;
            let answer = self.answers[self.asked.len()];
            self.asked.push(key);
            if answer == ZoneDecision::Mark {
                rearm(cell, &s.timeouts, cancel).await?;
            }
            Ok(answer)
        })
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_zone_gate_frames_before_each_zone_and_quit_takes_the_way_down() {
    let sim = sim_cell("ipg").await;
    let job = demo_job(2);
    let dir = tempfile::tempdir().unwrap();
    let cell = connect(&sim, Tap::none()).await;
    let gate = Scripted {
        answers: vec![ZoneDecision::Mark, ZoneDecision::Quit],
        asked: Vec::new(),
    };
    let err = Executor::new(job.clone(), cell, dir.path().join("j"), None)
        .with_options(ExecOptions {
            timeouts: test_timeouts(),
            ..ExecOptions::default()
        })
        .with_zone_gate(Box::new(gate))
        .run(CancellationToken::new(), None)
        .await
        .expect_err("quit at zone 1");
    let ExecError::Stopped(s) = err else {
        panic!("{err}")
    };
    assert_eq!(
        (s.cause.clone(), s.phase, s.key),
        (
            StopCause::Cancelled,
            Phase::Frame,
            Some(LayerKey { zone: 1, layer: 0 })
        )
    );
    assert_eq!(s.layers_finished, 2);
    let st = trim_io::journal::read(&dir.path().join("j")).unwrap();
    assert_eq!(st.finished.len(), 2);
    assert!(st.finished.iter().all(|k| k.zone == 0));
    // Zone 0 marked exactly once, zone 1 never; both framed, dark.
    let mut zone0 = job.clone();
    zone0.zones.retain(|z| z.id == 0);
    assert_eq!(assert_marked_exactly_once(&zone0, &sim.galvo.marks()), 0);
    let traces = sim.galvo.traces();
    assert_dark(&traces);
    for zone in [0, 1] {
        let tag = trim_io::galvo::outline::frame_tag(zone, 0);
        assert!(
            traces.iter().any(|t| t.tag == tag),
            "zone {zone} not framed"
        );
    }
    assert!(!sim.laser.state().emission && !sim.monitor.pointer());
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
}
