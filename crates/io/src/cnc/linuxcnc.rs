//! A client for LinuxCNC's `linuxcncrsh` text protocol (TCP port 5007), following
//! docs/cnc/LINUXCNC.md: `hello`, `set echo off`, `set verbose on` (else `set` gets no
//! reply), `set enable`, `set set_wait received` on every connect (it is global to the server),
//! drain `get error`; to prepare: `get estop`, `get machine`, `get joint_homed`, and estop off,
//! machine on, home only when the operator allowed each ([`EnableSteps`]), `set mode mdi`, `set mdi M428`
//! (TCP kinematics), MDI `G0` moves, `set wait done`, `get abs_act_pos` (X Y Z A B C, B padded),
//! `set abort`, `set estop on`. Replies end in `\r\n` or `\n\r`: lines split on any run of CR/LF.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use bytes::BytesMut;
use futures::future::BoxFuture;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use trim_cell::job::Pose;

use super::{
    AXES, Cnc, CncError, CncFault, CncResult, EnableSteps, IN_POSITION_TOLERANCE, MachineState,
    Positions, Watch,
};
use crate::tap::{Device, Direction, Tap};

/// The default linuxcncrsh port.
pub const DEFAULT_PORT: u16 = 5007;
/// Default time to wait for a reply to a command that does not wait for motion (ms). Each `set`
/// takes about 100 ms on LinuxCNC (`estop off` about 200 ms).
pub const REPLY_TIMEOUT_MS: u64 = 3000;
/// Default time to connect (ms).
pub const CONNECT_TIMEOUT_MS: u64 = 3000;
/// Default time to wait for homing (s).
pub const HOMING_TIMEOUT_S: u64 = 30;
/// Poll period while homing (ms).
const HOMING_POLL_MS: u64 = 50;
/// The most errors popped in one drain (the queue is finite; this guards a broken server).
const MAX_ERRORS_DRAINED: usize = 64;
/// Number of joints of the five-axis machine (`joint_*` arrays are padded: check only these).
pub const JOINTS: usize = 5;

/// Session settings.
#[derive(Debug, Clone)]
pub struct LinuxCncConfig {
    /// Connect password (`hello`).
    pub connect_password: String,
    /// Enable password (`set enable`).
    pub enable_password: String,
    /// Reply timeout for commands that do not wait for motion.
    pub reply_timeout: Duration,
    /// Connect timeout.
    pub connect_timeout: Duration,
    /// Homing timeout.
    pub homing_timeout: Duration,
    /// The M-code that switches to TCP kinematics (`M428` in the xyzac-trt sim config); `None`
    /// leaves the kinematics as they are.
    pub tcp_kinematics_mcode: Option<String>,
}

impl Default for LinuxCncConfig {
    fn default() -> Self {
        LinuxCncConfig {
            connect_password: "EMC".into(),
            enable_password: "EMCTOO".into(),
            reply_timeout: Duration::from_millis(REPLY_TIMEOUT_MS),
            connect_timeout: Duration::from_millis(CONNECT_TIMEOUT_MS),
            homing_timeout: Duration::from_secs(HOMING_TIMEOUT_S),
            tcp_kinematics_mcode: Some("M428".into()),
        }
    }
}

/// A session with linuxcncrsh.
pub struct LinuxCnc {
    stream: TcpStream,
    buf: BytesMut,
    lines: VecDeque<String>,
    config: LinuxCncConfig,
    tap: Tap,
    commanded: Option<Pose>,
    broken: Option<String>,
    addr: SocketAddr,
    /// An exchange was started and not finished (its future was dropped, e.g. on cancel).
    in_flight: bool,
}

/// Splits complete lines off `buf` on any run of CR/LF.
pub fn split_lines(buf: &mut BytesMut, out: &mut VecDeque<String>) {
    while let Some(pos) = buf.iter().position(|&b| b == b'\r' || b == b'\n') {
        let line = buf.split_to(pos);
        let skip = buf
            .iter()
            .take_while(|&&b| b == b'\r' || b == b'\n')
            .count();
        let _ = buf.split_to(skip);
        if !line.is_empty() {
            out.push_back(String::from_utf8_lossy(&line).into_owned());
        }
    }
}

