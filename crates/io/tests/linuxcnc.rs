//! Integration test against a real, headless LinuxCNC (xyzac-trt sim config) started through
//! `scripts/linuxcnc-sim`, following docs/cnc/LINUXCNC.md. Fails with a clear message when
//! LinuxCNC is not installed, unless `TRIMCTL_SKIP_LINUXCNC=1`: then it is reported as ignored
//! (libtest-mimic, `harness = false`: see `support/linuxcnc_sim.rs`).
//!
//! Everything runs in one test function: LinuxCNC is one instance per machine.
#![expect(
    clippy::unwrap_used,
    reason = "a test binary without libtest (harness = false): a failed step fails the test"
)]

mod common;
#[path = "support/linuxcnc_sim.rs"]
mod linuxcnc_sim;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio_util::sync::CancellationToken;
use trim_cell::kinematics::{
    AxisPose, KinematicsKind, MachineSettings, forward, inverse, joints_of,
};
use trim_geom::{Point3, UnitVector3, Vector3};
use trim_io::cell_devices::{Cell, Timeouts};
use trim_io::cnc::linuxcnc::{LinuxCnc, LinuxCncConfig};
use trim_io::cnc::{Cnc, CncFault, EnableSteps};
use trim_io::executor::{ExecError, ExecOptions, Executor, Phase, Progress, StopCause};
use trim_io::tap::{Device, Tap};

/// How often the intrusion test polls the CNC while a layer marks.
const CNC_POLL: Duration = Duration::from_millis(20);
/// The port the test's LinuxCNC listens on (not the default 5007, to stay clear of a user's).
const PORT: u16 = 5017;
/// Reached vs commanded, world and joints (mm, degrees).
const POSITION_TOLERANCE: f64 = 1e-3;
/// The focus must land on the planned point within this (mm).
const FOCUS_TOLERANCE_MM: f64 = 1e-6;
/// Generous: a move of the sim machine takes a few seconds (20 mm/s, 30 deg/s).
const MOTION_TIMEOUT: Duration = Duration::from_secs(60);

/// Planner-style poses: a focus point and a beam direction through the planner's inverse
/// kinematics (xyzac-trt, TCP pose mode, the sim config's pivot offsets).
fn planned_poses(m: &MachineSettings) -> Vec<(Point3, UnitVector3, AxisPose)> {
    let targets = [
        (Point3::new(10.0, 20.0, -5.0), Vector3::new(0.0, 0.0, 1.0)),
        (Point3::new(-12.5, 8.0, 3.0), Vector3::new(0.3, 0.2, 0.93)),
        (Point3::new(5.0, -15.0, -10.0), Vector3::new(-0.4, 0.1, 0.9)),
    ];
    let mut previous = AxisPose::HOME;
    targets
        .iter()
        .map(|(p, d)| {
            let dir = UnitVector3::new_normalize(*d);
            let candidates = inverse(m, p, &dir, previous.rotary_deg);
            let pose = trim_cell::kinematics::choose_pose(m, &candidates, &previous)
                .unwrap_or_else(|e| panic!("no pose for {p:?} {d:?}: {e}"));
            previous = pose;
            (*p, dir, pose)
        })
        .collect()
}

fn main() -> std::process::ExitCode {
    linuxcnc_sim::run_test(
        "real_linuxcnc_takes_planned_poses_and_runs_a_whole_job",
        || {
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .expect("a tokio runtime")
                .block_on(real_linuxcnc_takes_planned_poses_and_runs_a_whole_job());
        },
    )
}

