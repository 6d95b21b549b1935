//! A simulator of the `linuxcncrsh` protocol subset the client uses, for fast tests: the
//! xyzac-trt sim machine's limits and maximum speeds (20 mm/s, 30 °/s), motion in (scaled) real
//! time reported to the [`SafetyMonitor`], the quirks of LINUXCNC.md §3.9 (`set` silent unless
//! verbose, `\n\r` after `set` replies, padded arrays, popped error queue), and fault injection.
//! Kinematics are not modelled: joint positions equal world positions.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

use crate::fault::{FaultKind, FaultSwitch};
use crate::safety::{CellEvent, SafetyMonitor};

/// Axis order of the simulated machine's positions (X Y Z A B C, B always 0).
const AXIS_LETTERS: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];
/// Motion update period (ms).
const MOTION_TICK_MS: u64 = 2;

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct CncSimConfig {
    /// Axis limits (min, max) for X Y Z A B C (mm, degrees). A and B have the same travel, so
    /// one simulator serves A/C and B/C jobs (`[machine] a_limits_deg`, `b_limits_deg`).
    pub limits: [(f64, f64); 6],
    /// Maximum linear speed (mm/s).
    pub max_linear_mm_per_s: f64,
    /// Maximum rotary speed (deg/s).
    pub max_rotary_deg_per_s: f64,
    /// Real seconds per simulated second (0 = moves are instant).
    pub time_scale: f64,
    /// Start out of E-stop, on and homed (the built-in simulated cell of `trimctl run`'s demo);
    /// else in E-stop, off and not homed, as a real machine after power-up.
    pub start_ready: bool,
}

impl Default for CncSimConfig {
    fn default() -> Self {
        CncSimConfig {
            limits: [
                (-200.0, 200.0),
                (-100.0, 100.0),
                (-120.0, 120.0),
                (-100.0, 50.0),
                (-100.0, 50.0),
                (-36000.0, 36000.0),
            ],
            max_linear_mm_per_s: 20.0,
            max_rotary_deg_per_s: 30.0,
            time_scale: 1.0,
            start_ready: false,
        }
    }
}

#[derive(Debug)]
struct Machine {
    estop: bool,
    on: bool,
    homed: bool,
    mode: String,
    tcp: bool,
    pos: [f64; 6],
    motion_id: u64,
    moving: bool,
    last_failed: bool,
    errors: VecDeque<String>,
    set_wait_done: bool,
    moves: u64,
}

struct Shared {
    config: CncSimConfig,
    m: Mutex<Machine>,
    monitor: SafetyMonitor,
    faults: FaultSwitch,
    conns: Mutex<Vec<JoinHandle<()>>>,
}

impl Shared {
    fn m(&self) -> MutexGuard<'_, Machine> {
        self.m
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// A running CNC simulator. Dropping it stops the server.
pub struct CncSim {
    addr: SocketAddr,
    shared: Arc<Shared>,
    accept: JoinHandle<()>,
}

impl Drop for CncSim {
    fn drop(&mut self) {
        self.accept.abort();
        for c in self
            .shared
            .conns
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .drain(..)
        {
            c.abort();
        }
    }
}

impl CncSim {
    /// Starts a simulator on `bind` (port 0: any free port). The machine starts in estop,
    /// not homed (or out of E-stop, on and homed with [`CncSimConfig::start_ready`]), identity
    /// kinematics, at 0.
    pub async fn start(
        bind: SocketAddr,
        config: CncSimConfig,
        monitor: SafetyMonitor,
        faults: FaultSwitch,
    ) -> std::io::Result<CncSim> {
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let ready = config.start_ready;
        let shared = Arc::new(Shared {
            config,
            m: Mutex::new(Machine {
                estop: !ready,
                on: ready,
                homed: ready,
                mode: "MANUAL".into(),
                tcp: false,
                pos: [0.0; 6],
                motion_id: 0,
                moving: false,
                last_failed: false,
                errors: VecDeque::new(),
                set_wait_done: false,
                moves: 0,
            }),
            monitor,
            faults,
            conns: Mutex::new(Vec::new()),
        });
        let s = shared.clone();
        let accept = tokio::spawn(async move {
            while let Ok((stream, _)) = listener.accept().await {
                let t = tokio::spawn(serve(stream, s.clone()));
                let mut conns = s
                    .conns
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                conns.retain(|c| !c.is_finished());
                conns.push(t);
            }
        });
        Ok(CncSim {
            addr,
            shared,
            accept,
        })
    }

