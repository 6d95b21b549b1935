//! Device clients against their simulators over real transports: the galvo on loopback TCP,
//! the laser on a pseudo-terminal opened as a serial port, the CNC simulator's linuxcncrsh.

use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use tokio::net::TcpStream;
use tokio_util::codec::Framed;
use trim_cell::job::Pose;
use trim_io::cnc::linuxcnc::{LinuxCnc, LinuxCncConfig};
use trim_io::cnc::{Cnc, CncFault, EnableSteps};
use trim_io::galvo::protocol::{
    ControllerState, Frame, FrameCodec, ListCommand, REPLY_BIT, Request, StatusCode, split_reply,
};
use trim_io::galvo::{GalvoClient, GalvoClientConfig, GalvoError};
use trim_io::laser::{LaserClient, LaserError, LaserFault, Profile};
use trim_io::tap::Tap;
use trim_sim::cnc::{CncSim, CncSimConfig};
use trim_sim::fault::{Fault, FaultKind, FaultSwitch, Trigger};
use trim_sim::galvo::{GalvoSim, GalvoSimConfig, Lit};
use trim_sim::laser::LaserSim;
use trim_sim::safety::{CellEvent, SafetyMonitor};

const LO: ([u8; 4], u16) = ([127, 0, 0, 1], 0);
/// Liveness bound for things that happen within a few ms on an idle machine.
const GENEROUS: Duration = Duration::from_secs(5);

async fn galvo_sim(faults: FaultSwitch, monitor: SafetyMonitor) -> GalvoSim {
    GalvoSim::start(
        LO.into(),
        GalvoSimConfig {
            time_scale: 0.0,
            ..GalvoSimConfig::default()
        },
        monitor,
        faults,
    )
    .await
    .expect("galvo simulator")
}

fn square(tag_offset: i32) -> Vec<ListCommand> {
    vec![
        ListCommand::Speeds {
            jump_bits_per_ms: 20_000.0,
            mark_bits_per_ms: 4000.0,
        },
        ListCommand::Jump {
            x: tag_offset,
            y: 0,
        },
        ListCommand::Mark {
            x: tag_offset + 1000,
            y: 0,
        },
        ListCommand::Mark {
            x: tag_offset + 1000,
            y: 1000,
        },
    ]
}

