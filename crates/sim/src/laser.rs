//! A laser simulator that speaks a [`Profile`] on a pseudo-terminal (openpty): the client opens
//! the slave's device node (`/dev/pts/N`) as a real serial port. It keeps the laser's state
//! (emission, power, key, faults), reports emission to the [`SafetyMonitor`], and injects faults.

use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use std::sync::atomic::{AtomicBool, Ordering};

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, poll};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use crate::fault::{FaultKind, FaultSwitch};
use crate::safety::{CellEvent, SafetyMonitor};
use trim_io::laser::profile::{Profile, QueryKind, capture, fill, format_value, ops};

/// The bytes the simulator sends for a garbled reply (before the terminator).
pub const GARBLE_BYTES: &[u8] = b"\x15#?~\x7f";

/// The simulated laser's state.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LaserState {
    /// Emission enabled.
    pub emission: bool,
    /// Power setting (%).
    pub power_pct: f64,
    /// Repetition rate (kHz).
    pub rep_rate_khz: f64,
    /// Shutter open.
    pub shutter_open: bool,
    /// Key switch on.
    pub key_on: bool,
    /// Active fault codes (profile `fault_codes` keys) or status bits (`status_bits` numbers).
    pub faults: Vec<u32>,
    /// Lines received.
    pub lines_received: u64,
}

struct Shared {
    profile: Profile,
    state: Mutex<LaserState>,
    monitor: SafetyMonitor,
    faults: FaultSwitch,
}

impl Shared {
    fn state(&self) -> MutexGuard<'_, LaserState> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// A running laser simulator on a pty. Dropping it closes the pty.
pub struct LaserSim {
    path: PathBuf,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    _slave: OwnedFd,
}

impl Drop for LaserSim {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Why the simulator could not start.
#[derive(Debug, thiserror::Error)]
pub enum LaserSimError {
    /// A pty call failed.
    #[error("laser simulator: {what}: {errno}")]
    Pty {
        /// Which call.
        what: &'static str,
        /// The error.
        errno: nix::Error,
    },
    /// The thread could not be started.
    #[error("laser simulator: {0}")]
    Io(#[from] std::io::Error),
}

impl LaserSim {
    /// Opens a pty and starts answering on it (key on, no faults, emission off).
    pub fn start(
        profile: Profile,
        monitor: SafetyMonitor,
        faults: FaultSwitch,
    ) -> Result<LaserSim, LaserSimError> {
        let pty = nix::pty::openpty(None, None).map_err(|errno| LaserSimError::Pty {
            what: "openpty",
            errno,
        })?;
        let mut t = tcgetattr(&pty.slave).map_err(|errno| LaserSimError::Pty {
            what: "tcgetattr",
            errno,
        })?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(|errno| LaserSimError::Pty {
            what: "tcsetattr",
            errno,
        })?;
        let path = nix::unistd::ttyname(&pty.slave).map_err(|errno| LaserSimError::Pty {
            what: "ttyname",
            errno,
        })?;
        let flags = fcntl(&pty.master, FcntlArg::F_GETFL).map_err(|errno| LaserSimError::Pty {
            what: "fcntl",
            errno,
        })?;
        fcntl(
            &pty.master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(|errno| LaserSimError::Pty {
            what: "fcntl",
            errno,
        })?;
        let master = pty.master;
        monitor.report(CellEvent::Emission(false));
        let shared = Arc::new(Shared {
            profile,
            state: Mutex::new(LaserState {
                key_on: true,
                ..LaserState::default()
            }),
            monitor,
            faults,
        });
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("laser-sim".into())
                .spawn(move || serve(&master, &shared, &stop))?
        };
        Ok(LaserSim {
            path,
            shared,
            stop,
            thread: Some(thread),
            _slave: pty.slave,
        })
    }

    /// The serial device node to open (`/dev/pts/N`).
    #[must_use]
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// The laser's state now.
    #[must_use]
    pub fn state(&self) -> LaserState {
        self.shared.state().clone()
    }

    /// Sets the key switch.
    pub fn set_key(&self, on: bool) {
        self.shared.state().key_on = on;
    }

    /// Sets the active fault codes / status bits.
    pub fn set_faults(&self, faults: Vec<u32>) {
        self.shared.state().faults = faults;
    }

    /// The fault switch.
    #[must_use]
    pub fn faults(&self) -> &FaultSwitch {
        &self.shared.faults
    }