async fn real_linuxcnc_takes_planned_poses_and_runs_a_whole_job() {
    let _instance = linuxcnc_sim::Instance::start(PORT, "/tmp/trimctl-linuxcnc-test");
    let addr: SocketAddr = format!("127.0.0.1:{PORT}").parse().unwrap();
    let t = Instant::now();
    let mut cnc = LinuxCnc::connect(addr, LinuxCncConfig::default(), Tap::none())
        .await
        .expect("link")
        .expect("session");
    // The real LinuxCNC starts in E-stop and unhomed: the test allows both steps explicitly.
    cnc.enable(EnableSteps::ALL)
        .await
        .expect("link")
        .expect("enable");
    eprintln!(
        "connect + enable (estop off, machine on, home, M428): {:.2} s",
        t.elapsed().as_secs_f64()
    );

    let m = MachineSettings::default();
    assert_eq!(m.kinematics, KinematicsKind::XyzacTrt);
    for (point, dir, pose) in planned_poses(&m) {
        // The planner's pose puts the focus on the point with the beam along the direction.
        let (focus, beam) = forward(&m, &pose);
        assert!(
            (focus - point).norm() < FOCUS_TOLERANCE_MM,
            "{focus:?} vs {point:?}"
        );
        assert!((beam.into_inner() - dir.into_inner()).norm() < 1e-9);

        let job_pose = pose.to_job_pose(KinematicsKind::XyzacTrt);
        let t = Instant::now();
        cnc.start_move(&job_pose)
            .await
            .expect("link")
            .expect("move accepted");
        let reached = cnc
            .wait_in_position(MOTION_TIMEOUT)
            .await
            .expect("link")
            .expect("in position");
        eprintln!("move to {job_pose:?}: {:.2} s", t.elapsed().as_secs_f64());
        // Commanded world = reached world (LinuxCNC with M428 reports the tool tip).
        for (axis, commanded) in &job_pose.0 {
            let got = reached.world.axis(axis).unwrap();
            assert!(
                (got - commanded).abs() < POSITION_TOLERANCE,
                "{axis}: {got} vs {commanded}"
            );
        }
        // Joints = the planner's inverse kinematics, and they differ from world under TCP
        // kinematics once the table tilts.
        let joints = joints_of(&m, &pose);
        for i in 0..3 {
            assert!(
                (reached.joints[i] - joints[i]).abs() < POSITION_TOLERANCE,
                "joint {i}: LinuxCNC {} vs planner {} (pose {pose:?})",
                reached.joints[i],
                joints[i]
            );
        }
        assert!((reached.joints[3] - pose.tilt_deg).abs() < POSITION_TOLERANCE);
        assert!((reached.joints[4] - pose.rotary_deg).abs() < POSITION_TOLERANCE);
        let joint_world_gap = (0..3)
            .map(|i| (reached.joints[i] - pose.linear_mm[i]).abs())
            .fold(0.0, f64::max);
        if pose.tilt_deg.abs() > 1.0 {
            assert!(
                joint_world_gap > 0.1,
                "joints equal world under TCP kinematics: {reached:?}"
            );
        }
    }

    // A move beyond the limits is refused with LinuxCNC's own messages.
    let mut too_far = trim_cell::job::Pose::default();
    too_far.0.insert("x".into(), 500.0);
    cnc.start_move(&too_far)
        .await
        .expect("link")
        .expect("received");
    let refused = cnc.wait_in_position(MOTION_TIMEOUT).await.expect("link");
    match refused {
        Err(CncFault::Refused { errors, .. }) => {
            assert!(errors.iter().any(|e| e.contains("limit")), "{errors:?}");
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    cnc.abort().await.expect("link").expect("abort");
    assert!(cnc.errors().await.expect("link").expect("errors").len() < 64);

    // A stop while `set wait done` is pending (as on a cancel mid-move): linuxcncrsh reads a
    // session's lines one by one, so the abort goes out on a fresh session, and motion stops short.
    let mut long = trim_cell::job::Pose::default();
    for (k, v) in [
        ("x", -150.0),
        ("y", 0.0),
        ("z", 0.0),
        ("a", 0.0),
        ("c", 0.0),
    ] {
        long.0.insert(k.into(), v);
    }
    cnc.start_move(&long)
        .await
        .expect("link")
        .expect("long move accepted");
    let abandoned = tokio::time::timeout(
        Duration::from_millis(800),
        cnc.wait_in_position(MOTION_TIMEOUT),
    )
    .await;
    assert!(
        abandoned.is_err(),
        "a 150 mm move at 20 mm/s cannot finish in 0.8 s"
    );
    let t = Instant::now();
    cnc.abort()
        .await
        .expect("link")
        .expect("abort on a fresh session");
    eprintln!(
        "abort during a pending wait: acknowledged in {:.0} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut probe = LinuxCnc::connect(addr, LinuxCncConfig::default(), Tap::none())
        .await
        .expect("link")
        .expect("session");
    // Motion decelerates (the sim's acceleration limit): wait for standstill, bounded.
    let mut last = probe.positions().await.expect("link").expect("positions");
    let stopped_at = loop {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let p = probe.positions().await.expect("link").expect("positions");
        let moved = (p.world.axis("x").unwrap() - last.world.axis("x").unwrap()).abs();
        if moved < POSITION_TOLERANCE {
            break p;
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "still moving 10 s after the abort: {p:?}"
        );
        last = p;
    };
    eprintln!(
        "abort: standstill {:.2} s after the abort was sent",
        t.elapsed().as_secs_f64()
    );
    let x = stopped_at.world.axis("x").unwrap();
    assert!(x > -140.0, "the move was not stopped short: x = {x}");
    probe.estop().await.expect("link").expect("estop");
    drop((cnc, probe));

    // A whole job end to end: the real LinuxCNC with the galvo and laser simulators.
    let job = common::demo_job(2);
    let sim = common::sim_cell("monaco").await;
    let mut addrs = sim.addresses();
    addrs.cnc = addr;
    let timeouts = Timeouts {
        cnc_motion: MOTION_TIMEOUT,
        cnc_reply: Duration::from_secs(5),
        ..common::test_timeouts()
    };
    let cell = Cell::connect(&addrs, &timeouts, Tap::none())
        .await
        .expect("cell");
    let dir = tempfile::tempdir().expect("tempdir");
    let t = Instant::now();
    let summary = Executor::new(job.clone(), cell, dir.path().join("run.journal"), None)
        .with_options(ExecOptions {
            timeouts,
            enable: EnableSteps::ALL,
            ..ExecOptions::default()
        })
        .run(CancellationToken::new(), None)
        .await
        .unwrap_or_else(|e| panic!("job on the real LinuxCNC: {e}"));
    assert_eq!(summary.layers_marked, 4);
    assert_eq!(
        common::assert_marked_exactly_once(&job, &sim.galvo.marks()),
        0
    );
    assert!(
        sim.monitor.violations().is_empty(),
        "{:?}",
        sim.monitor.violations()
    );
    let motion: f64 = summary.layers.iter().map(|l| l.motion_s).sum();
    let overhead: Vec<f64> = summary.layers.iter().map(|l| l.overhead_s * 1e3).collect();
    eprintln!(
        "job on real LinuxCNC: {:.2} s wall ({motion:.2} s move + wait in position), galvo modelled {:.4} s vs estimate {:.4} s, per-layer overhead {overhead:.1?} ms",
        t.elapsed().as_secs_f64(),
        summary.galvo_modelled_s,
        summary.galvo_estimate_s
    );

    // Another linuxcncrsh session moves the machine mid-layer (an MDI move, as a jog would),
    // or puts it in E-stop: the executor's poll of the CNC sees it and takes the way down,
    // laser first.
    for intrusion in ["move", "estop"] {
        let sim = common::sim_cell_scaled("monaco", 20.0).await;
        let mut addrs = sim.addresses();
        addrs.cnc = addr;
        let cell = Cell::connect(&addrs, &timeouts, Tap::none())
            .await
            .expect("cell");
        let dir = tempfile::tempdir().expect("tempdir");
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let run = Executor::new(job.clone(), cell, dir.path().join("run.journal"), None)
            .with_options(ExecOptions {
                timeouts,
                enable: EnableSteps::ALL,
                cnc_poll: CNC_POLL,
                ..ExecOptions::default()
            })
            .run(CancellationToken::new(), Some(tx));
        let first = job.zones[0].layers[0].pose.clone();
        let intrude = async {
            while let Some(p) = rx.recv().await {
                if matches!(p, Progress::Vectors { key, .. } if key.zone == 0 && key.layer == 0) {
                    break;
                }
            }
            let mut other = LinuxCnc::connect(addr, LinuxCncConfig::default(), Tap::none())
                .await
                .expect("link")
                .expect("second session");
            let at = Instant::now();
            if intrusion == "move" {
                let mut p = first.clone();
                p.0.insert("x".into(), first.axis("x").unwrap_or(0.0) + 5.0);
                other.start_move(&p).await.expect("link").expect("MDI move");
            } else {
                other.estop().await.expect("link").expect("estop");
            }
            at
        };
        let (result, intruded_at) = tokio::join!(run, intrude);
        let err = result.expect_err(intrusion);
        let ExecError::Stopped(s) = err else {
            panic!("{intrusion}: {err}")
        };
        assert_eq!(s.phase, Phase::WaitDone, "{intrusion}: {:?}", s.cause);
        assert!(
            matches!(
                &s.cause,
                StopCause::Fault {
                    device: Device::Cnc,
                    ..
                }
            ),
            "{intrusion}: {:?}",
            s.cause
        );
        let closed = sim
            .monitor
            .light_closed_since(intruded_at)
            .unwrap_or_else(|| panic!("{intrusion}: light still on"));
        let after = closed.saturating_duration_since(intruded_at);
        eprintln!(
            "real LinuxCNC, {intrusion} from another session mid-layer: {:?}; light off {:.0} ms after",
            s.cause,
            after.as_secs_f64() * 1e3
        );
        assert!(
            after < CNC_POLL + Duration::from_millis(500),
            "{intrusion}: light off {after:?} after the intrusion"
        );
        assert!(s.shutdown.laser_off_ok, "{intrusion}: {:?}", s.shutdown);
        assert!(!sim.laser.state().emission, "{intrusion}");
    }
    // The simulators' other helper is for the executor tests.
    let _ = common::connect;
}