/// The G-code line of a rapid move to a pose: `G0 X.. Y.. Z.. A.. C..` (axes in G-code order,
/// 6 decimals). Refuses unknown axes and values that are not finite.
pub fn g0_line(pose: &Pose) -> Result<String, CncFault> {
    let mut line = String::from("G0");
    for (name, value) in &pose.0 {
        if !AXES.contains(&name.as_str()) {
            return Err(CncFault::BadPose(format!("unknown axis {name:?}")));
        }
        if !value.is_finite() {
            return Err(CncFault::BadPose(format!("axis {name} = {value}")));
        }
    }
    for axis in AXES {
        if let Some(v) = pose.axis(axis) {
            line.push_str(&format!(" {}{v:.6}", axis.to_uppercase()));
        }
    }
    if line == "G0" {
        return Err(CncFault::BadPose("no axes".into()));
    }
    Ok(line)
}

/// Parses `ABS_ACT_POS x y z a b c` into a pose (B included only when `with_b`).
pub fn parse_abs_pos(reply: &str) -> Option<Pose> {
    let mut words = reply.split_whitespace();
    if words.next()? != "ABS_ACT_POS" {
        return None;
    }
    let values: Vec<f64> = words.map(str::parse).collect::<Result<_, _>>().ok()?;
    if values.len() != 6 {
        return None;
    }
    let mut pose = Pose::default();
    for (axis, v) in AXES.iter().zip(values) {
        pose.0.insert((*axis).to_owned(), v);
    }
    Some(pose)
}

impl LinuxCnc {
    /// Connects and opens a controlling session (hello, echo off, verbose on, enable,
    /// set_wait received, errors drained). Does not change the machine state: see
    /// [`Cnc::enable`].
    pub async fn connect(
        addr: SocketAddr,
        config: LinuxCncConfig,
        tap: Tap,
    ) -> CncResult<LinuxCnc> {
        let stream =
            match tokio::time::timeout(config.connect_timeout, TcpStream::connect(addr)).await {
                Ok(Ok(s)) => s,
                Ok(Err(e)) => {
                    return Err(CncError::Connect {
                        addr: addr.to_string(),
                        reason: e.to_string(),
                    });
                }
                Err(_) => {
                    return Err(CncError::Connect {
                        addr: addr.to_string(),
                        reason: "timed out".into(),
                    });
                }
            };
        let _ = stream.set_nodelay(true);
        let mut c = LinuxCnc {
            stream,
            buf: BytesMut::with_capacity(4096),
            lines: VecDeque::new(),
            config,
            tap,
            commanded: None,
            broken: None,
            addr,
            in_flight: false,
        };
        let hello = format!("hello {} trimctl 1.0", c.config.connect_password);
        let r = c.exchange(&hello, None).await?;
        if !r.starts_with("HELLO ACK") {
            return Ok(Err(CncFault::Refused {
                command: "hello".into(),
                errors: vec![r],
            }));
        }
        // The reply to `set echo off` is the echo of that very line (verbose is still off).
        let r = c.exchange("set echo off", None).await?;
        if r != "set echo off" && !r.starts_with("SET ECHO") {
            return Err(CncError::BadReply {
                command: "set echo off".into(),
                reply: r,
            });
        }
        for cmd in [
            "set verbose on".to_owned(),
            format!("set enable {}", c.config.enable_password),
            "set set_wait received".to_owned(),
        ] {
            if let Err(f) = c.set(&cmd, None).await? {
                return Ok(Err(f));
            }
        }
        let stale = match c.drain_errors().await? {
            Ok(e) => e,
            Err(f) => return Ok(Err(f)),
        };
        if !stale.is_empty() {
            tracing::info!(?stale, "linuxcnc: stale errors drained at connect");
        }
        Ok(Ok(c))
    }

    async fn read_line(
        &mut self,
        command: &str,
        deadline: tokio::time::Instant,
    ) -> Result<String, CncError> {
        loop {
            if let Some(l) = self.lines.pop_front() {
                return Ok(l);
            }
            let mut chunk = [0_u8; 4096];
            match tokio::time::timeout_at(deadline, self.stream.read(&mut chunk)).await {
                Err(_) => {
                    return Err(CncError::Timeout {
                        command: command.to_owned(),
                        timeout_ms: 0,
                    });
                }
                Ok(Ok(0)) => {
                    return Err(CncError::LinkLost {
                        command: command.to_owned(),
                        reason: "connection closed by the control".into(),
                    });
                }
                Ok(Ok(n)) => {
                    self.buf.extend_from_slice(&chunk[..n]);
                    split_lines(&mut self.buf, &mut self.lines);
                }
                Ok(Err(e)) => {
                    return Err(CncError::LinkLost {
                        command: command.to_owned(),
                        reason: e.to_string(),
                    });
                }
            }
        }
    }

