//! The safety monitor: the simulators report the physical state of the cell (laser emission,
//! galvo gate and list execution, CNC motion) into one event log, and the monitor checks the
//! interlock invariants on every change (DESIGN.md "Execution and devices"):
//!
//! - **light** (laser emission on *and* the galvo gate open) only while the galvo executes a list
//!   and the CNC stands still;
//! - laser emission never enabled while the CNC moves;
//! - while the galvo traces a frame (`EXECUTE_FRAME`, red-light framing): the gate never opens
//!   and the laser's emission is never on.
//!
//! Violations are recorded, not panicked on, so tests can assert there are none and the executor
//! can be checked from outside. Times are `Instant`s, so latencies can be measured from it.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

/// One state change of the cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum CellEvent {
    /// The laser source's emission was enabled (true) or disabled (false).
    Emission(bool),
    /// The galvo gate (laser signal) opened (true) or closed (false).
    Gate(bool),
    /// The galvo started (true) or ended (false) executing a list.
    GalvoExecuting(bool),
    /// The CNC started (true) or ended (false) a motion.
    CncMoving(bool),
    /// The galvo's pointer (aiming laser) went on (true) or off (false).
    Pointer(bool),
    /// The galvo started (true) or ended (false) tracing a frame.
    Framing(bool),
}

/// A broken invariant.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Violation {
    /// Index of the event that broke it in the event log.
    pub event_index: usize,
    /// What was wrong.
    pub what: String,
}

#[derive(Debug, Default)]
struct State {
    /// `None` until a laser reports: an unwired laser counts as emitting for the galvo's input.
    emission: Option<bool>,
    gate: bool,
    galvo_executing: bool,
    cnc_moving: bool,
    pointer: bool,
    framing: bool,
    light_off_count: u64,
    light_on_count: u64,
    events: Vec<(Instant, CellEvent)>,
    violations: Vec<Violation>,
}

impl State {
    fn light(&self) -> bool {
        self.emission.unwrap_or(false) && self.gate
    }
}

/// A shared, cheaply clonable handle on the cell's event log and invariants.
#[derive(Debug, Clone, Default)]
pub struct SafetyMonitor {
    inner: Arc<Mutex<State>>,
}

/// A snapshot of the light path for the galvo simulator's per-vector accounting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightEpoch {
    /// Light on at the snapshot.
    pub on: bool,
    /// Light-off transitions so far.
    pub offs: u64,
    /// Light-on transitions so far.
    pub ons: u64,
}

