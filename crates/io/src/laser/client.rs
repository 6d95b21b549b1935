//! The laser client: a serial port (tokio-serial) speaking a [`Profile`]; every reply checked,
//! faults decoded, every await with a timeout.
//!
//! A transport failure (a missed reply, an I/O error) marks the link broken: later commands
//! fail at once without being sent, since a late reply could be taken for theirs. The stop
//! path's [`LaserClient::emission_off_until`] is the exception: it always sends, first on the
//! port already open, then on the port reopened, again and again until the laser acknowledges
//! or the deadline passes, and reports every attempt. A client dropped while the emission may be
//! on (a panic unwinding, a future dropped) writes the emission-off line on its way out.
//!
//! A port is closed on a thread of its own ([`close_in_background`]): on a stalled USB adapter a
//! close blocks in the kernel while it drains its output (Linux's `closing_wait`, 30 s by
//! default), and a client dropped on a runtime's thread would hold that thread, and the way
//! down of the other devices on it, for as long. The port is opened exclusively, so an open of a
//! path first waits, bounded, for every close of it still under way ([`wait_for_closes`]).

use std::collections::HashMap;
use std::sync::{Condvar, LazyLock, Mutex};
use std::time::{Duration, Instant};

use bytes::{Buf, BytesMut};
use futures::{SinkExt, StreamExt};
use tokio_serial::SerialPortBuilderExt;
use tokio_util::codec::{Decoder, Encoder, Framed};

use super::profile::{LaserStatus, Profile, QueryKind, capture, fill, format_value, ops};
use crate::tap::{Device, Direction, Tap};

/// Default time to wait for one reply (ms).
pub const REPLY_TIMEOUT_MS: u64 = 500;
/// Longest reply line accepted (bytes).
pub const MAX_LINE_LEN: usize = 256;

/// Lines split on an exact terminator, in both directions.
#[derive(Debug, Clone)]
pub struct LineCodec {
    terminator: Vec<u8>,
}

impl LineCodec {
    /// A codec for a terminator such as "\r\n" or "\r".
    #[must_use]
    pub fn new(terminator: &str) -> LineCodec {
        LineCodec {
            terminator: terminator.as_bytes().to_vec(),
        }
    }
}

impl Decoder for LineCodec {
    type Item = String;
    type Error = std::io::Error;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<String>, std::io::Error> {
        let t = &self.terminator;
        if let Some(pos) = src.windows(t.len()).position(|w| w == t.as_slice()) {
            let line = src.split_to(pos);
            src.advance(t.len());
            return Ok(Some(String::from_utf8_lossy(&line).into_owned()));
        }
        if src.len() > MAX_LINE_LEN {
            src.clear();
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("no line terminator within {MAX_LINE_LEN} bytes"),
            ));
        }
        Ok(None)
    }
}

impl Encoder<String> for LineCodec {
    type Error = std::io::Error;
    fn encode(&mut self, item: String, dst: &mut BytesMut) -> Result<(), std::io::Error> {
        dst.extend_from_slice(item.as_bytes());
        dst.extend_from_slice(&self.terminator);
        Ok(())
    }
}

/// A transport failure on the serial line.
#[derive(Debug, Clone, thiserror::Error)]
pub enum LaserError {
    /// The port could not be opened.
    #[error("laser: cannot open {path}: {reason}")]
    Open {
        /// The device path.
        path: String,
        /// Why.
        reason: String,
    },
    /// No reply in time.
    #[error("laser: no reply to {command:?} within {timeout_ms} ms")]
    Timeout {
        /// The line sent.
        command: String,
        /// The timeout (ms).
        timeout_ms: u64,
    },
    /// The port failed.
    #[error("laser: link lost during {command:?}: {reason}")]
    LinkLost {
        /// The line sent.
        command: String,
        /// Why.
        reason: String,
    },
    /// The reply is neither the expected one nor a refusal.
    #[error("laser: bad reply to {command:?}: got {reply:?}, expected {expected:?}")]
    BadReply {
        /// The line sent.
        command: String,
        /// The line received.
        reply: String,
        /// The template expected.
        expected: String,
    },
    /// A profile without the operation was asked for it.
    #[error("laser profile {profile} has no {op}")]
    Unsupported {
        /// The profile.
        profile: String,
        /// The operation.
        op: String,
    },
}