    /// The address it listens on.
    #[must_use]
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The fault switch.
    #[must_use]
    pub fn faults(&self) -> &FaultSwitch {
        &self.shared.faults
    }

    /// The position now: X Y Z A B C.
    #[must_use]
    pub fn position(&self) -> [f64; 6] {
        self.shared.m().pos
    }

    /// Moves started so far.
    #[must_use]
    pub fn moves(&self) -> u64 {
        self.shared.m().moves
    }

    /// Puts the machine in E-stop (as its button would: motion stops, the machine goes off),
    /// or leaves the E-stop released and the machine off.
    pub fn set_estop(&self, on: bool) {
        let mut m = self.shared.m();
        m.estop = on;
        m.on = false;
        stop_motion(&self.shared, &mut m);
    }

    /// Marks the joints unhomed (as after a power cycle of the control).
    pub fn set_unhomed(&self) {
        self.shared.m().homed = false;
    }

    /// The machine's state: (E-stop, on, homed).
    #[must_use]
    pub fn machine_state(&self) -> (bool, bool, bool) {
        let m = self.shared.m();
        (m.estop, m.on, m.homed)
    }

    /// Whether TCP kinematics (M428) is active.
    #[must_use]
    pub fn tcp_kinematics(&self) -> bool {
        self.shared.m().tcp
    }

    /// A handle that reads the position `[X, Y, Z, A, B, C]` and the TCP mode, for the
    /// digital twin.
    #[must_use]
    pub fn pose_source(&self) -> crate::twin::PoseSource {
        let shared = Arc::clone(&self.shared);
        Box::new(move || {
            let m = shared.m();
            (m.pos, m.tcp)
        })
    }
}

struct Session {
    echo: bool,
    verbose: bool,
    hello: bool,
    enabled: bool,
}

async fn serve(mut stream: TcpStream, shared: Arc<Shared>) {
    let _ = stream.set_nodelay(true);
    let mut session = Session {
        echo: true,
        verbose: false,
        hello: false,
        enabled: false,
    };
    let mut buf = BytesBuf::default();
    let mut chunk = [0_u8; 1024];
    loop {
        let n = match stream.read(&mut chunk).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        buf.0.extend_from_slice(&chunk[..n]);
        while let Some(line) = buf.next_line() {
            // linuxcncrsh echoes lines only once linked (after `hello`), while echo is on.
            if session.echo && session.hello {
                let _ = stream.write_all(format!("{line}\r\n").as_bytes()).await;
            }
            let key = fault_key(&line);
            match shared.faults.on_command(&key) {
                Some(FaultKind::DropLink) => return,
                Some(FaultKind::Stall) => {
                    shared.faults.wait_released().await;
                    return;
                }
                Some(FaultKind::DropOne) => continue,
                Some(FaultKind::Garble) => {
                    let _ = stream.write_all(b"\x07?!GARBLE \x01\r\n").await;
                    continue;
                }
                Some(FaultKind::Refuse) => {
                    if line.starts_with("set") {
                        let w = line
                            .split_whitespace()
                            .nth(1)
                            .unwrap_or_default()
                            .to_uppercase();
                        shared
                            .m()
                            .errors
                            .push_back("refused (fault injection)".into());
                        let _ = stream
                            .write_all(format!("SET {w} NAK\n\r").as_bytes())
                            .await;
                    } else {
                        let _ = stream.write_all(b"NAK\r\n").await;
                    }
                    continue;
                }
                None => {}
            }
            let reply = handle(&shared, &mut session, &line).await;
            match reply {
                Reply::Get(r) => {
                    if stream
                        .write_all(format!("{r}\r\n").as_bytes())
                        .await
                        .is_err()
                    {
                        return;
                    }
                }
                Reply::Set { word, ok } => {
                    if session.verbose {
                        let r = format!("SET {} {}\n\r", word, if ok { "ACK" } else { "NAK" });
                        if stream.write_all(r.as_bytes()).await.is_err() {
                            return;
                        }
                    }
                }
                Reply::Close => return,
            }
        }
    }
}

#[derive(Default)]
struct BytesBuf(Vec<u8>);

impl BytesBuf {
    fn next_line(&mut self) -> Option<String> {
        loop {
            let pos = self.0.iter().position(|&b| b == b'\r' || b == b'\n')?;
            let line: Vec<u8> = self.0.drain(..=pos).take(pos).collect();
            let line = String::from_utf8_lossy(&line).trim().to_owned();
            if !line.is_empty() {
                return Some(line);
            }
        }
    }
}

/// The name a line counts under for fault triggers: `hello`, or the word after `set`/`get`
/// (`mdi`, `wait`, `abs_act_pos`, ...).
#[must_use]
pub fn fault_key(line: &str) -> String {
    let mut w = line.split_whitespace();
    match w.next() {
        Some(first) if first.eq_ignore_ascii_case("set") || first.eq_ignore_ascii_case("get") => {
            w.next().unwrap_or_default().to_lowercase()
        }
        Some(first) => first.to_lowercase(),
        None => String::new(),
    }
}

enum Reply {
    Get(String),
    Set { word: String, ok: bool },
    Close,
}

async fn handle(shared: &Arc<Shared>, s: &mut Session, line: &str) -> Reply {
    let words: Vec<&str> = line.split_whitespace().collect();
    let first = words.first().map(|w| w.to_lowercase()).unwrap_or_default();
    match first.as_str() {
        "hello" => {
            if words.get(1) == Some(&"EMC") {
                s.hello = true;
                Reply::Get("HELLO ACK EMCNETSVR 1.1".into())
            } else {
                Reply::Get("HELLO NAK".into())
            }
        }
        "quit" | "shutdown" => Reply::Close,
        "get" if s.hello => Reply::Get(get(shared, &words[1..])),
        "set" if s.hello => {
            let word = words.get(1).map(|w| w.to_uppercase()).unwrap_or_default();
            let ok = set(shared, s, &words[1..]).await;
            Reply::Set { word, ok }
        }
        _ => Reply::Get(format!("{} NAK", first.to_uppercase())),
    }
}

fn yes(b: bool) -> &'static str {
    if b { "YES" } else { "NO" }
}

