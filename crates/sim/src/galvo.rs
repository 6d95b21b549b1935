//! A galvo controller simulator that implements docs/protocols/galvo.md on a TCP port: two list
//! buffers, the timing model as its clock, the reply cache for resends, the heartbeat watchdog,
//! a record of every vector it marked (with whether light reached the part), the pointer and
//! red-light framing (§5a: a record of every vector traced, with the pointer, the gate and the
//! laser's emission during it), and fault injection.

use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio_util::codec::Framed;

use crate::fault::{FaultKind, FaultSwitch};
use crate::safety::{CellEvent, SafetyMonitor};
use trim_io::galvo::list_clock::ListClock;
use trim_io::galvo::protocol::{
    ControllerState, Frame, FrameBlock, FrameCodec, FrameError, ListCommand, NO_LIST,
    REPLY_CACHE_LEN, Request, StatusBlock, StatusCode, decode_frame, reply_frame, type_name,
};

/// How often the watchdog looks at the link (ms).
const WATCHDOG_TICK_MS: u64 = 5;
/// The longest a stalled connection is held before it is closed (s).
const STALL_HOLD_S: u64 = 600;
/// Traced vectors kept in the record ([`GalvoSim::traces`]); later ones are counted only.
pub const TRACE_RECORD_CAP: usize = 100_000;
/// The shortest real time of one frame pass (ms): an endless trace must not spin, however fast
/// its clock runs.
const MIN_PASS_MS: u64 = 1;

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct GalvoSimConfig {
    /// Half the field in bits: coordinates beyond ±this are refused with `OUT_OF_FIELD`.
    pub half_field_bits: i64,
    /// Real seconds per modelled second (1 = real time; 0 = as fast as possible).
    pub time_scale: f64,
    /// Largest number of commands a list holds.
    pub list_capacity: u32,
    /// The digital twin that lands every lit vector on the true part, if any.
    pub twin: Option<std::sync::Arc<crate::twin::Twin>>,
}

impl Default for GalvoSimConfig {
    fn default() -> Self {
        GalvoSimConfig {
            half_field_bits: 1 << 30,
            time_scale: 1.0,
            list_capacity: 1 << 20,
            twin: None,
        }
    }
}

/// Whether light reached the part during a marked vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Lit {
    /// The light path was open for the whole vector.
    Full,
    /// The light path changed during the vector: partly marked.
    Partial,
    /// No light: the mirrors moved, nothing was marked.
    Dry,
}

/// One `MARK` vector the simulator executed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct MarkRecord {
    /// The tag of the list.
    pub tag: u32,
    /// Start (bits).
    pub from_bits: [i32; 2],
    /// End (bits).
    pub to_bits: [i32; 2],
    /// Light during the vector.
    pub lit: Lit,
}

/// One `MARK` record the simulator traced in a frame (`EXECUTE_FRAME`): the mirrors moved with
/// the pointer; what the process laser's light path was doing meanwhile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct TraceRecord {
    /// The tag of the list.
    pub tag: u32,
    /// The pass over the list (0-based).
    pub pass: u32,
    /// Start (bits).
    pub from_bits: [i32; 2],
    /// End (bits).
    pub to_bits: [i32; 2],
    /// The pointer was on during the whole vector.
    pub pointer: bool,
    /// The gate was open at some time during the vector (never, by design).
    pub gate_open: bool,
    /// The laser reported emission on at some time during the vector.
    pub emission: bool,
}

#[derive(Debug, Default, Clone)]
struct ListBuf {
    tag: u32,
    commands: Vec<ListCommand>,
}

#[derive(Debug)]
struct Controller {
    lists: [ListBuf; 2],
    state: ControllerState,
    exec_list: u8,
    exec_tag: u32,
    commands_done: u32,
    marks_done: u32,
    laser_signals: bool,
    gate: bool,
    elapsed_ns: f64,
    last_error: u16,
    heartbeat_timeout_ms: u32,
    last_rx: Instant,
    session: bool,
    stop_requested: bool,
    cache: HashMap<u32, Frame>,
    cache_order: VecDeque<u32>,
    garble_next: bool,
    run_id: u64,
    pointer: bool,
    framing: bool,
    frame_list: u8,
    frame_tag: u32,
    passes_done: u32,
    vectors_traced: u32,
}