/// The laser's own refusal or fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LaserFault {
    /// The laser answered with an error.
    #[error("laser refused {command:?}: {reply:?}")]
    Refused {
        /// The line sent.
        command: String,
        /// Its reply.
        reply: String,
    },
    /// The laser reports faults.
    #[error("laser faults: {}", faults.join("; "))]
    Faults {
        /// Decoded faults.
        faults: Vec<String>,
    },
    /// The key switch is off.
    #[error("laser key switch is off")]
    KeyOff,
}

/// A device result: transport error outside, the laser's refusal or fault inside.
pub type LaserResult<T> = Result<Result<T, LaserFault>, LaserError>;

/// Which port an emission-off attempt of the stop path went out on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OffPort {
    /// The port already open (even when the link was marked broken).
    Open,
    /// The port closed and opened again.
    Reopened,
}

/// One attempt of the stop path's emission-off ([`LaserClient::emission_off_until`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct OffAttempt {
    /// The port it went out on.
    pub port: OffPort,
    /// From the first attempt's start to this one's end (s).
    pub after_s: f64,
    /// `None`: the laser acknowledged the emission-off; else what went wrong.
    pub error: Option<String>,
}

/// The stop path's emission-off: acknowledged or not, and every attempt.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct EmissionOff {
    /// The laser acknowledged an emission-off.
    pub acknowledged: bool,
    /// Every attempt, in order.
    pub attempts: Vec<OffAttempt>,
}

/// A pause between two failed emission-off attempts (ms), so a port that cannot be opened is not
/// hammered.
const OFF_RETRY_PAUSE_MS: u64 = 20;

type Port = Framed<tokio_serial::SerialStream, LineCodec>;

/// How long an open waits for a previous close of the same port (ms). Closing a port whose
/// output is a few short lines takes milliseconds; one still closing after this is held by a
/// stalled adapter, and the open fails naming it rather than waiting out the kernel's 30 s.
pub const CLOSE_WAIT_MS: u64 = 2000;

/// Closes of each port path still under way, and their end's signal.
static CLOSING: LazyLock<(Mutex<HashMap<String, usize>>, Condvar)> =
    LazyLock::new(|| (Mutex::new(HashMap::new()), Condvar::new()));

/// How the client closes a port (a field so that a test can make it block as a stalled
/// adapter's close does).
type Closer = fn(Port);

/// Closes `port` (opened at `path`) on a thread of its own, counted under its path until the
/// close returns. If no thread can be started, the port is closed here (the closure that held it
/// is dropped with the error).
fn close_in_background(path: &str, port: Port, closer: Closer) {
    *lock(&CLOSING.0).entry(path.to_owned()).or_default() += 1;
    let key = path.to_owned();
    let spawned = std::thread::Builder::new()
        .name("laser-port-close".into())
        .spawn(move || {
            closer(port);
            close_returned(&key);
        });
    if let Err(e) = spawned {
        tracing::warn!("laser: no thread to close {path} on ({e}): closed it here");
        close_returned(path);
    }
}

/// One close of `path` returned: uncounted, and the waiting opens woken.
fn close_returned(path: &str) {
    let mut map = lock(&CLOSING.0);
    if let Some(n) = map.get_mut(path) {
        *n -= 1;
        if *n == 0 {
            map.remove(path);
        }
    }
    drop(map);
    CLOSING.1.notify_all();
}

/// Waits until no close of `path` is under way, at most `timeout`.
fn wait_for_closes(path: &str, timeout: Duration) -> Result<(), LaserError> {
    let (closing, ended) = &*CLOSING;
    let until = Instant::now() + timeout;
    let mut map = lock(closing);
    while map.get(path).is_some_and(|&n| n > 0) {
        let now = Instant::now();
        if now >= until {
            return Err(LaserError::Open {
                path: path.to_owned(),
                reason: format!(
                    "its previous close has not returned within {} ms: a stalled serial \
                     adapter holds the port (unplug and replug it, or wait for the kernel's \
                     closing wait, 30 s by default)",
                    timeout.as_millis()
                ),
            });
        }
        map = ended
            .wait_timeout(map, until - now)
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .0;
    }
    Ok(())
}

