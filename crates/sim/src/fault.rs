//! Fault injection for the simulators: what goes wrong (drop link, stall, garble, refuse) and
//! when (the n-th time a command arrives, or after n marked vectors of a galvo list).

use std::collections::HashMap;
use std::str::FromStr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use tokio::sync::Notify;

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// The link goes away: TCP closed; on serial, nothing gets through any more (cable pulled).
    DropLink,
    /// The device stops reading and answering (hangs) until the faults are cleared.
    Stall,
    /// The reply is corrupted (bad frame, junk text).
    Garble,
    /// The device answers with a refusal (error status, NAK, error reply).
    Refuse,
    /// One command is lost on the wire, once: neither executed nor answered; the next one is
    /// handled as usual (a missed reply that the link recovers from). Mid-list (galvo
    /// `marks:` triggers) there is no command to lose: nothing happens.
    DropOne,
}

impl FaultKind {
    /// The four kinds of the fault matrix ([`FaultKind::DropOne`] is not among them: the
    /// link recovers from it by itself).
    pub const ALL: [FaultKind; 4] = [
        FaultKind::DropLink,
        FaultKind::Stall,
        FaultKind::Garble,
        FaultKind::Refuse,
    ];
}

impl FromStr for FaultKind {
    type Err = String;
    fn from_str(s: &str) -> Result<FaultKind, String> {
        match s {
            "drop-link" | "drop" => Ok(FaultKind::DropLink),
            "stall" => Ok(FaultKind::Stall),
            "garble" => Ok(FaultKind::Garble),
            "refuse" => Ok(FaultKind::Refuse),
            "drop-one" => Ok(FaultKind::DropOne),
            other => Err(format!(
                "unknown fault {other:?} (expected drop-link, stall, garble, refuse or drop-one)"
            )),
        }
    }
}

/// When a fault fires.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Trigger {
    /// The `nth` (1-based) arrival of the command `name` (the simulator's command names:
    /// galvo request names such as "EXECUTE", laser command keys such as "emission_on", CNC
    /// words such as "mdi" or "wait").
    Command {
        /// The command name.
        name: String,
        /// Which arrival (1 = the first).
        nth: u32,
    },
    /// Galvo only: after `marks` vectors of the `nth` executed list (while the list runs).
    AfterMarks {
        /// Vectors marked before the fault.
        marks: u32,
        /// Which executed list (1 = the first).
        nth_list: u32,
    },
}

/// One armed fault.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Fault {
    /// What goes wrong.
    pub kind: FaultKind,
    /// When.
    pub trigger: Trigger,
}

impl FromStr for Fault {
    type Err = String;
    /// `KIND@COMMAND[#N]` or `KIND@marks:M[#N]`, e.g. `stall@EXECUTE#2`, `drop-link@marks:3`.
    fn from_str(s: &str) -> Result<Fault, String> {
        let (kind, rest) = s
            .split_once('@')
            .ok_or_else(|| format!("fault {s:?}: expected KIND@COMMAND[#N]"))?;
        let kind: FaultKind = kind.parse()?;
        let (what, nth) = match rest.split_once('#') {
            Some((w, n)) => (
                w,
                n.parse::<u32>()
                    .map_err(|e| format!("fault {s:?}: bad count {n:?}: {e}"))?,
            ),
            None => (rest, 1),
        };
        let trigger = if let Some(m) = what.strip_prefix("marks:") {
            Trigger::AfterMarks {
                marks: m
                    .parse()
                    .map_err(|e| format!("fault {s:?}: bad mark count {m:?}: {e}"))?,
                nth_list: nth,
            }
        } else {
            Trigger::Command {
                name: what.to_owned(),
                nth,
            }
        };
        Ok(Fault { kind, trigger })
    }
}

#[derive(Debug, Default)]
struct SwitchState {
    armed: Vec<Fault>,
    counts: HashMap<String, u32>,
    lists_started: u32,
    fired: Vec<(Instant, Fault)>,
    stalled: bool,
    link_down: bool,
}

/// The faults of one simulator: armed faults, arrival counters, and the stall latch. Clone it to
/// share between the simulator and the test that drives it.
#[derive(Debug, Clone, Default)]
pub struct FaultSwitch {
    state: Arc<Mutex<SwitchState>>,
    released: Arc<Notify>,
}

impl FaultSwitch {
    /// A switch with the given faults armed.
    #[must_use]
    pub fn new(faults: Vec<Fault>) -> FaultSwitch {
        let s = FaultSwitch::default();
        s.lock().armed = faults;
        s
    }