fn get(shared: &Arc<Shared>, args: &[&str]) -> String {
    let what = args.first().map(|w| w.to_lowercase()).unwrap_or_default();
    let mut m = shared.m();
    match what.as_str() {
        "error" => match m.errors.pop_front() {
            Some(e) => format!("ERROR {e}"),
            None => "ERROR OK".into(),
        },
        "joint_homed" => format!("JOINT_HOMED {0} {0} {0} {0} {0} NO", yes(m.homed)),
        "abs_act_pos" | "abs_cmd_pos" => {
            let p = m.pos;
            format!(
                "{} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6}",
                what.to_uppercase(),
                p[0],
                p[1],
                p[2],
                p[3],
                p[4],
                p[5]
            )
        }
        "joint_pos" => {
            let p = m.pos;
            format!(
                "JOINT_POS {:.6} {:.6} {:.6} {:.6} {:.6} 0.000000",
                p[0], p[1], p[2], p[3], p[5]
            )
        }
        "estop" => format!("ESTOP {}", if m.estop { "ON" } else { "OFF" }),
        "machine" => format!("MACHINE {}", if m.on { "ON" } else { "OFF" }),
        "mode" => format!("MODE {}", m.mode),
        "program_status" => format!(
            "PROGRAM_STATUS {}",
            if m.moving { "RUNNING" } else { "IDLE" }
        ),
        other => format!("{} NAK", other.to_uppercase()),
    }
}

async fn set(shared: &Arc<Shared>, s: &mut Session, args: &[&str]) -> bool {
    let what = args.first().map(|w| w.to_lowercase()).unwrap_or_default();
    let arg = |i: usize| args.get(i).map(|w| w.to_lowercase()).unwrap_or_default();
    // Each `set` takes a moment on LinuxCNC; a short one here keeps ordering realistic.
    match what.as_str() {
        "echo" => {
            s.echo = arg(1) == "on";
            true
        }
        "verbose" => {
            s.verbose = arg(1) == "on";
            true
        }
        "enable" => {
            s.enabled = args.get(1) == Some(&"EMCTOO");
            s.enabled
        }
        _ if !s.enabled => false,
        "set_wait" => {
            shared.m().set_wait_done = arg(1) == "done";
            true
        }
        "timeout" => true,
        "estop" => {
            let on = arg(1) == "on";
            let mut m = shared.m();
            m.estop = on;
            if on {
                m.on = false;
                stop_motion(shared, &mut m);
            }
            true
        }
        "machine" => {
            let on = arg(1) == "on";
            let mut m = shared.m();
            if on && m.estop {
                m.errors
                    .push_back("can't turn machine on while in estop".into());
                return false;
            }
            m.on = on;
            true
        }
        "mode" => {
            shared.m().mode = arg(1).to_uppercase();
            true
        }
        "home" => {
            let mut m = shared.m();
            if m.homed && m.mode != "MANUAL" {
                m.errors.push_back("must be in joint mode to home".into());
                return false;
            }
            if !m.on {
                m.errors.push_back("machine is off".into());
                return false;
            }
            m.homed = true;
            true
        }
        "abort" => {
            let mut m = shared.m();
            stop_motion(shared, &mut m);
            true
        }
        "wait" => loop {
            {
                let m = shared.m();
                if !m.moving {
                    return !m.last_failed;
                }
            }
            tokio::time::sleep(Duration::from_millis(MOTION_TICK_MS)).await;
        },
        "mdi" => {
            let code = args[1..].join(" ");
            mdi(shared, &code)
        }
        _ => false,
    }
}