    /// The pty vanishes (a USB adapter pulled): the simulator stops and closes the master,
    /// so the client's reads and writes fail with EIO and its node cannot be opened again.
    pub fn vanish(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How long one poll of the pty waits (ms): the thread's reaction time to stop and faults.
const POLL_MS: u16 = 10;

fn write_all(fd: &OwnedFd, mut bytes: &[u8]) -> nix::Result<()> {
    while !bytes.is_empty() {
        match nix::unistd::write(fd.as_fd(), bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(nix::errno::Errno::EAGAIN) => {
                let mut fds = [PollFd::new(fd.as_fd(), PollFlags::POLLOUT)];
                poll(&mut fds, POLL_MS)?;
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Reads what is there within one poll period (0 bytes: nothing came).
fn read_some(fd: &OwnedFd, buf: &mut [u8]) -> nix::Result<usize> {
    let mut fds = [PollFd::new(fd.as_fd(), PollFlags::POLLIN)];
    if poll(&mut fds, POLL_MS)? == 0 {
        return Ok(0);
    }
    match nix::unistd::read(fd.as_fd(), buf) {
        Err(nix::errno::Errno::EAGAIN) => Ok(0),
        other => other,
    }
}

fn serve(fd: &OwnedFd, shared: &Shared, stop: &AtomicBool) {
    let term = shared.profile.terminator.as_bytes().to_vec();
    let mut pending: Vec<u8> = Vec::new();
    let mut buf = [0_u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let n = match read_some(fd, &mut buf) {
            Ok(n) => n,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(u64::from(POLL_MS)));
                continue;
            }
        };
        // Checked after the read: bytes that arrive once the faults are cleared are answered.
        if shared.faults.stalled() || shared.faults.link_down() {
            // Hung, or the cable pulled: nothing is answered, what arrives is lost.
            pending.clear();
            continue;
        }
        pending.extend_from_slice(&buf[..n]);
        while let Some(pos) = pending
            .windows(term.len())
            .position(|w| w == term.as_slice())
        {
            let line: Vec<u8> = pending.drain(..pos + term.len()).take(pos).collect();
            let line = String::from_utf8_lossy(&line)
                .trim_start_matches(['\r', '\n'])
                .to_owned();
            if line.is_empty() {
                continue;
            }
            shared.state().lines_received += 1;
            let key = command_key(&shared.profile, &line);
            let mut reply = match shared.faults.on_command(&key) {
                Some(FaultKind::DropLink) => {
                    shared.faults.set_link_down();
                    pending.clear();
                    break;
                }
                Some(FaultKind::Stall) => {
                    pending.clear();
                    break;
                }
                // This line is lost: not executed, not answered; the next is.
                Some(FaultKind::DropOne) => continue,
                Some(FaultKind::Garble) => GARBLE_BYTES.to_vec(),
                Some(FaultKind::Refuse) => {
                    format!("{}: refused", shared.profile.error_prefixes[0]).into_bytes()
                }
                None => answer(shared, &line).into_bytes(),
            };
            reply.extend_from_slice(&term);
            if let Err(e) = write_all(fd, &reply) {
                tracing::debug!(error = %e, "laser simulator: write failed");
            }
        }
        if pending.len() > 4096 {
            pending.clear();
        }
    }
}

/// The name a line is counted under for fault triggers: the operation or query name, else the
/// line itself.
#[must_use]
pub fn command_key(profile: &Profile, line: &str) -> String {
    for (name, ex) in &profile.commands {
        if capture(&ex.send, line).is_some() {
            return name.clone();
        }
    }
    for (name, q) in &profile.queries {
        if capture(&q.send, line).is_some() {
            return name.clone();
        }
    }
    line.to_owned()
}

fn answer(shared: &Shared, line: &str) -> String {
    let p = &shared.profile;
    let err = |why: &str| format!("{}: {why}", p.error_prefixes[0]);
    for (name, ex) in &p.commands {
        let Some(arg) = capture(&ex.send, line) else {
            continue;
        };
        let value = if ex.send.contains(trim_io::laser::profile::VALUE) {
            match arg.trim().parse::<f64>() {
                Ok(v) if v.is_finite() => Some(v),
                _ => return err("bad value"),
            }
        } else {
            None
        };
        let mut s = shared.state();
        match name.as_str() {
            ops::EMISSION_ON => {
                if !s.key_on {
                    return err("key switch off");
                }
                if !s.faults.is_empty() {
                    return err("fault active");
                }
                if !s.emission {
                    s.emission = true;
                    shared.monitor.report(CellEvent::Emission(true));
                }
            }
            ops::EMISSION_OFF if s.emission => {
                s.emission = false;
                shared.monitor.report(CellEvent::Emission(false));
            }
            ops::SET_POWER_PCT => {
                let v = value.unwrap_or(0.0);
                if !(0.0..=100.0).contains(&v) {
                    return err("power out of range");
                }
                s.power_pct = v;
            }
            ops::SHUTTER_OPEN => s.shutter_open = true,
            "shutter_close" => s.shutter_open = false,
            ops::SET_REP_RATE_KHZ => s.rep_rate_khz = value.unwrap_or(0.0),
            _ => {}
        }
        return fill(&ex.reply, value.map(format_value).as_deref());
    }
    for q in p.queries.values() {
        if capture(&q.send, line).is_none() {
            continue;
        }
        let s = shared.state();
        let value = match q.kind {
            QueryKind::FaultCodes => {
                if s.faults.is_empty() {
                    "0".to_owned()
                } else {
                    s.faults
                        .iter()
                        .map(u32::to_string)
                        .collect::<Vec<_>>()
                        .join(",")
                }
            }
            QueryKind::Key => u8::from(s.key_on).to_string(),
            QueryKind::Emission => u8::from(s.emission).to_string(),
            QueryKind::StatusBits => {
                let mut word = 0_u64;
                for b in &p.status_bits {
                    let set = match b.meaning {
                        trim_io::laser::profile::BitMeaning::Emission => s.emission,
                        trim_io::laser::profile::BitMeaning::Key => s.key_on,
                        trim_io::laser::profile::BitMeaning::Fault => s.faults.contains(&b.bit),
                        trim_io::laser::profile::BitMeaning::Info => false,
                    };
                    if set && b.bit < 64 {
                        word |= 1 << b.bit;
                    }
                }
                word.to_string()
            }
        };
        return fill(&q.reply, Some(&value));
    }
    if p.error_prefixes.iter().any(|e| e == "BCMD") {
        "BCMD".to_owned()
    } else {
        err("unknown command")
    }
}