async fn wait_idle(c: &GalvoClient) -> trim_io::galvo::protocol::StatusBlock {
    let t = Instant::now();
    loop {
        let s = c.status().await.expect("link").expect("status");
        if s.state != ControllerState::Executing {
            return s;
        }
        assert!(t.elapsed() < GENEROUS, "list never ended");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

#[tokio::test]
async fn galvo_resend_with_the_same_sequence_number_is_executed_once() {
    let sim = galvo_sim(FaultSwitch::default(), SafetyMonitor::new()).await;
    let stream = TcpStream::connect(sim.addr()).await.unwrap();
    let mut f = Framed::new(stream, FrameCodec);
    let send = |req: Request, seq: u32| Frame {
        crc: true,
        sequence: seq,
        frame_type: req.frame_type(),
        payload: req.encode_payload(),
    };
    f.send(send(
        Request::Hello {
            heartbeat_timeout_ms: 0,
        },
        1,
    ))
    .await
    .unwrap();
    f.next().await.unwrap().unwrap();
    f.send(send(
        Request::LoadList {
            list: 0,
            tag: 7,
            commands: square(0),
        },
        2,
    ))
    .await
    .unwrap();
    f.next().await.unwrap().unwrap();
    let append = Request::AppendList {
        list: 0,
        commands: vec![ListCommand::Mark { x: 0, y: 0 }],
    };
    f.send(send(append.clone(), 3)).await.unwrap();
    let first = f.next().await.unwrap().unwrap();
    // The same frame again (as after a lost reply): the cached reply, not a second append.
    f.send(send(append, 3)).await.unwrap();
    let second = f.next().await.unwrap().unwrap();
    assert_eq!(first, second);
    assert_eq!(first.frame_type, 0x0011 | REPLY_BIT);
    let (code, data) = split_reply(&first.payload).unwrap();
    assert_eq!(code, StatusCode::Ok);
    assert_eq!(data, 5_u32.to_le_bytes());
    assert_eq!(sim.status().loaded, [5, 0]);
    // A bad frame is answered BAD_FRAME and the connection closed.
    let mut bytes = trim_io::galvo::protocol::encode_frame(&send(Request::Status, 4));
    bytes[17] ^= 1; // the CRC
    tokio::io::AsyncWriteExt::write_all(f.get_mut(), &bytes)
        .await
        .unwrap();
    let rep = f.next().await.unwrap().unwrap();
    assert_eq!(split_reply(&rep.payload).unwrap().0, StatusCode::BadFrame);
    assert!(
        f.next().await.is_none(),
        "connection not closed after a bad frame"
    );
}

#[tokio::test]
async fn galvo_two_list_buffers_and_refusals() {
    let monitor = SafetyMonitor::new();
    let sim = GalvoSim::start(
        LO.into(),
        GalvoSimConfig {
            time_scale: 1000.0,
            ..GalvoSimConfig::default()
        },
        monitor.clone(),
        FaultSwitch::default(),
    )
    .await
    .unwrap();
    let c = GalvoClient::connect(sim.addr(), GalvoClientConfig::default(), Tap::none())
        .await
        .unwrap()
        .unwrap();
    c.load_list(0, 1, &square(0)).await.unwrap().unwrap();
    let refused = c.execute(0).await.unwrap().unwrap_err();
    assert_eq!(refused.code, StatusCode::SignalsOff);
    c.laser_signals(true).await.unwrap().unwrap();
    assert_eq!(
        c.execute(1).await.unwrap().unwrap_err().code,
        StatusCode::ListEmpty
    );
    c.execute(0).await.unwrap().unwrap();
    // While list 0 runs (1000× slow: 0.5 s), list 1 loads; list 0 itself is busy.
    assert_eq!(
        c.load_list(0, 9, &square(0))
            .await
            .unwrap()
            .unwrap_err()
            .code,
        StatusCode::ListBusy
    );
    c.load_list(1, 2, &square(5000)).await.unwrap().unwrap();
    assert_eq!(
        c.execute(1).await.unwrap().unwrap_err().code,
        StatusCode::ListBusy
    );
    let s = wait_idle(&c).await;
    assert_eq!((s.list, s.tag, s.marks_done, s.commands_done), (0, 1, 2, 4));
    c.execute(1).await.unwrap().unwrap();
    let s = wait_idle(&c).await;
    assert_eq!((s.list, s.tag, s.marks_done), (1, 2, 2));
    // Out of field.
    let far = vec![ListCommand::Mark { x: i32::MAX, y: 0 }];
    let small = GalvoSim::start(
        LO.into(),
        GalvoSimConfig {
            half_field_bits: 1000,
            time_scale: 0.0,
            ..GalvoSimConfig::default()
        },
        SafetyMonitor::new(),
        FaultSwitch::default(),
    )
    .await
    .unwrap();
    let c2 = GalvoClient::connect(small.addr(), GalvoClientConfig::default(), Tap::none())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(
        c2.load_list(0, 1, &far).await.unwrap().unwrap_err().code,
        StatusCode::OutOfField
    );
    // Unwired laser: marks count as lit; the recorded vectors are the list's.
    let marks = sim.marks();
    assert_eq!(marks.len(), 4);
    assert!(marks.iter().all(|m| m.lit == Lit::Full));
    assert_eq!(marks[2].from_bits, [5000, 0]);
    assert_eq!(marks[2].to_bits, [6000, 0]);
    // Modelled time: 2 lists of jump + 2 marks (timing model, no delays set).
    let one = |off: f64| off / 20_000.0 + 1000.0 / 4000.0 * 2.0;
    let expected_s = (one(0.0) + one(5000.0)) * 1e-3;
    assert!(
        (sim.elapsed_s() - expected_s).abs() < 1e-9,
        "{} vs {expected_s}",
        sim.elapsed_s()
    );
    // Nothing here breaks an interlock: the gate opens only while a list marks.
    assert!(
        monitor.violations().is_empty(),
        "{:?}",
        monitor.violations()
    );
}

#[tokio::test]
async fn the_monitor_reports_a_provoked_violation_from_the_device_simulators() {
    // The interlock checks in this file assert no violation; this shows the same monitor, fed
    // by the simulators, does report one when the devices are driven in a wrong order: laser
    // emission on, then a CNC move.
    let monitor = SafetyMonitor::new();
    let profile = Profile::builtin("monaco").unwrap();
    let laser = LaserSim::start(profile.clone(), monitor.clone(), FaultSwitch::default()).unwrap();
    let cnc = CncSim::start(
        LO.into(),
        CncSimConfig {
            time_scale: 0.05,
            ..CncSimConfig::default()
        },
        monitor.clone(),
        FaultSwitch::default(),
    )
    .await
    .unwrap();
    let mut l = open(&laser, &profile);
    let mut c = LinuxCnc::connect(cnc.addr(), LinuxCncConfig::default(), Tap::none())
        .await
        .unwrap()
        .unwrap();
    c.enable(EnableSteps::ALL).await.unwrap().unwrap();
    l.emission(true).await.unwrap().unwrap();
    assert!(monitor.violations().is_empty());
    let mut pose = Pose::default();
    pose.0.insert("x".into(), 5.0);
    c.start_move(&pose).await.unwrap().unwrap();
    c.wait_in_position(Duration::from_secs(5))
        .await
        .unwrap()
        .unwrap();
    l.emission(false).await.unwrap().unwrap();
    let v = monitor.violations();
    assert_eq!(v.len(), 1, "{v:?}");
    assert_eq!(v[0].what, "laser emission enabled while the CNC moves");
}

#[tokio::test]
async fn galvo_heartbeat_loss_drops_the_laser_signals_and_latches() {
    let monitor = SafetyMonitor::new();
    let sim = GalvoSim::start(
        LO.into(),
        GalvoSimConfig {
            time_scale: 1.0,
            ..GalvoSimConfig::default()
        },
        monitor.clone(),
        FaultSwitch::default(),
    )
    .await
    .unwrap();
    // A raw session with a 100 ms heartbeat that then goes silent mid-list.
    let stream = TcpStream::connect(sim.addr()).await.unwrap();
    let mut f = Framed::new(stream, FrameCodec);
    let mut seq = 0;
    let mut req = |r: Request| {
        seq += 1;
        Frame {
            crc: false,
            sequence: seq,
            frame_type: r.frame_type(),
            payload: r.encode_payload(),
        }
    };
    for r in [
        Request::Hello {
            heartbeat_timeout_ms: 100,
        },
        Request::LaserSignals { enable: true },
        // 200 mm of marking at 1000 bits/ms with 10 000 bits/mm: 2 s.
        Request::LoadList {
            list: 0,
            tag: 3,
            commands: vec![
                ListCommand::Speeds {
                    jump_bits_per_ms: 1000.0,
                    mark_bits_per_ms: 1000.0,
                },
                ListCommand::Mark { x: 2_000_000, y: 0 },
            ],
        },
        Request::Execute { list: 0 },
    ] {
        f.send(req(r)).await.unwrap();
        let rep = f.next().await.unwrap().unwrap();
        assert_eq!(split_reply(&rep.payload).unwrap().0, StatusCode::Ok);
    }
    let silent_from = Instant::now();
    let t = Instant::now();
    while sim.status().state != ControllerState::WatchdogTrip {
        assert!(t.elapsed() < GENEROUS, "no watchdog trip");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let s = sim.status();
    assert!(!s.laser_signals && !s.gate_open);
    let gate_closed = monitor
        .events()
        .iter()
        .find(|(t, e)| *t >= silent_from && *e == CellEvent::Gate(false))
        .map(|(t, _)| *t)
        .expect("gate closed");
    let latency = gate_closed - silent_from;
    eprintln!(
        "heartbeat timeout 100 ms: gate closed {:.1} ms after the host went silent",
        latency.as_secs_f64() * 1e3
    );
    assert!(latency >= Duration::from_millis(100) && latency < GENEROUS);
    // Latched: signals cannot be enabled until RESET_ERROR.
    f.send(req(Request::LaserSignals { enable: true }))
        .await
        .unwrap();
    assert_eq!(
        split_reply(&f.next().await.unwrap().unwrap().payload)
            .unwrap()
            .0,
        StatusCode::Watchdog
    );
    f.send(req(Request::ResetError)).await.unwrap();
    f.next().await.unwrap().unwrap();
    f.send(req(Request::LaserSignals { enable: true }))
        .await
        .unwrap();
    assert_eq!(
        split_reply(&f.next().await.unwrap().unwrap().payload)
            .unwrap()
            .0,
        StatusCode::Ok
    );
    // The client's heartbeat keeps a quiet session alive.
    let c = GalvoClient::connect(
        sim.addr(),
        GalvoClientConfig {
            heartbeat_timeout_ms: 100,
            ..GalvoClientConfig::default()
        },
        Tap::none(),
    )
    .await
    .unwrap()
    .unwrap();
    c.reset_error().await.unwrap().unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert_ne!(
        c.status().await.unwrap().unwrap().state,
        ControllerState::WatchdogTrip
    );
}

#[tokio::test]
async fn galvo_client_reports_stall_garble_and_drop_as_transport_errors() {
    let faults = FaultSwitch::new(vec![Fault {
        kind: FaultKind::Garble,
        trigger: Trigger::Command {
            name: "STATUS".into(),
            nth: 1,
        },
    }]);
    let sim = galvo_sim(faults.clone(), SafetyMonitor::new()).await;
    let cfg = GalvoClientConfig {
        reply_timeout: Duration::from_millis(200),
        heartbeat_timeout_ms: 0,
        ..GalvoClientConfig::default()
    };
    let c = GalvoClient::connect(sim.addr(), cfg, Tap::none())
        .await
        .unwrap()
        .unwrap();
    assert!(matches!(c.status().await, Err(GalvoError::Garbled { .. })));
    assert!(
        matches!(c.status().await, Err(GalvoError::LinkLost { .. })),
        "a garbled link stays down"
    );
    faults.arm(Fault {
        kind: FaultKind::Stall,
        trigger: Trigger::Command {
            name: "STATUS".into(),
            nth: 1,
        },
    });
    faults.clear();
    faults.arm(Fault {
        kind: FaultKind::Stall,
        trigger: Trigger::Command {
            name: "STATUS".into(),
            nth: 1,
        },
    });
    let c = GalvoClient::connect(sim.addr(), cfg, Tap::none())
        .await
        .unwrap()
        .unwrap();
    let t = Instant::now();
    match c.status().await {
        Err(GalvoError::Timeout { attempts, .. }) => assert_eq!(attempts, 2),
        other => panic!("{other:?}"),
    }
    assert!(t.elapsed() >= Duration::from_millis(400));
    faults.clear();
    faults.arm(Fault {
        kind: FaultKind::DropLink,
        trigger: Trigger::Command {
            name: "EXECUTE".into(),
            nth: 1,
        },
    });
    let c = GalvoClient::connect(sim.addr(), cfg, Tap::none())
        .await
        .unwrap()
        .unwrap();
    assert!(matches!(
        c.execute(0).await,
        Err(GalvoError::LinkLost { .. })
    ));
    faults.arm(Fault {
        kind: FaultKind::Refuse,
        trigger: Trigger::Command {
            name: "STOP".into(),
            nth: 1,
        },
    });
    let c = GalvoClient::connect(sim.addr(), cfg, Tap::none())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(
        c.stop().await.unwrap().unwrap_err().code,
        StatusCode::Refused
    );
}

fn open(sim: &LaserSim, profile: &Profile) -> LaserClient {
    LaserClient::open(
        &sim.path().to_string_lossy(),
        profile.clone(),
        Duration::from_millis(500),
        Tap::none(),
    )
    .expect("open the pty")
}

#[tokio::test]
async fn laser_profiles_over_a_pty_serial_port() {
    for name in ["monaco", "ipg"] {
        let profile = Profile::builtin(name).unwrap();
        let monitor = SafetyMonitor::new();
        let sim =
            LaserSim::start(profile.clone(), monitor.clone(), FaultSwitch::default()).unwrap();
        assert!(sim.path().starts_with("/dev/pts"), "{:?}", sim.path());
        let mut c = open(&sim, &profile);
        c.emission(true).await.unwrap().unwrap();
        assert!(sim.state().emission && monitor.emission());
        let st = c.check().await.unwrap().unwrap();
        assert_eq!(st.emission, Some(true));
        assert_eq!(st.key_on, Some(true));
        c.set_power_pct(42.5).await.unwrap().unwrap();
        assert!((sim.state().power_pct - 42.5).abs() < 1e-9);
        assert!(matches!(
            c.set_power_pct(150.0).await.unwrap(),
            Err(LaserFault::Refused { .. })
        ));
        c.emission(false).await.unwrap().unwrap();
        assert!(!sim.state().emission && !monitor.emission());
        // Faults decoded from the profile's tables.
        let (codes, text) = if name == "monaco" {
            (
                vec![3, 22],
                vec![
                    "3: pump diode over temperature",
                    "22: amplifier interlock open",
                ],
            )
        } else {
            (vec![3], vec!["bit 3: high back reflection"])
        };
        sim.set_faults(codes);
        match c.check().await.unwrap() {
            Err(LaserFault::Faults { faults }) => assert_eq!(faults, text),
            other => panic!("{name}: {other:?}"),
        }
        assert!(
            matches!(
                c.emission(true).await.unwrap(),
                Err(LaserFault::Refused { .. })
            ),
            "{name}: emission with a fault"
        );
        sim.set_faults(vec![]);
        sim.set_key(false);
        if name == "monaco" {
            assert_eq!(c.check().await.unwrap(), Err(LaserFault::KeyOff));
        }
        assert!(matches!(
            c.emission(true).await.unwrap(),
            Err(LaserFault::Refused { .. })
        ));
        sim.set_key(true);
        // An unsupported operation of the profile.
        if name == "ipg" {
            assert!(matches!(
                c.command("shutter_open", None).await,
                Err(LaserError::Unsupported { .. })
            ));
        }
        assert!(sim.state().lines_received >= 8);
    }
}

#[tokio::test]
async fn laser_faults_stall_garble_refuse_drop() {
    let profile = Profile::builtin("ipg").unwrap();
    let faults = FaultSwitch::new(vec![
        Fault {
            kind: FaultKind::Garble,
            trigger: Trigger::Command {
                name: "emission_on".into(),
                nth: 1,
            },
        },
        Fault {
            kind: FaultKind::Refuse,
            trigger: Trigger::Command {
                name: "emission_on".into(),
                nth: 2,
            },
        },
        Fault {
            kind: FaultKind::Stall,
            trigger: Trigger::Command {
                name: "emission_on".into(),
                nth: 3,
            },
        },
    ]);
    let sim = LaserSim::start(profile.clone(), SafetyMonitor::new(), faults.clone()).unwrap();
    let mut c = open(&sim, &profile);
    match c.emission(true).await {
        Err(LaserError::BadReply { reply, .. }) => assert!(reply.contains('#'), "{reply:?}"),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        c.emission(true).await.unwrap(),
        Err(LaserFault::Refused { .. })
    ));
    assert!(matches!(
        c.emission(true).await,
        Err(LaserError::Timeout { .. })
    ));
    assert!(!sim.state().emission);
    faults.clear();
    faults.arm(Fault {
        kind: FaultKind::DropLink,
        trigger: Trigger::Command {
            name: "status".into(),
            nth: 1,
        },
    });
    drop(c); // the port is opened exclusively (TIOCEXCL), as a real serial port
    let mut c = open(&sim, &profile);
    c.emission(true).await.unwrap().unwrap();
    assert!(matches!(c.check().await, Err(LaserError::Timeout { .. })));
    // The cable stays pulled until the faults are cleared.
    drop(c);
    let mut c2 = open(&sim, &profile);
    assert!(matches!(
        c2.emission(false).await,
        Err(LaserError::Timeout { .. })
    ));
    faults.clear();
    drop(c2);
    let mut c3 = open(&sim, &profile);
    c3.emission(false).await.unwrap().unwrap();
}

#[tokio::test]
async fn cnc_client_against_the_linuxcncrsh_simulator() {
    let monitor = SafetyMonitor::new();
    let sim = CncSim::start(
        LO.into(),
        CncSimConfig {
            time_scale: 0.05,
            ..CncSimConfig::default()
        },
        monitor.clone(),
        FaultSwitch::default(),
    )
    .await
    .unwrap();
    let mut c = LinuxCnc::connect(sim.addr(), LinuxCncConfig::default(), Tap::none())
        .await
        .unwrap()
        .unwrap();
    // The machine starts as after power-up: in E-stop, off, unhomed. Preparing it refuses each
    // step the operator did not allow, naming the state, and changes nothing.
    let refusal = |r: Result<(), CncFault>| match r {
        Err(CncFault::NotReady { state, remedy }) => format!("{state}: {remedy}"),
        other => panic!("not refused: {other:?}"),
    };
    let why = refusal(c.enable(EnableSteps::default()).await.unwrap());
    assert!(
        why.starts_with("in E-stop") && why.contains("--enable-machine"),
        "{why}"
    );
    assert_eq!(
        sim.machine_state(),
        (true, false, false),
        "changed while refusing"
    );
    let power_only = EnableSteps {
        enable_machine: true,
        home: false,
    };
    let why = refusal(c.enable(power_only).await.unwrap());
    assert!(
        why.starts_with("not homed") && why.contains("--home"),
        "{why}"
    );
    assert_eq!(
        sim.machine_state(),
        (true, false, false),
        "changed while refusing"
    );
    c.enable(EnableSteps::ALL).await.unwrap().unwrap();
    assert_eq!(sim.machine_state(), (false, true, true));
    assert!(sim.tcp_kinematics());
    // Enabling again does not home again (that would queue "must be in joint mode to home"),
    // and a ready machine needs no step allowed.
    c.enable(EnableSteps::default()).await.unwrap().unwrap();
    // Switched off (E-stop released) is refused too.
    sim.set_estop(false);
    let why = refusal(c.enable(EnableSteps::default()).await.unwrap());
    assert!(why.starts_with("switched off"), "{why}");
    c.enable(power_only).await.unwrap().unwrap();
    assert!(c.errors().await.unwrap().unwrap().is_empty());
    let mut p = Pose::default();
    for (k, v) in [
        ("x", 10.0),
        ("y", 20.0),
        ("z", -5.0),
        ("a", 15.0),
        ("c", 30.0),
    ] {
        p.0.insert(k.into(), v);
    }
    c.start_move(&p).await.unwrap().unwrap();
    let reached = c.wait_in_position(GENEROUS).await.unwrap().unwrap();
    assert_eq!(reached.world, p, "B padding dropped, the rest reached");
    assert_eq!(sim.position(), [10.0, 20.0, -5.0, 15.0, 0.0, 30.0]);
    let moves: Vec<bool> = monitor
        .events()
        .iter()
        .filter_map(|(_, e)| match e {
            CellEvent::CncMoving(m) => Some(*m),
            _ => None,
        })
        .collect();
    assert_eq!(moves, vec![true, false]);
    p.0.insert("x".into(), 500.0);
    c.start_move(&p).await.unwrap().unwrap();
    match c.wait_in_position(GENEROUS).await.unwrap() {
        Err(CncFault::Refused { errors, .. }) => assert!(
            errors.iter().any(|e| e.contains("X's positive limit")),
            "{errors:?}"
        ),
        other => panic!("{other:?}"),
    }
    p.0.insert("q".into(), 1.0);
    assert!(matches!(
        c.start_move(&p).await.unwrap(),
        Err(CncFault::BadPose(_))
    ));
    c.estop().await.unwrap().unwrap();
}