fn stop_motion(shared: &Arc<Shared>, m: &mut Machine) {
    m.motion_id += 1;
    if m.moving {
        m.moving = false;
        shared.monitor.report(CellEvent::CncMoving(false));
    }
}

/// Executes an MDI line: `M428`, `M429`, or `G0` with axis words.
fn mdi(shared: &Arc<Shared>, code: &str) -> bool {
    let mut m = shared.m();
    if !m.on || !m.homed || m.mode != "MDI" {
        m.errors
            .push_back("MDI needs the machine on, homed, in MDI mode".into());
        m.last_failed = true;
        return false;
    }
    let upper = code.to_uppercase();
    let words: Vec<&str> = upper.split_whitespace().collect();
    m.last_failed = false;
    match words.first().copied() {
        Some("M428") => {
            m.tcp = true;
            return true;
        }
        Some("M429") => {
            m.tcp = false;
            return true;
        }
        Some("G0") => {}
        _ => {
            m.errors.push_back(format!("unknown MDI {code:?}"));
            m.last_failed = true;
            return true; // received; `wait done` reports the failure
        }
    }
    let mut target = m.pos;
    for w in &words[1..] {
        let mut chars = w.chars();
        let letter = chars.next().unwrap_or(' ');
        let Some(i) = AXIS_LETTERS.iter().position(|&c| c == letter) else {
            m.errors.push_back(format!("bad word {w}"));
            m.last_failed = true;
            return true;
        };
        match chars.as_str().parse::<f64>() {
            Ok(v) => target[i] = v,
            Err(_) => {
                m.errors.push_back(format!("bad number in {w}"));
                m.last_failed = true;
                return true;
            }
        }
    }
    for i in 0..6 {
        let (lo, hi) = shared.config.limits[i];
        if target[i] < lo - 1e-9 || target[i] > hi + 1e-9 {
            let side = if target[i] > hi {
                "positive"
            } else {
                "negative"
            };
            m.errors.push_back(format!(
                "Linear move on line 0 would exceed {}'s {side} limit",
                AXIS_LETTERS[i]
            ));
            m.errors
                .push_back("invalid params in linear command".into());
            m.last_failed = true;
            return true;
        }
    }
    let from = m.pos;
    let mut duration_s: f64 = 0.0;
    for i in 0..6 {
        let v = if i < 3 {
            shared.config.max_linear_mm_per_s
        } else {
            shared.config.max_rotary_deg_per_s
        };
        duration_s = duration_s.max((target[i] - from[i]).abs() / v);
    }
    m.motion_id += 1;
    m.moves += 1;
    let id = m.motion_id;
    if !m.moving {
        m.moving = true;
        shared.monitor.report(CellEvent::CncMoving(true));
    }
    drop(m);
    let shared = shared.clone();
    let real = Duration::from_secs_f64(duration_s * shared.config.time_scale.max(0.0));
    tokio::spawn(async move {
        let start = Instant::now();
        loop {
            let t = if real.is_zero() {
                1.0
            } else {
                (start.elapsed().as_secs_f64() / real.as_secs_f64()).min(1.0)
            };
            {
                let mut m = shared.m();
                if m.motion_id != id {
                    return;
                }
                for i in 0..6 {
                    m.pos[i] = from[i] + (target[i] - from[i]) * t;
                }
                if t >= 1.0 {
                    m.pos = target;
                    m.moving = false;
                    shared.monitor.report(CellEvent::CncMoving(false));
                    return;
                }
            }
            tokio::time::sleep(Duration::from_millis(MOTION_TICK_MS)).await;
        }
    });
    true
}