impl SafetyMonitor {
    /// A monitor with an empty log.
    #[must_use]
    pub fn new() -> SafetyMonitor {
        SafetyMonitor::default()
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock leaves plain data behind; keep using it.
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Reports a state change and checks the invariants.
    pub fn report(&self, event: CellEvent) {
        let mut s = self.lock();
        let was_light = s.light();
        match event {
            CellEvent::Emission(on) => s.emission = Some(on),
            CellEvent::Gate(on) => s.gate = on,
            CellEvent::GalvoExecuting(on) => s.galvo_executing = on,
            CellEvent::CncMoving(on) => s.cnc_moving = on,
            CellEvent::Pointer(on) => s.pointer = on,
            CellEvent::Framing(on) => s.framing = on,
        }
        let light = s.light();
        if was_light && !light {
            s.light_off_count += 1;
        }
        if !was_light && light {
            s.light_on_count += 1;
        }
        let index = s.events.len();
        s.events.push((Instant::now(), event));
        let mut broken = Vec::new();
        if light && s.cnc_moving {
            broken.push("light on while the CNC moves".to_owned());
        }
        if light && !s.galvo_executing {
            broken.push("light on while the galvo is idle".to_owned());
        }
        if s.emission == Some(true)
            && s.cnc_moving
            && matches!(
                event,
                CellEvent::CncMoving(true) | CellEvent::Emission(true)
            )
        {
            broken.push("laser emission enabled while the CNC moves".to_owned());
        }
        if s.framing && s.gate {
            broken.push("galvo gate open while framing".to_owned());
        }
        if s.framing
            && s.emission == Some(true)
            && matches!(event, CellEvent::Framing(true) | CellEvent::Emission(true))
        {
            broken.push("laser emission enabled while framing".to_owned());
        }
        for what in broken {
            tracing::error!(%what, ?event, "safety violation");
            s.violations.push(Violation {
                event_index: index,
                what,
            });
        }
    }

    /// The emission input of the galvo controller: the laser's emission status, or true when
    /// no laser reports to this monitor (not wired).
    #[must_use]
    pub fn emission_input(&self) -> bool {
        self.lock().emission.unwrap_or(true)
    }

    /// Whether the laser source reports emission enabled.
    #[must_use]
    pub fn emission(&self) -> bool {
        self.lock().emission.unwrap_or(false)
    }

    /// Whether light reaches the part right now.
    #[must_use]
    pub fn light(&self) -> bool {
        self.lock().light()
    }

    /// The light path seen through the galvo's emission input (an unwired laser counts as on).
    #[must_use]
    pub fn light_epoch(&self) -> LightEpoch {
        let s = self.lock();
        LightEpoch {
            on: s.gate && s.emission.unwrap_or(true),
            offs: s.light_off_count,
            ons: s.light_on_count,
        }
    }

    /// Whether the galvo's pointer (aiming laser) is on.
    #[must_use]
    pub fn pointer(&self) -> bool {
        self.lock().pointer
    }

    /// Whether the galvo is tracing a frame.
    #[must_use]
    pub fn framing(&self) -> bool {
        self.lock().framing
    }

    /// Whether the CNC is moving.
    #[must_use]
    pub fn cnc_moving(&self) -> bool {
        self.lock().cnc_moving
    }

    /// The invariant violations so far.
    #[must_use]
    pub fn violations(&self) -> Vec<Violation> {
        self.lock().violations.clone()
    }

    /// The whole event log.
    #[must_use]
    pub fn events(&self) -> Vec<(Instant, CellEvent)> {
        self.lock().events.clone()
    }

    /// The first instant at or after `since` at which the light path was closed: `since` itself
    /// if it was closed then, else the first light-off event after it; `None` if still open.
    #[must_use]
    pub fn light_closed_since(&self, since: Instant) -> Option<Instant> {
        let s = self.lock();
        let mut emission: Option<bool> = None;
        let mut gate = false;
        let mut closed_at: Option<Instant> = None;
        for &(t, e) in &s.events {
            match e {
                CellEvent::Emission(on) => emission = Some(on),
                CellEvent::Gate(on) => gate = on,
                _ => {}
            }
            let light = emission.unwrap_or(false) && gate;
            if light {
                closed_at = None;
            } else if closed_at.is_none() {
                closed_at = Some(t);
            }
        }
        if s.light() {
            return None;
        }
        Some(closed_at.map_or(since, |t| t.max(since)))
    }

    /// The first instant at or after `since` at which the laser's emission was disabled
    /// (`since` itself if it was already off then); `None` if it is still enabled.
    #[must_use]
    pub fn emission_off_since(&self, since: Instant) -> Option<Instant> {
        let s = self.lock();
        if s.emission == Some(true) {
            return None;
        }
        let last_off = s
            .events
            .iter()
            .rev()
            .find(|(_, e)| *e == CellEvent::Emission(false))
            .map(|(t, _)| *t);
        Some(last_off.map_or(since, |t| t.max(since)))
    }

    /// Clears the event log and the violations (not the state).
    pub fn clear_log(&self) {
        let mut s = self.lock();
        s.events.clear();
        s.violations.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_while_moving_or_idle_is_a_violation_and_normal_order_is_not() {
        let m = SafetyMonitor::new();
        m.report(CellEvent::CncMoving(true));
        m.report(CellEvent::CncMoving(false));
        m.report(CellEvent::Emission(true));
        m.report(CellEvent::GalvoExecuting(true));
        m.report(CellEvent::Gate(true));
        m.report(CellEvent::Gate(false));
        m.report(CellEvent::GalvoExecuting(false));
        m.report(CellEvent::Emission(false));
        assert!(m.violations().is_empty(), "{:?}", m.violations());

        m.report(CellEvent::Emission(true));
        m.report(CellEvent::CncMoving(true));
        m.report(CellEvent::Gate(true));
        let v = m.violations();
        assert_eq!(v.len(), 3, "{v:?}");
        assert_eq!(v[0].what, "laser emission enabled while the CNC moves");
        assert!(
            v[1..]
                .iter()
                .any(|x| x.what == "light on while the galvo is idle")
        );
        assert!(
            v[1..]
                .iter()
                .any(|x| x.what == "light on while the CNC moves")
        );
    }

    #[test]
    fn a_gate_or_emission_while_framing_is_a_violation() {
        let m = SafetyMonitor::new();
        m.report(CellEvent::Emission(false));
        m.report(CellEvent::Pointer(true));
        m.report(CellEvent::Framing(true));
        m.report(CellEvent::Framing(false));
        m.report(CellEvent::Pointer(false));
        assert!(m.violations().is_empty(), "{:?}", m.violations());
        assert!(!m.pointer() && !m.framing());
        m.report(CellEvent::Framing(true));
        m.report(CellEvent::Gate(true));
        m.report(CellEvent::Gate(false));
        m.report(CellEvent::Emission(true));
        let v: Vec<String> = m.violations().into_iter().map(|v| v.what).collect();
        assert_eq!(
            v,
            [
                "galvo gate open while framing",
                "laser emission enabled while framing"
            ]
        );
    }

    #[test]
    fn light_closed_since_finds_the_closing_event() {
        let m = SafetyMonitor::new();
        m.report(CellEvent::GalvoExecuting(true));
        m.report(CellEvent::Emission(true));
        m.report(CellEvent::Gate(true));
        let t0 = Instant::now();
        assert_eq!(m.light_closed_since(t0), None);
        m.report(CellEvent::Gate(false));
        let closed = m.light_closed_since(t0).unwrap();
        assert!(closed >= t0);
        assert_eq!(m.events().last().unwrap().0, closed);
        assert_eq!(m.emission_off_since(t0), None);
        m.report(CellEvent::Emission(false));
        assert!(m.emission_off_since(t0).unwrap() >= closed);
    }
}