struct Shared {
    config: GalvoSimConfig,
    ctl: Mutex<Controller>,
    monitor: SafetyMonitor,
    faults: FaultSwitch,
    marks: Mutex<Vec<MarkRecord>>,
    traces: Mutex<Vec<TraceRecord>>,
    conn_task: Mutex<Option<JoinHandle<()>>>,
}

impl Shared {
    fn ctl(&self) -> MutexGuard<'_, Controller> {
        self.ctl
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn set_gate(&self, c: &mut Controller, open: bool) {
        if c.gate != open {
            c.gate = open;
            self.monitor.report(CellEvent::Gate(open));
        }
    }

    /// Ends a running frame at once (`STOP`, a trip): its task sees a newer run and leaves
    /// without touching anything.
    fn end_frame(&self, c: &mut Controller) {
        if c.framing {
            c.framing = false;
            c.run_id += 1;
            c.stop_requested = false;
            self.monitor.report(CellEvent::Framing(false));
        }
    }

    fn set_pointer(&self, c: &mut Controller, on: bool) {
        if c.pointer != on {
            c.pointer = on;
            self.monitor.report(CellEvent::Pointer(on));
        }
    }

    /// Drops the laser signals and stops the list: the watchdog and link-loss reaction.
    fn trip(&self, why: &str) {
        let mut c = self.ctl();
        if !c.session {
            return;
        }
        // A trip that finds the signals off and no list running (the host closed an idle
        // session at the end of a job) changes nothing an operator must see.
        if c.laser_signals || c.pointer || c.state == ControllerState::Executing {
            tracing::warn!(why, "galvo simulator: watchdog trip, laser signals dropped");
        } else {
            tracing::debug!(why, "galvo simulator: idle session ended, watchdog latched");
        }
        c.session = false;
        c.laser_signals = false;
        self.set_gate(&mut c, false);
        self.set_pointer(&mut c, false);
        if c.framing {
            self.end_frame(&mut c);
        } else if c.state == ControllerState::Executing {
            c.stop_requested = true;
        }
        c.state = ControllerState::WatchdogTrip;
        c.last_error = StatusCode::Watchdog.code();
    }
}

/// A running galvo simulator. Dropping it stops the server.
pub struct GalvoSim {
    addr: SocketAddr,
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
}

impl Drop for GalvoSim {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
        if let Some(t) = self
            .shared
            .conn_task
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take()
        {
            t.abort();
        }
    }
}