    /// Sends one line and returns one reply line; `timeout` defaults to the reply timeout.
    async fn exchange(
        &mut self,
        command: &str,
        timeout: Option<Duration>,
    ) -> Result<String, CncError> {
        if let Some(reason) = &self.broken {
            return Err(CncError::LinkLost {
                command: command.to_owned(),
                reason: format!("link already lost: {reason}"),
            });
        }
        if self.in_flight {
            // A dropped exchange left a reply on its way: the session is out of step.
            self.broken = Some("an earlier command was abandoned mid-reply".into());
            return Err(CncError::LinkLost {
                command: command.to_owned(),
                reason: "an earlier command was abandoned mid-reply".into(),
            });
        }
        let timeout = timeout.unwrap_or(self.config.reply_timeout);
        let deadline = tokio::time::Instant::now() + timeout;
        self.lines.clear();
        self.in_flight = true;
        self.tap
            .record(Device::Cnc, Direction::Command, || command.to_owned());
        let mut line = command.as_bytes().to_vec();
        line.extend_from_slice(b"\r\n");
        let result = match tokio::time::timeout_at(deadline, self.stream.write_all(&line)).await {
            Ok(Ok(())) => self.read_line(command, deadline).await,
            Ok(Err(e)) => Err(CncError::LinkLost {
                command: command.to_owned(),
                reason: e.to_string(),
            }),
            Err(_) => Err(CncError::Timeout {
                command: command.to_owned(),
                timeout_ms: 0,
            }),
        };
        self.in_flight = false;
        match result {
            Ok(reply) => {
                self.tap
                    .record(Device::Cnc, Direction::Reply, || reply.clone());
                Ok(reply)
            }
            Err(mut e) => {
                if let CncError::Timeout { timeout_ms, .. } = &mut e {
                    *timeout_ms = u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX);
                }
                self.broken = Some(e.to_string());
                Err(e)
            }
        }
    }

    /// `set ...`: ACK → Ok, NAK → the control's queued errors.
    async fn set(&mut self, command: &str, timeout: Option<Duration>) -> CncResult<()> {
        let reply = self.exchange(command, timeout).await?;
        let word = command
            .split_whitespace()
            .nth(1)
            .unwrap_or_default()
            .to_uppercase();
        let mut w = reply.split_whitespace();
        let ok = (w.next(), w.next(), w.next(), w.next());
        match ok {
            (Some("SET"), Some(x), Some("ACK"), None) if x == word => Ok(Ok(())),
            (Some("SET"), Some(x), Some("NAK"), None) if x == word => {
                let errors = match self.drain_errors().await? {
                    Ok(e) => e,
                    Err(f) => return Ok(Err(f)),
                };
                Ok(Err(CncFault::Refused {
                    command: command.to_owned(),
                    errors,
                }))
            }
            _ => {
                let e = CncError::BadReply {
                    command: command.to_owned(),
                    reply,
                };
                self.broken = Some(e.to_string());
                Err(e)
            }
        }
    }

    /// `get WORD ...`: the reply's words after the echoed keyword.
    async fn get(&mut self, what: &str) -> Result<Vec<String>, CncError> {
        let command = format!("get {what}");
        let reply = self.exchange(&command, None).await?;
        let key = what
            .split_whitespace()
            .next()
            .unwrap_or_default()
            .to_uppercase();
        let mut words = reply.split_whitespace();
        if words.next() != Some(key.as_str()) {
            let e = CncError::BadReply { command, reply };
            self.broken = Some(e.to_string());
            return Err(e);
        }
        Ok(words.map(str::to_owned).collect())
    }

    async fn drain_errors(&mut self) -> CncResult<Vec<String>> {
        let mut out = Vec::new();
        for _ in 0..MAX_ERRORS_DRAINED {
            let words = self.get("error").await?;
            if words == ["OK"] {
                return Ok(Ok(out));
            }
            out.push(words.join(" "));
        }
        Ok(Ok(out))
    }

    async fn homed(&mut self) -> Result<bool, CncError> {
        let words = self.get("joint_homed").await?;
        if words.len() < JOINTS {
            return Err(CncError::BadReply {
                command: "get joint_homed".into(),
                reply: words.join(" "),
            });
        }
        Ok(words[..JOINTS].iter().all(|w| w == "YES"))
    }

    async fn read_positions(&mut self) -> CncResult<Positions> {
        let words = self.get("abs_act_pos").await?;
        let Some(mut world) = parse_abs_pos(&format!("ABS_ACT_POS {}", words.join(" "))) else {
            return Err(CncError::BadReply {
                command: "get abs_act_pos".into(),
                reply: words.join(" "),
            });
        };
        // B is padding on an A/C machine: keep it only when commanded.
        if self
            .commanded
            .as_ref()
            .is_none_or(|p| p.axis("b").is_none())
        {
            world.0.remove("b");
        }
        let jw = self.get("joint_pos").await?;
        let joints: Vec<f64> = match jw.iter().take(JOINTS).map(|w| w.parse::<f64>()).collect() {
            Ok(j) => j,
            Err(_) => {
                return Err(CncError::BadReply {
                    command: "get joint_pos".into(),
                    reply: jw.join(" "),
                });
            }
        };
        Ok(Ok(Positions { world, joints }))
    }

    /// `get WORD` whose reply is `WORD ON` or `WORD OFF`.
    async fn on_off(&mut self, word: &str) -> Result<bool, CncError> {
        let words = self.get(word).await?;
        match words.first().map(String::as_str) {
            Some("ON") => Ok(true),
            Some("OFF") => Ok(false),
            _ => Err(CncError::BadReply {
                command: format!("get {word}"),
                reply: words.join(" "),
            }),
        }
    }

    async fn read_state(&mut self) -> CncResult<MachineState> {
        Ok(Ok(MachineState {
            estop: self.on_off("estop").await?,
            on: self.on_off("machine").await?,
            homed: self.homed().await?,
        }))
    }

    async fn do_enable(&mut self, steps: EnableSteps) -> CncResult<()> {
        let state = match self.read_state().await? {
            Ok(s) => s,
            Err(f) => return Ok(Err(f)),
        };
        if let Some(refusal) = steps.refusal(state) {
            return Ok(Err(refusal));
        }
        // Allowed and needed: the sequence as it always was (estop off, machine on, then the
        // homed state read again, which also gives LinuxCNC the moment it needs after
        // `set machine on` under `set_wait received`).
        if state.estop || !state.on {
            for cmd in ["set estop off", "set machine on"] {
                if let Err(f) = self.set(cmd, None).await? {
                    return Ok(Err(f));
                }
            }
        }
        if !self.homed().await? {
            // Unhomed only now (homing lost with the E-stop): still the operator's decision.
            if let Some(refusal) = steps.refusal(MachineState {
                estop: false,
                on: true,
                homed: false,
            }) {
                return Ok(Err(refusal));
            }
            for cmd in ["set mode manual", "set home -1"] {
                if let Err(f) = self.set(cmd, None).await? {
                    return Ok(Err(f));
                }
            }
            let started = Instant::now();
            while !self.homed().await? {
                if started.elapsed() > self.config.homing_timeout {
                    return Ok(Err(CncFault::NotHomed(format!(
                        "not homed after {} s",
                        self.config.homing_timeout.as_secs()
                    ))));
                }
                tokio::time::sleep(Duration::from_millis(HOMING_POLL_MS)).await;
            }
        }
        if let Err(f) = self.set("set mode mdi", None).await? {
            return Ok(Err(f));
        }
        if let Some(m) = self.config.tcp_kinematics_mcode.clone() {
            if let Err(f) = self.set(&format!("set mdi {m}"), None).await? {
                return Ok(Err(f));
            }
            if let Err(f) = self.set("set wait done", None).await? {
                return Ok(Err(f));
            }
        }
        Ok(Ok(()))
    }

    async fn do_wait(&mut self, timeout: Duration) -> CncResult<Positions> {
        if let Err(f) = self.set("set wait done", Some(timeout)).await? {
            return Ok(Err(f));
        }
        let pos = match self.read_positions().await? {
            Ok(p) => p,
            Err(f) => return Ok(Err(f)),
        };
        if let Some(cmd) = &self.commanded {
            for (axis, &commanded) in &cmd.0 {
                let actual = pos.world.axis(axis).unwrap_or(f64::NAN);
                let in_position = (actual - commanded).abs() <= IN_POSITION_TOLERANCE; // false for NaN
                if !in_position {
                    return Ok(Err(CncFault::NotInPosition {
                        axis: axis.clone(),
                        actual,
                        commanded,
                    }));
                }
            }
        }
        Ok(Ok(pos))
    }
}