/// Locks a mutex whose data stays valid if a holder panicked (counts and a taken closure).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A laser on a serial port.
pub struct LaserClient {
    /// `None` only while the stop path reopens it (the port is opened exclusively: the old one
    /// is closed first).
    port: Option<Port>,
    path: String,
    profile: Profile,
    reply_timeout: Duration,
    tap: Tap,
    broken: Option<String>,
    /// An emission-on was sent and no emission-off acknowledged since: the laser may emit.
    emission_may_be_on: bool,
    /// No reply has been read on the port since it was opened: the first line may still be the
    /// laser's reply to the emission-off a previous client's drop guard wrote before closing it.
    fresh_port: bool,
    /// Opens the port (a field so that a test can make it block as a stalled adapter does).
    opener: Opener,
    /// Closes the port, on a thread of its own.
    closer: Closer,
}

/// How the client opens its port.
type Opener = fn(&str, &Profile) -> Result<Port, LaserError>;

impl Drop for LaserClient {
    /// The guard: dropped while the emission may be on (a panic unwinding through the
    /// executor, its future dropped), the client writes the emission-off line on the port,
    /// without waiting for a reply. Then the port is closed on a thread of its own, so a close
    /// that blocks (a stalled adapter) holds neither the caller nor the emission-off line.
    fn drop(&mut self) {
        self.write_off_if_on();
        if let Some(port) = self.port.take() {
            close_in_background(&self.path, port, self.closer);
        }
    }
}

impl LaserClient {
    /// The drop guard's emission-off line, written when the emission may be on.
    fn write_off_if_on(&mut self) {
        if !self.emission_may_be_on {
            return;
        }
        let Some(port) = self.port.as_mut() else {
            return;
        };
        let ex = self.profile.commands.get(ops::EMISSION_OFF);
        let Some(ex) = ex else { return };
        let mut line = fill(&ex.send, None).into_bytes();
        line.extend_from_slice(self.profile.terminator.as_bytes());
        let written = port.get_mut().try_write(&line);
        match written {
            Ok(n) if n == line.len() => {
                tracing::error!(
                    "laser: client dropped with the emission possibly on: emission-off written"
                );
            }
            other => tracing::error!(
                ?other,
                "laser: client dropped with the emission possibly on: emission-off NOT written"
            ),
        }
    }
}

/// Drops bytes received and not read yet: the codec's buffer and the port's input queue (a late
/// reply to a timed-out command, or to another client's last line). A failure to flush the
/// queue is not an error: a stale line is then skipped or refused as a bad reply.
fn drop_stale_input(port: &mut Port) {
    port.read_buffer_mut().clear();
    let _ = tokio_serial::SerialPort::clear(port.get_ref(), tokio_serial::ClearBuffer::Input);
}