impl GalvoSim {
    /// Starts a simulator listening on `bind` (use port 0 for any free port).
    pub async fn start(
        bind: SocketAddr,
        config: GalvoSimConfig,
        monitor: SafetyMonitor,
        faults: FaultSwitch,
    ) -> std::io::Result<GalvoSim> {
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            config,
            ctl: Mutex::new(Controller {
                lists: [ListBuf::default(), ListBuf::default()],
                state: ControllerState::Idle,
                exec_list: NO_LIST,
                exec_tag: 0,
                commands_done: 0,
                marks_done: 0,
                laser_signals: false,
                gate: false,
                elapsed_ns: 0.0,
                last_error: 0,
                heartbeat_timeout_ms: 0,
                last_rx: Instant::now(),
                session: false,
                stop_requested: false,
                cache: HashMap::new(),
                cache_order: VecDeque::new(),
                garble_next: false,
                run_id: 0,
                pointer: false,
                framing: false,
                frame_list: NO_LIST,
                frame_tag: 0,
                passes_done: 0,
                vectors_traced: 0,
            }),
            monitor,
            faults,
            marks: Mutex::new(Vec::new()),
            traces: Mutex::new(Vec::new()),
            conn_task: Mutex::new(None),
        });
        let accept = tokio::spawn(accept_loop(listener, shared.clone()));
        let watchdog = tokio::spawn(watchdog_loop(shared.clone()));
        Ok(GalvoSim {
            addr,
            shared,
            tasks: vec![accept, watchdog],
        })
    }

    /// The address it listens on.
    #[must_use]
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Every vector executed so far, in order.
    #[must_use]
    pub fn marks(&self) -> Vec<MarkRecord> {
        self.shared
            .marks
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Every vector traced in frames so far, in order (at most [`TRACE_RECORD_CAP`]).
    #[must_use]
    pub fn traces(&self) -> Vec<TraceRecord> {
        self.shared
            .traces
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Forgets the list it executed last (its status then reports no list, and no marks), as a
    /// restart of the controller leaves it, or a framing list replacing the status's tag: a
    /// resume must then know the cut layer's progress from the journal.
    pub fn forget_list(&self) {
        let mut ctl = self.shared.ctl();
        ctl.exec_list = NO_LIST;
        ctl.exec_tag = 0;
        ctl.marks_done = 0;
        ctl.commands_done = 0;
    }

    /// The current framing block (as a `FRAME_STATUS` request would return it).
    #[must_use]
    pub fn frame_status(&self) -> FrameBlock {
        frame_block(&self.shared.ctl())
    }

    /// The modelled time of all lists executed (s).
    #[must_use]
    pub fn elapsed_s(&self) -> f64 {
        self.shared.ctl().elapsed_ns * 1e-9
    }

    /// The fault switch.
    #[must_use]
    pub fn faults(&self) -> &FaultSwitch {
        &self.shared.faults
    }

    /// The current status block (as a `STATUS` request would return it).
    #[must_use]
    pub fn status(&self) -> StatusBlock {
        status_block(&self.shared.ctl())
    }
}

fn status_block(c: &Controller) -> StatusBlock {
    StatusBlock {
        state: c.state,
        list: c.exec_list,
        tag: c.exec_tag,
        commands_done: c.commands_done,
        marks_done: c.marks_done,
        laser_signals: c.laser_signals,
        gate_open: c.gate,
        elapsed_ns: c.elapsed_ns as u64,
        loaded: [
            u32::try_from(c.lists[0].commands.len()).unwrap_or(u32::MAX),
            u32::try_from(c.lists[1].commands.len()).unwrap_or(u32::MAX),
        ],
        last_error: c.last_error,
    }
}

fn frame_block(c: &Controller) -> FrameBlock {
    FrameBlock {
        pointer: c.pointer,
        framing: c.framing,
        list: c.frame_list,
        tag: c.frame_tag,
        passes_done: c.passes_done,
        vectors_traced: c.vectors_traced,
    }
}

async fn accept_loop(listener: TcpListener, shared: Arc<Shared>) {
    loop {
        let Ok((stream, peer)) = listener.accept().await else {
            continue;
        };
        tracing::debug!(%peer, "galvo simulator: connection");
        let old = shared
            .conn_task
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some(old) = old {
            old.abort();
            shared.trip("connection replaced");
        }
        {
            let mut c = shared.ctl();
            c.cache.clear();
            c.cache_order.clear();
            c.garble_next = false;
        }
        let task = tokio::spawn(serve(stream, shared.clone()));
        *shared
            .conn_task
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(task);
    }
}

async fn watchdog_loop(shared: Arc<Shared>) {
    loop {
        tokio::time::sleep(Duration::from_millis(WATCHDOG_TICK_MS)).await;
        let expired = {
            let c = shared.ctl();
            c.session
                && c.heartbeat_timeout_ms > 0
                && c.last_rx.elapsed() > Duration::from_millis(u64::from(c.heartbeat_timeout_ms))
        };
        if expired {
            shared.trip("heartbeat timeout");
        }
    }
}

async fn serve(stream: TcpStream, shared: Arc<Shared>) {
    let _ = stream.set_nodelay(true);
    let mut framed = Framed::new(stream, FrameCodec);
    loop {
        if shared.faults.stalled() {
            let _ = tokio::time::timeout(
                Duration::from_secs(STALL_HOLD_S),
                shared.faults.wait_released(),
            )
            .await;
            shared.trip("connection closed after a stall");
            return;
        }
        let next = tokio::select! {
            f = framed.next() => f,
            () = tokio::time::sleep(Duration::from_millis(50)) => continue,
        };
        let frame = match next {
            None => {
                shared.trip("connection closed");
                return;
            }
            Some(Ok(f)) => f,
            Some(Err(e)) => {
                // Reply when the header can still be read (the magic is right), then close.
                tracing::warn!(error = %e, "galvo simulator: bad frame, closing");
                let mut buf = framed.read_buffer().clone();
                let header = |b: &bytes::BytesMut| {
                    (b.len() >= 10).then(|| {
                        (
                            u32::from_le_bytes([b[4], b[5], b[6], b[7]]),
                            u16::from_le_bytes([b[8], b[9]]),
                        )
                    })
                };
                let reply = match decode_frame(&mut buf) {
                    Err(FrameError::BadMagic(_)) => None,
                    Err(FrameError::UnsupportedVersion { .. }) => {
                        header(&buf).map(|h| (StatusCode::UnsupportedVersion, h))
                    }
                    _ => header(&buf).map(|h| (StatusCode::BadFrame, h)),
                };
                if let Some((code, (sequence, frame_type))) = reply {
                    let req = Frame {
                        crc: false,
                        sequence,
                        frame_type: frame_type & !trim_io::galvo::protocol::REPLY_BIT,
                        payload: Vec::new(),
                    };
                    let _ = framed
                        .send(reply_frame(&req, code, e.to_string().as_bytes()))
                        .await;
                }
                shared.trip("bad frame");
                return;
            }
        };
        shared.ctl().last_rx = Instant::now();
        let name = type_name(frame.frame_type);
        match shared.faults.on_command(name) {
            Some(FaultKind::DropLink) => {
                shared.trip("link dropped (fault)");
                return;
            }
            Some(FaultKind::Stall | FaultKind::DropOne) => continue,
            Some(FaultKind::Garble) => {
                shared.ctl().garble_next = true;
            }
            Some(FaultKind::Refuse) => {
                let rep = reply_frame(&frame, StatusCode::Refused, b"refused (fault injection)");
                if framed.send(rep).await.is_err() {
                    shared.trip("connection closed");
                    return;
                }
                continue;
            }
            None => {}
        }
        let cached = shared.ctl().cache.get(&frame.sequence).cloned();
        let reply = match cached {
            Some(r) => r,
            None => {
                let r = handle(&shared, &frame);
                let mut c = shared.ctl();
                c.cache.insert(frame.sequence, r.clone());
                c.cache_order.push_back(frame.sequence);
                while c.cache_order.len() > REPLY_CACHE_LEN {
                    if let Some(old) = c.cache_order.pop_front() {
                        c.cache.remove(&old);
                    }
                }
                r
            }
        };
        let garble = std::mem::take(&mut shared.ctl().garble_next);
        let sent = if garble {
            let mut bytes = trim_io::galvo::protocol::encode_frame(&reply);
            bytes[0] ^= 0x5A;
            let last = bytes.len() - 1;
            bytes[last] ^= 0xFF;
            framed.get_mut().write_all(&bytes).await
        } else {
            framed.send(reply).await
        };
        if sent.is_err() {
            shared.trip("connection closed");
            return;
        }
    }
}

fn handle(shared: &Arc<Shared>, frame: &Frame) -> Frame {
    let req = match Request::decode(frame.frame_type, &frame.payload) {
        Ok(r) => r,
        Err(FrameError::UnknownType(_)) => {
            return reply_frame(frame, StatusCode::UnknownType, b"unknown request type");
        }
        Err(e) => return reply_frame(frame, StatusCode::BadPayload, e.to_string().as_bytes()),
    };
    let (code, data): (StatusCode, Vec<u8>) = match execute_request(shared, req) {
        Ok(data) => (StatusCode::Ok, data),
        Err((code, msg)) => (code, msg.into_bytes()),
    };
    reply_frame(frame, code, &data)
}

fn execute_request(shared: &Arc<Shared>, req: Request) -> Result<Vec<u8>, (StatusCode, String)> {
    let mut c = shared.ctl();
    match req {
        Request::Hello {
            heartbeat_timeout_ms,
        } => {
            c.heartbeat_timeout_ms = heartbeat_timeout_ms;
            c.session = true;
            c.last_rx = Instant::now();
            let mut out = vec![trim_io::galvo::protocol::PROTOCOL_VERSION];
            out.extend_from_slice(&shared.config.list_capacity.to_le_bytes());
            Ok(out)
        }
        Request::Heartbeat => Ok(Vec::new()),
        Request::Status => Ok(status_block(&c).encode()),
        Request::LoadList {
            list,
            tag,
            commands,
        } => {
            let l = check_list(list)?;
            if c.state == ControllerState::Executing && c.exec_list == list {
                return Err((StatusCode::ListBusy, format!("list {list} is executing")));
            }
            check_field(&commands, shared.config.half_field_bits)?;
            check_capacity(commands.len(), shared.config.list_capacity)?;
            c.lists[l] = ListBuf { tag, commands };
            Ok(u32::try_from(c.lists[l].commands.len())
                .unwrap_or(u32::MAX)
                .to_le_bytes()
                .to_vec())
        }
        Request::AppendList { list, commands } => {
            let l = check_list(list)?;
            if c.state == ControllerState::Executing && c.exec_list == list {
                return Err((StatusCode::ListBusy, format!("list {list} is executing")));
            }
            check_field(&commands, shared.config.half_field_bits)?;
            check_capacity(
                c.lists[l].commands.len() + commands.len(),
                shared.config.list_capacity,
            )?;
            c.lists[l].commands.extend(commands);
            Ok(u32::try_from(c.lists[l].commands.len())
                .unwrap_or(u32::MAX)
                .to_le_bytes()
                .to_vec())
        }
        Request::Execute { list } => {
            let l = check_startable(&c, list)?;
            if !c.laser_signals {
                return Err((StatusCode::SignalsOff, "laser signals disabled".into()));
            }
            c.state = ControllerState::Executing;
            c.exec_list = list;
            c.exec_tag = c.lists[l].tag;
            c.commands_done = 0;
            c.marks_done = 0;
            c.stop_requested = false;
            c.run_id += 1;
            let run_id = c.run_id;
            let commands = c.lists[l].commands.clone();
            let tag = c.exec_tag;
            drop(c);
            shared.monitor.report(CellEvent::GalvoExecuting(true));
            tokio::spawn(run_list(shared.clone(), commands, tag, run_id));
            Ok(Vec::new())
        }
        Request::Stop => {
            c.laser_signals = false;
            shared.set_gate(&mut c, false);
            shared.set_pointer(&mut c, false);
            if c.framing {
                shared.end_frame(&mut c);
                c.state = ControllerState::Stopped;
            } else if c.state == ControllerState::Executing {
                c.stop_requested = true;
                c.state = ControllerState::Stopped;
            }
            Ok(Vec::new())
        }
        Request::LaserSignals { enable } => {
            if enable && c.last_error == StatusCode::Watchdog.code() {
                return Err((StatusCode::Watchdog, "watchdog trip latched".into()));
            }
            if enable && (c.pointer || c.framing) {
                return Err((
                    StatusCode::Refused,
                    "the pointer is on or a frame runs: POINTER off and STOP first".into(),
                ));
            }
            c.laser_signals = enable;
            if !enable {
                shared.set_gate(&mut c, false);
            }
            Ok(Vec::new())
        }
        Request::FrameStatus => Ok(frame_block(&c).encode()),
        Request::Pointer { on } => {
            if on && c.last_error == StatusCode::Watchdog.code() {
                return Err((StatusCode::Watchdog, "watchdog trip latched".into()));
            }
            if on && c.laser_signals {
                return Err((
                    StatusCode::Refused,
                    "the laser signals are enabled: LASER_SIGNALS off first".into(),
                ));
            }
            shared.set_pointer(&mut c, on);
            Ok(Vec::new())
        }
        Request::ExecuteFrame { list, passes } => {
            let l = check_startable(&c, list)?;
            if c.laser_signals {
                return Err((
                    StatusCode::Refused,
                    "the laser signals are enabled: LASER_SIGNALS off before framing".into(),
                ));
            }
            shared.set_gate(&mut c, false);
            c.state = ControllerState::Executing;
            c.framing = true;
            c.exec_list = list;
            c.exec_tag = c.lists[l].tag;
            c.frame_list = list;
            c.frame_tag = c.lists[l].tag;
            c.commands_done = 0;
            c.marks_done = 0;
            c.passes_done = 0;
            c.vectors_traced = 0;
            c.stop_requested = false;
            c.run_id += 1;
            let run_id = c.run_id;
            let commands = c.lists[l].commands.clone();
            let tag = c.exec_tag;
            drop(c);
            shared.monitor.report(CellEvent::Framing(true));
            tokio::spawn(run_frame(shared.clone(), commands, tag, passes, run_id));
            Ok(Vec::new())
        }
        Request::ResetError => {
            c.last_error = 0;
            if matches!(
                c.state,
                ControllerState::WatchdogTrip | ControllerState::Error | ControllerState::Stopped
            ) {
                c.state = ControllerState::Idle;
            }
            c.session = true;
            c.last_rx = Instant::now();
            Ok(Vec::new())
        }
    }
}

fn check_list(list: u8) -> Result<usize, (StatusCode, String)> {
    match list {
        0 | 1 => Ok(usize::from(list)),
        other => Err((StatusCode::BadPayload, format!("no list {other} (0 or 1)"))),
    }
}

/// A list `EXECUTE` or `EXECUTE_FRAME` may start: no latched watchdog trip, no list running,
/// the list not empty. Its index.
fn check_startable(c: &Controller, list: u8) -> Result<usize, (StatusCode, String)> {
    let l = check_list(list)?;
    if c.last_error == StatusCode::Watchdog.code() {
        return Err((StatusCode::Watchdog, "watchdog trip latched".into()));
    }
    if c.state == ControllerState::Executing {
        return Err((StatusCode::ListBusy, format!("list {} runs", c.exec_list)));
    }
    if c.lists[l].commands.is_empty() {
        return Err((StatusCode::ListEmpty, format!("list {list} is empty")));
    }
    Ok(l)
}

fn check_capacity(n: usize, cap: u32) -> Result<(), (StatusCode, String)> {
    if n > cap as usize {
        return Err((
            StatusCode::BadPayload,
            format!("{n} commands over the list capacity {cap}"),
        ));
    }
    Ok(())
}

fn check_field(commands: &[ListCommand], half: i64) -> Result<(), (StatusCode, String)> {
    for (i, c) in commands.iter().enumerate() {
        if let ListCommand::Jump { x, y } | ListCommand::Mark { x, y } = *c
            && (i64::from(x).abs() > half || i64::from(y).abs() > half)
        {
            return Err((
                StatusCode::OutOfField,
                format!("command {i}: ({x}, {y}) bits outside ±{half}"),
            ));
        }
    }
    Ok(())
}

/// A list's clock in scaled real time: each command ends when the list's modelled time so far,
/// times the scale, has passed since the list started.
///
/// The commands' ends are absolute deadlines, not one sleep per command: the timer's
/// granularity is a millisecond, so a sleep per 20 µs vector made a list last about a millisecond
/// a command whatever its modelled time (the demo's 4.7 s of galvo time took 7 s at a scale of
/// 0.01). A command whose end has already passed yields and goes on at once.
struct Pacer {
    start: tokio::time::Instant,
    due_ns: f64,
    scale: f64,
}

impl Pacer {
    fn start(scale: f64) -> Self {
        Self {
            start: tokio::time::Instant::now(),
            due_ns: 0.0,
            scale,
        }
    }

    /// Waits until `ns` more of modelled time have passed.
    async fn advance(&mut self, ns: f64) {
        if self.scale > 0.0 && ns > 0.0 {
            self.due_ns += ns * self.scale;
            let due = self.start + Duration::from_secs_f64(self.due_ns * 1e-9);
            if due > tokio::time::Instant::now() {
                tokio::time::sleep_until(due).await;
                return;
            }
        }
        tokio::task::yield_now().await;
    }
}

/// Executes a list in (scaled) real time, one command after the other.
async fn run_list(shared: Arc<Shared>, commands: Vec<ListCommand>, tag: u32, run_id: u64) {
    let list_number = shared.faults.on_list_start();
    let mut clock = ListClock::new();
    let mut pos = [0_i32, 0_i32];
    let mut pacer = Pacer::start(shared.config.time_scale);
    let mut marks_in_list = 0_u32;
    for cmd in &commands {
        if still_running(&shared, run_id).is_none() {
            return;
        }
        let step = clock.step(cmd);
        if step.run_end_ns > 0.0 {
            pacer.advance(step.run_end_ns).await;
            let mut c = shared.ctl();
            c.elapsed_ns += step.run_end_ns;
            shared.set_gate(&mut c, false);
        }
        let from = pos;
        if let ListCommand::Jump { x, y } | ListCommand::Mark { x, y } = *cmd {
            pos = [x, y];
        }
        if step.is_mark {
            let before = {
                let mut c = shared.ctl();
                if c.laser_signals {
                    shared.set_gate(&mut c, true);
                }
                shared.monitor.light_epoch()
            };
            pacer.advance(step.ns).await;
            let after = shared.monitor.light_epoch();
            let lit = if before.on && after.on && after.offs == before.offs {
                Lit::Full
            } else if !before.on && !after.on && after.ons == before.ons {
                Lit::Dry
            } else {
                Lit::Partial
            };
            // The vector is recorded even when a stop or a trip cut it: light reached the part.
            let mut c = shared.ctl();
            let running = c.run_id == run_id && !c.stop_requested;
            if running {
                c.elapsed_ns += step.ns;
                c.commands_done += 1;
                if lit == Lit::Full {
                    c.marks_done += 1;
                }
            }
            drop(c);
            if running || lit != Lit::Dry {
                shared
                    .marks
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .push(MarkRecord {
                        tag,
                        from_bits: from,
                        to_bits: pos,
                        lit: if running { lit } else { Lit::Partial },
                    });
                if lit != Lit::Dry
                    && let Some(twin) = &shared.config.twin
                {
                    twin.on_mark(tag, marks_in_list, from, pos);
                }
            }
            if !running {
                let _ = still_running(&shared, run_id);
                return;
            }
            marks_in_list += 1;
            if let Some(kind) = shared.faults.on_marks(list_number, marks_in_list) {
                inject_mid_list(&shared, kind);
            }
        } else {
            pacer.advance(step.ns).await;
            let Some(mut c) = still_running(&shared, run_id) else {
                return;
            };
            c.elapsed_ns += step.ns;
            c.commands_done += 1;
        }
    }
    let end_ns = clock.finish();
    pacer.advance(end_ns).await;
    let Some(mut c) = still_running(&shared, run_id) else {
        return;
    };
    c.elapsed_ns += end_ns;
    shared.set_gate(&mut c, false);
    c.state = ControllerState::Idle;
    drop(c);
    shared.monitor.report(CellEvent::GalvoExecuting(false));
}

/// The controller lock if list `run_id` may go on; otherwise ends it (gate closed, executing
/// or framing off).
fn still_running(shared: &Arc<Shared>, run_id: u64) -> Option<MutexGuard<'_, Controller>> {
    let mut c = shared.ctl();
    if c.run_id == run_id && !c.stop_requested {
        return Some(c);
    }
    if c.run_id == run_id {
        shared.set_gate(&mut c, false);
        if c.state == ControllerState::Executing {
            c.state = ControllerState::Stopped;
        }
        c.stop_requested = false;
        c.run_id += 1;
        let framing = std::mem::take(&mut c.framing);
        drop(c);
        shared.monitor.report(if framing {
            CellEvent::Framing(false)
        } else {
            CellEvent::GalvoExecuting(false)
        });
    }
    None
}