impl LinuxCnc {
    /// Sends a stop command on this session, or, when the session is busy (a `set wait done`
    /// abandoned mid-reply: linuxcncrsh would only read the stop after the wait) or broken, on a
    /// fresh session.
    async fn stop_command(&mut self, command: &str) -> CncResult<()> {
        if self.in_flight || self.broken.is_some() {
            let mut fresh =
                match LinuxCnc::connect(self.addr, self.config.clone(), self.tap.clone()).await? {
                    Ok(c) => c,
                    Err(f) => return Ok(Err(f)),
                };
            return fresh.set(command, None).await;
        }
        self.set(command, None).await
    }
}

impl Cnc for LinuxCnc {
    fn state(&mut self) -> BoxFuture<'_, CncResult<MachineState>> {
        Box::pin(self.read_state())
    }

    fn enable(&mut self, steps: EnableSteps) -> BoxFuture<'_, CncResult<()>> {
        Box::pin(self.do_enable(steps))
    }

    fn start_move<'a>(&'a mut self, pose: &'a Pose) -> BoxFuture<'a, CncResult<()>> {
        Box::pin(async move {
            let line = match g0_line(pose) {
                Ok(l) => l,
                Err(f) => return Ok(Err(f)),
            };
            self.commanded = Some(pose.clone());
            self.set(&format!("set mdi {line}"), None).await
        })
    }

    fn wait_in_position(&mut self, timeout: Duration) -> BoxFuture<'_, CncResult<Positions>> {
        Box::pin(self.do_wait(timeout))
    }

    fn positions(&mut self) -> BoxFuture<'_, CncResult<Positions>> {
        Box::pin(self.read_positions())
    }

    fn watch(&mut self) -> BoxFuture<'_, CncResult<Watch>> {
        Box::pin(async move {
            let positions = match self.read_positions().await? {
                Ok(p) => p,
                Err(f) => return Ok(Err(f)),
            };
            let state = match self.read_state().await? {
                Ok(s) => s,
                Err(f) => return Ok(Err(f)),
            };
            Ok(Ok(Watch { positions, state }))
        })
    }

    fn abort(&mut self) -> BoxFuture<'_, CncResult<()>> {
        Box::pin(self.stop_command("set abort"))
    }

    fn estop(&mut self) -> BoxFuture<'_, CncResult<()>> {
        Box::pin(self.stop_command("set estop on"))
    }

    fn errors(&mut self) -> BoxFuture<'_, CncResult<Vec<String>>> {
        Box::pin(self.drain_errors())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_split_on_any_run_of_cr_lf() {
        let mut buf = BytesMut::from(&b"SET VERBOSE ACK\n\rERROR OK\r\nABS_ACT"[..]);
        let mut out = VecDeque::new();
        split_lines(&mut buf, &mut out);
        assert_eq!(out, ["SET VERBOSE ACK", "ERROR OK"]);
        assert_eq!(&buf[..], b"ABS_ACT");
    }

    #[test]
    fn g0_lines_take_axes_in_gcode_order() {
        let mut p = Pose::default();
        for (k, v) in [
            ("c", 30.0),
            ("a", 15.0),
            ("z", -5.0),
            ("x", 10.0),
            ("y", 20.0),
        ] {
            p.0.insert(k.into(), v);
        }
        assert_eq!(
            g0_line(&p).unwrap(),
            "G0 X10.000000 Y20.000000 Z-5.000000 A15.000000 C30.000000"
        );
        p.0.insert("q".into(), 1.0);
        assert!(matches!(g0_line(&p), Err(CncFault::BadPose(_))));
        assert!(g0_line(&Pose::default()).is_err());
    }

    #[test]
    fn abs_act_pos_parses_six_values() {
        let p =
            parse_abs_pos("ABS_ACT_POS 10.000000 20.000000 -5.000000 15.000000 0.000000 30.000000")
                .unwrap();
        assert_eq!(p.axis("c"), Some(30.0));
        assert_eq!(p.axis("b"), Some(0.0));
        assert!(parse_abs_pos("ABS_ACT_POS 1 2 3").is_none());
        assert!(parse_abs_pos("JOINT_POS 1 2 3 4 5 6").is_none());
    }
}