    fn lock(&self) -> MutexGuard<'_, SwitchState> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Arms one more fault.
    pub fn arm(&self, fault: Fault) {
        self.lock().armed.push(fault);
    }

    /// Disarms every fault, releases a stall and resets the counters.
    pub fn clear(&self) {
        {
            let mut s = self.lock();
            s.armed.clear();
            s.counts.clear();
            s.lists_started = 0;
            s.stalled = false;
            s.link_down = false;
        }
        self.released.notify_waiters();
    }

    /// Counts an arrival of `name`; returns the fault that fires on it (fired faults disarm).
    pub fn on_command(&self, name: &str) -> Option<FaultKind> {
        let mut s = self.lock();
        let count = {
            let c = s.counts.entry(name.to_owned()).or_insert(0);
            *c += 1;
            *c
        };
        let pos = s.armed.iter().position(|f| {
            matches!(&f.trigger, Trigger::Command { name: n, nth } if n == name && *nth == count)
        })?;
        Some(fire(&mut s, pos))
    }

    /// Counts the start of a galvo list; returns its 1-based number.
    pub fn on_list_start(&self) -> u32 {
        let mut s = self.lock();
        s.lists_started += 1;
        s.lists_started
    }

    /// Returns the fault that fires after `marks` vectors of list number `list_number`.
    pub fn on_marks(&self, list_number: u32, marks: u32) -> Option<FaultKind> {
        let mut s = self.lock();
        let pos = s.armed.iter().position(|f| {
            matches!(f.trigger, Trigger::AfterMarks { marks: m, nth_list } if m == marks && nth_list == list_number)
        })?;
        Some(fire(&mut s, pos))
    }

    /// Latches the stall (until [`FaultSwitch::clear`]).
    pub fn set_stalled(&self) {
        self.lock().stalled = true;
    }

    /// Latches a lost link (serial: nothing gets through) until [`FaultSwitch::clear`].
    pub fn set_link_down(&self) {
        self.lock().link_down = true;
    }

    /// Whether a lost link is latched.
    #[must_use]
    pub fn link_down(&self) -> bool {
        self.lock().link_down
    }

    /// Whether a stall is latched.
    #[must_use]
    pub fn stalled(&self) -> bool {
        self.lock().stalled
    }

    /// Waits until the stall is released by [`FaultSwitch::clear`].
    pub async fn wait_released(&self) {
        loop {
            let notified = self.released.notified();
            if !self.stalled() {
                return;
            }
            notified.await;
        }
    }

    /// The faults that fired, with when.
    #[must_use]
    pub fn fired(&self) -> Vec<(Instant, Fault)> {
        self.lock().fired.clone()
    }

    /// Faults still armed.
    #[must_use]
    pub fn armed(&self) -> Vec<Fault> {
        self.lock().armed.clone()
    }
}

fn fire(s: &mut SwitchState, pos: usize) -> FaultKind {
    let fault = s.armed.remove(pos);
    tracing::warn!(?fault, "fault injected");
    let kind = fault.kind;
    if kind == FaultKind::Stall {
        s.stalled = true;
    }
    s.fired.push((Instant::now(), fault));
    kind
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_fire_on_the_nth_arrival_once() {
        let f: Fault = "stall@EXECUTE#2".parse().unwrap();
        assert_eq!(
            f,
            Fault {
                kind: FaultKind::Stall,
                trigger: Trigger::Command {
                    name: "EXECUTE".into(),
                    nth: 2
                }
            }
        );
        let g: Fault = "drop-link@marks:3".parse().unwrap();
        assert_eq!(
            g.trigger,
            Trigger::AfterMarks {
                marks: 3,
                nth_list: 1
            }
        );
        assert!("melt@X".parse::<Fault>().is_err());
        assert!("stall".parse::<Fault>().is_err());
        let sw = FaultSwitch::new(vec![f, g]);
        assert_eq!(sw.on_command("EXECUTE"), None);
        assert_eq!(sw.on_command("STATUS"), None);
        assert_eq!(sw.on_command("EXECUTE"), Some(FaultKind::Stall));
        assert!(sw.stalled());
        assert_eq!(sw.on_command("EXECUTE"), None);
        let n = sw.on_list_start();
        assert_eq!(sw.on_marks(n, 2), None);
        assert_eq!(sw.on_marks(n, 3), Some(FaultKind::DropLink));
        assert_eq!(sw.fired().len(), 2);
        sw.clear();
        assert!(!sw.stalled());
        assert!(sw.armed().is_empty());
    }
}