/// Traces a list `passes` times (0: until stopped) in (scaled) real time on the same clock as a
/// marked list, the gate closed throughout: a `MARK` moves the mirrors with the pointer and is
/// recorded as a [`TraceRecord`], never as a mark.
async fn run_frame(
    shared: Arc<Shared>,
    commands: Vec<ListCommand>,
    tag: u32,
    passes: u32,
    run_id: u64,
) {
    let scale = shared.config.time_scale;
    let mut pass = 0_u32;
    while passes == 0 || pass < passes {
        let pass_started = Instant::now();
        let mut clock = ListClock::new();
        let mut pos = [0_i32, 0_i32];
        let mut pacer = Pacer::start(scale);
        for cmd in &commands {
            if still_running(&shared, run_id).is_none() {
                return;
            }
            let step = clock.step(cmd);
            let ns = step.run_end_ns + step.ns;
            let from = pos;
            if let ListCommand::Jump { x, y } | ListCommand::Mark { x, y } = *cmd {
                pos = [x, y];
            }
            let (pointer_before, gate_before) = {
                let c = shared.ctl();
                (c.pointer, c.gate)
            };
            let emission_before = shared.monitor.emission();
            pacer.advance(ns).await;
            let Some(mut c) = still_running(&shared, run_id) else {
                return;
            };
            c.elapsed_ns += ns;
            c.commands_done = c.commands_done.saturating_add(1);
            if step.is_mark {
                c.vectors_traced = c.vectors_traced.saturating_add(1);
                let record = TraceRecord {
                    tag,
                    pass,
                    from_bits: from,
                    to_bits: pos,
                    pointer: pointer_before && c.pointer,
                    gate_open: gate_before || c.gate,
                    emission: emission_before || shared.monitor.emission(),
                };
                drop(c);
                let mut traces = shared
                    .traces
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                if traces.len() < TRACE_RECORD_CAP {
                    traces.push(record);
                }
            }
        }
        let end_ns = clock.finish();
        pacer.advance(end_ns).await;
        tokio::time::sleep(
            Duration::from_millis(MIN_PASS_MS).saturating_sub(pass_started.elapsed()),
        )
        .await;
        let Some(mut c) = still_running(&shared, run_id) else {
            return;
        };
        c.elapsed_ns += end_ns;
        c.passes_done = c.passes_done.saturating_add(1);
        pass = pass.saturating_add(1);
    }
    let Some(mut c) = still_running(&shared, run_id) else {
        return;
    };
    shared.set_gate(&mut c, false);
    c.state = ControllerState::Idle;
    c.framing = false;
    drop(c);
    shared.monitor.report(CellEvent::Framing(false));
}

fn inject_mid_list(shared: &Arc<Shared>, kind: FaultKind) {
    match kind {
        FaultKind::DropLink => {
            if let Some(t) = shared
                .conn_task
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .take()
            {
                t.abort();
            }
            shared.trip("link dropped (fault)");
        }
        FaultKind::Stall => shared.faults.set_stalled(),
        FaultKind::DropOne => {}
        FaultKind::Garble => shared.ctl().garble_next = true,
        FaultKind::Refuse => {
            let mut c = shared.ctl();
            c.last_error = StatusCode::Refused.code();
            c.laser_signals = false;
            shared.set_gate(&mut c, false);
            c.stop_requested = true;
            c.state = ControllerState::Error;
        }
    }
}