fn open_port(path: &str, profile: &Profile) -> Result<Port, LaserError> {
    let stream = tokio_serial::new(path, profile.baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| LaserError::Open {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
    Ok(Framed::new(stream, LineCodec::new(&profile.terminator)))
}

impl LaserClient {
    /// Opens the serial device at `path` with the profile's line settings (8N1), once an
    /// earlier client's close of it has returned (waited for at most [`CLOSE_WAIT_MS`]).
    pub fn open(
        path: &str,
        profile: Profile,
        reply_timeout: Duration,
        tap: Tap,
    ) -> Result<LaserClient, LaserError> {
        wait_for_closes(path, Duration::from_millis(CLOSE_WAIT_MS))?;
        let port = open_port(path, &profile)?;
        Ok(LaserClient::on_port(
            port,
            path,
            profile,
            reply_timeout,
            tap,
        ))
    }

    fn on_port(
        port: Port,
        path: &str,
        profile: Profile,
        reply_timeout: Duration,
        tap: Tap,
    ) -> LaserClient {
        LaserClient {
            port: Some(port),
            path: path.to_owned(),
            profile,
            reply_timeout,
            tap,
            broken: None,
            emission_may_be_on: false,
            fresh_port: true,
            opener: open_port,
            closer: drop,
        }
    }

    /// The profile.
    #[must_use]
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// Sends a line, returns the reply line (refusals inside).
    async fn exchange(&mut self, line: String) -> LaserResult<String> {
        if let Some(reason) = &self.broken {
            return Err(LaserError::LinkLost {
                command: line,
                reason: format!("link already lost: {reason}"),
            });
        }
        let Some(port) = self.port.as_mut() else {
            return Err(self.broken(LaserError::LinkLost {
                command: line,
                reason: "the port is closed".into(),
            }));
        };
        // Drop stale bytes (a late reply to a timed-out command) before sending.
        drop_stale_input(port);
        self.tap
            .record(Device::Laser, Direction::Command, || line.clone());
        let timeout_ms = u64::try_from(self.reply_timeout.as_millis()).unwrap_or(u64::MAX);
        let deadline = tokio::time::Instant::now() + self.reply_timeout;
        match tokio::time::timeout_at(deadline, port.send(line.clone())).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                return Err(self.broken(LaserError::LinkLost {
                    command: line,
                    reason: e.to_string(),
                }));
            }
            Err(_) => {
                return Err(self.broken(LaserError::Timeout {
                    command: line,
                    timeout_ms,
                }));
            }
        }
        // On a freshly opened port, the emission-off reply a previous client's drop guard left
        // (it writes the line and closes the port without waiting) may arrive after the input
        // was cleared: that one line is skipped, never any other.
        let stale_off = std::mem::take(&mut self.fresh_port)
            .then(|| {
                self.profile
                    .commands
                    .get(ops::EMISSION_OFF)
                    .filter(|ex| fill(&ex.send, None) != line)
                    .map(|ex| fill(&ex.reply, None))
            })
            .flatten();
        let mut first = true;
        let reply = loop {
            let read = tokio::time::timeout_at(deadline, port.next()).await;
            if let (true, Some(off), Ok(Some(Ok(r)))) = (first, &stale_off, &read)
                && r == off
            {
                self.tap.record(Device::Laser, Direction::Reply, || {
                    format!("{r} (stale: skipped)")
                });
                first = false;
                continue;
            }
            break read;
        };
        let reply = match reply {
            Err(_) => {
                return Err(self.broken(LaserError::Timeout {
                    command: line,
                    timeout_ms,
                }));
            }
            Ok(None) => {
                return Err(self.broken(LaserError::LinkLost {
                    command: line,
                    reason: "port closed".into(),
                }));
            }
            Ok(Some(Err(e))) if e.kind() == std::io::ErrorKind::InvalidData => {
                return Err(LaserError::BadReply {
                    command: line,
                    reply: e.to_string(),
                    expected: "a terminated line".into(),
                });
            }
            // The port itself failed (EIO: the device or its pty went away).
            Ok(Some(Err(e))) => {
                return Err(self.broken(LaserError::LinkLost {
                    command: line,
                    reason: e.to_string(),
                }));
            }
            Ok(Some(Ok(r))) => r,
        };
        self.tap
            .record(Device::Laser, Direction::Reply, || reply.clone());
        if self.profile.is_error_reply(&reply) {
            return Ok(Err(LaserFault::Refused {
                command: line,
                reply,
            }));
        }
        Ok(Ok(reply))
    }

    fn broken(&mut self, e: LaserError) -> LaserError {
        self.broken = Some(e.to_string());
        e
    }

    /// Runs a profile command and checks its reply (the echoed value must match).
    pub async fn command(&mut self, op: &str, value: Option<f64>) -> LaserResult<()> {
        let Some(ex) = self.profile.commands.get(op).cloned() else {
            return Err(LaserError::Unsupported {
                profile: self.profile.name.clone(),
                op: op.to_owned(),
            });
        };
        let v = value.map(format_value);
        let line = fill(&ex.send, v.as_deref());
        let reply = match self.exchange(line.clone()).await? {
            Ok(r) => r,
            Err(f) => return Ok(Err(f)),
        };
        let ok = match (capture(&ex.reply, &reply), value) {
            (Some(echo), Some(sent)) if ex.reply.contains(super::profile::VALUE) => echo
                .trim()
                .parse::<f64>()
                .is_ok_and(|e| (e - sent).abs() <= 1e-3 * sent.abs().max(1.0)),
            (Some(_), _) => true,
            (None, _) => false,
        };
        if !ok {
            return Err(LaserError::BadReply {
                command: line,
                reply,
                expected: fill(&ex.reply, v.as_deref()),
            });
        }
        Ok(Ok(()))
    }

    /// Enables or disables emission. Until an emission-off is acknowledged after an
    /// emission-on was sent, the laser counts as possibly emitting (see the `Drop` guard).
    pub async fn emission(&mut self, on: bool) -> LaserResult<()> {
        if on {
            self.emission_may_be_on = true;
            return self.command(ops::EMISSION_ON, None).await;
        }
        let r = self.command(ops::EMISSION_OFF, None).await;
        if matches!(r, Ok(Ok(()))) {
            self.emission_may_be_on = false;
        }
        r
    }

    /// The stop path's emission-off: sent on the port already open (whether or not the link
    /// was marked broken), then, while not acknowledged, on the port closed and reopened, again
    /// until the laser acknowledges or `deadline` passes. Each attempt waits for the reply at
    /// most the reply timeout; lines that are not the emission-off's reply (a late reply to an
    /// earlier command) are skipped. At least one attempt is made. An acknowledgement on a
    /// reopened port clears the broken mark (the new port is in step).
    pub async fn emission_off_until(&mut self, deadline: tokio::time::Instant) -> EmissionOff {
        let started = tokio::time::Instant::now();
        let mut out = EmissionOff::default();
        let Some(ex) = self.profile.commands.get(ops::EMISSION_OFF).cloned() else {
            out.attempts.push(OffAttempt {
                port: OffPort::Open,
                after_s: 0.0,
                error: Some(format!("profile {} has no emission_off", self.profile.name)),
            });
            return out;
        };
        let line = fill(&ex.send, None);
        loop {
            let port_use = if out.attempts.is_empty() {
                OffPort::Open
            } else {
                OffPort::Reopened
            };
            let result = match port_use {
                OffPort::Open => self.send_off(&line, &ex.reply, deadline).await,
                OffPort::Reopened => match self.reopen_port(deadline).await {
                    Ok(()) => self.send_off(&line, &ex.reply, deadline).await,
                    Err(e) => Err(e),
                },
            };
            let ok = result.is_ok();
            if ok && port_use == OffPort::Reopened {
                self.broken = None;
            }
            out.attempts.push(OffAttempt {
                port: port_use,
                after_s: started.elapsed().as_secs_f64(),
                error: result.err(),
            });
            if ok {
                out.acknowledged = true;
                self.emission_may_be_on = false;
                return out;
            }
            let now = tokio::time::Instant::now();
            if now >= deadline {
                return out;
            }
            let pause = Duration::from_millis(OFF_RETRY_PAUSE_MS).min(deadline - now);
            tokio::time::sleep(pause).await;
        }
    }

    /// Closes the port and opens it again (exclusive ports: the old one is closed first),
    /// waiting at most until `deadline`. On a stalled USB adapter a close can block in the
    /// kernel while it drains its output (Linux's `closing_wait`, 30 s by default), and so can
    /// an open; the way down must not wait for either. The close runs on its own thread, and
    /// the wait for it and the open on the blocking pool; a close or open still blocked at the
    /// deadline is left to finish there, and the port stays closed.
    async fn reopen_port(&mut self, deadline: tokio::time::Instant) -> Result<(), String> {
        if let Some(old) = self.port.take() {
            close_in_background(&self.path, old, self.closer);
        }
        let (path, profile, opener) = (self.path.clone(), self.profile.clone(), self.opener);
        let wait = deadline.saturating_duration_since(tokio::time::Instant::now());
        let job = tokio::task::spawn_blocking(move || {
            wait_for_closes(&path, wait)?;
            opener(&path, &profile)
        });
        match tokio::time::timeout_at(deadline, job).await {
            Ok(Ok(Ok(port))) => {
                self.port = Some(port);
                self.fresh_port = true;
                Ok(())
            }
            Ok(Ok(Err(e))) => Err(e.to_string()),
            Ok(Err(e)) => Err(format!("reopening {} failed: {e}", self.path)),
            Err(_) => Err(format!(
                "closing and reopening {} did not return by the laser-off deadline",
                self.path
            )),
        }
    }

    /// One emission-off on the current port: sent, then lines read until its reply, a refusal
    /// or the reply timeout (within `deadline`).
    async fn send_off(
        &mut self,
        line: &str,
        reply_template: &str,
        deadline: tokio::time::Instant,
    ) -> Result<(), String> {
        let Some(port) = self.port.as_mut() else {
            return Err("the port is closed".into());
        };
        drop_stale_input(port);
        self.tap
            .record(Device::Laser, Direction::Command, || line.to_owned());
        let now = tokio::time::Instant::now();
        let until = deadline.min(now + self.reply_timeout);
        let wait = until.saturating_duration_since(now);
        match tokio::time::timeout_at(until, port.send(line.to_owned())).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(format!("link lost: {e}")),
            Err(_) => return Err("could not send within the reply timeout".into()),
        }
        loop {
            let reply = match tokio::time::timeout_at(until, port.next()).await {
                Err(_) => return Err(format!("no reply within {} ms", wait.as_millis())),
                Ok(None) => return Err("link lost: port closed".into()),
                Ok(Some(Err(e))) if e.kind() == std::io::ErrorKind::InvalidData => continue,
                Ok(Some(Err(e))) => return Err(format!("link lost: {e}")),
                Ok(Some(Ok(r))) => r,
            };
            self.tap
                .record(Device::Laser, Direction::Reply, || reply.clone());
            if self.profile.is_error_reply(&reply) {
                return Err(format!("refused: {reply:?}"));
            }
            if capture(reply_template, &reply).is_some() {
                return Ok(());
            }
            // Not this command's reply (a late one): keep reading.
        }
    }

    /// Sets the power (percent).
    pub async fn set_power_pct(&mut self, pct: f64) -> LaserResult<()> {
        self.command(ops::SET_POWER_PCT, Some(pct)).await
    }

    /// Runs every query of the profile and decodes the status.
    pub async fn status(&mut self) -> LaserResult<LaserStatus> {
        let mut status = LaserStatus::default();
        let queries: Vec<_> = self.profile.queries.values().cloned().collect();
        for q in queries {
            let reply = match self.exchange(q.send.clone()).await? {
                Ok(r) => r,
                Err(f) => return Ok(Err(f)),
            };
            let bad = |reply: String| LaserError::BadReply {
                command: q.send.clone(),
                reply,
                expected: q.reply.clone(),
            };
            let Some(value) = capture(&q.reply, &reply) else {
                return Err(bad(reply));
            };
            if let Err(why) = self.profile.decode_query(q.kind, value, &mut status) {
                return Err(bad(format!("{reply} ({why})")));
            }
        }
        Ok(Ok(status))
    }

    /// Checks the laser is ready: key on (when a query tells) and no faults.
    pub async fn check(&mut self) -> LaserResult<LaserStatus> {
        let status = match self.status().await? {
            Ok(s) => s,
            Err(f) => return Ok(Err(f)),
        };
        if !status.faults.is_empty() {
            return Ok(Err(LaserFault::Faults {
                faults: status.faults,
            }));
        }
        if status.key_on == Some(false) {
            return Ok(Err(LaserFault::KeyOff));
        }
        Ok(Ok(status))
    }

    /// Whether this profile has a query of the kind.
    #[must_use]
    pub fn has_query(&self, kind: QueryKind) -> bool {
        self.profile.queries.values().any(|q| q.kind == kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An open that blocks for seconds, as one on a stalled adapter can, then fails.
    fn blocking_open(path: &str, _: &Profile) -> Result<Port, LaserError> {
        std::thread::sleep(Duration::from_secs(3));
        Err(LaserError::Open {
            path: path.to_owned(),
            reason: "stalled adapter (test)".into(),
        })
    }

    #[tokio::test]
    async fn a_blocking_close_and_open_do_not_hold_the_emission_off_past_its_deadline() {
        let (host, _laser_side) = tokio_serial::SerialStream::pair().expect("a pty pair");
        let profile = Profile::builtin("monaco").expect("builtin profile");
        let port = Framed::new(host, LineCodec::new(&profile.terminator));
        let reply = Duration::from_millis(100);
        let mut client = LaserClient::on_port(port, "/dev/pty-test", profile, reply, Tap::none());
        client.opener = blocking_open;
        let started = tokio::time::Instant::now();
        let budget = Duration::from_millis(600);
        let off = client.emission_off_until(started + budget).await;
        let took = started.elapsed();
        assert!(!off.acknowledged);
        assert!(
            took < budget + Duration::from_millis(300),
            "the emission-off took {took:?} against a budget of {budget:?}"
        );
        // The laser never answered on the open port; the reopening blocked past the deadline.
        assert_eq!(off.attempts[0].port, OffPort::Open);
        let last = off.attempts.last().expect("attempts");
        assert_eq!(last.port, OffPort::Reopened);
        let error = last.error.as_deref().unwrap_or_default();
        assert!(
            error.contains("did not return by the laser-off deadline"),
            "{error}"
        );
        assert!(
            client.port.is_none(),
            "no port is open after a failed reopening"
        );
    }

    /// Set once [`slow_close`] has closed its port.
    static SLOW_CLOSE_DONE: std::sync::atomic::AtomicBool =
        std::sync::atomic::AtomicBool::new(false);

    /// A close that blocks, as one on a stalled adapter draining its output does, then closes.
    fn slow_close(port: Port) {
        std::thread::sleep(Duration::from_millis(800));
        drop(port);
        SLOW_CLOSE_DONE.store(true, std::sync::atomic::Ordering::SeqCst);
    }

    #[tokio::test]
    async fn a_dropped_client_writes_the_emission_off_then_closes_on_its_own_thread_and_an_open_waits_for_the_close()
     {
        use tokio::io::AsyncReadExt;
        let (host, mut laser_side) = tokio_serial::SerialStream::pair().expect("a pty pair");
        let profile = Profile::builtin("monaco").expect("builtin profile");
        let off_line = format!(
            "{}{}",
            fill(&profile.commands[ops::EMISSION_OFF].send, None),
            profile.terminator
        );
        let port = Framed::new(host, LineCodec::new(&profile.terminator));
        let path = "/dev/pty-test-slow-close";
        let reply = Duration::from_millis(100);
        let mut client = LaserClient::on_port(port, path, profile, reply, Tap::none());
        client.closer = slow_close;
        client.emission_may_be_on = true;

        let dropped = Instant::now();
        drop(client);
        let took = dropped.elapsed();
        assert!(
            took < Duration::from_millis(200),
            "the drop waited {took:?} for a close that takes 800 ms"
        );
        let mut got = vec![0; off_line.len()];
        tokio::time::timeout(Duration::from_secs(1), laser_side.read_exact(&mut got))
            .await
            .expect("the emission-off line within 1 s")
            .expect("read the laser's side");
        assert_eq!(String::from_utf8_lossy(&got), off_line);

        // An open of the port meanwhile waits for the close, bounded.
        let short = wait_for_closes(path, Duration::from_millis(100)).expect_err("still closing");
        let why = short.to_string();
        assert!(
            why.contains(path) && why.contains("previous close has not returned within 100 ms"),
            "{why}"
        );
        assert!(!SLOW_CLOSE_DONE.load(std::sync::atomic::Ordering::SeqCst));
        wait_for_closes(path, Duration::from_secs(5)).expect("the close returns within 5 s");
        assert!(SLOW_CLOSE_DONE.load(std::sync::atomic::Ordering::SeqCst));
        let waited = dropped.elapsed();
        assert!(
            waited >= Duration::from_millis(700),
            "the open went ahead after {waited:?}, before the close returned"
        );
        // Another port's opens never wait for this one's closes.
        wait_for_closes("/dev/pty-test-other", Duration::ZERO).expect("nothing closing there");
    }

    #[test]
    fn line_codec_splits_on_the_exact_terminator() {
        let mut c = LineCodec::new("\r\n");
        let mut b = BytesMut::from(&b"L=1\r\nF=0\r"[..]);
        assert_eq!(c.decode(&mut b).unwrap(), Some("L=1".to_owned()));
        assert_eq!(c.decode(&mut b).unwrap(), None);
        b.extend_from_slice(b"\n");
        assert_eq!(c.decode(&mut b).unwrap(), Some("F=0".to_owned()));
        let mut c = LineCodec::new("\r");
        let mut b = BytesMut::from(&b"STA: 4\r"[..]);
        assert_eq!(c.decode(&mut b).unwrap(), Some("STA: 4".to_owned()));
        let mut long = BytesMut::from(&[b'x'; MAX_LINE_LEN + 1][..]);
        assert!(c.decode(&mut long).is_err());
        let mut out = BytesMut::new();
        c.encode("EMON".into(), &mut out).unwrap();
        assert_eq!(&out[..], b"EMON\r");
    }
}
