//! [`SimCell`]: the galvo, laser and CNC simulators started in-process on loopback and a pty,
//! sharing one [`SafetyMonitor`], with faults to arm and an optional digital twin.

use std::net::SocketAddr;

use trim_io::cell_devices::CellAddresses;
use trim_io::laser::Profile;

use crate::cnc::{CncSim, CncSimConfig};
use crate::fault::{Fault, FaultSwitch};
use crate::galvo::{GalvoSim, GalvoSimConfig};
use crate::laser::LaserSim;
use crate::safety::SafetyMonitor;

/// Faults to arm in each simulator.
#[derive(Debug, Clone, Default)]
pub struct SimFaults {
    /// Galvo faults.
    pub galvo: Vec<Fault>,
    /// Laser faults.
    pub laser: Vec<Fault>,
    /// CNC faults.
    pub cnc: Vec<Fault>,
}

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// The laser profile the laser simulator speaks.
    pub laser_profile: Profile,
    /// Galvo: real seconds per modelled second.
    pub galvo_time_scale: f64,
    /// CNC: real seconds per simulated second.
    pub cnc_time_scale: f64,
    /// Faults to arm.
    pub faults: SimFaults,
    /// The digital twin the galvo simulator lands its vectors with, if any.
    pub twin: Option<std::sync::Arc<crate::twin::Twin>>,
}

impl SimOptions {
    /// Real-time simulators with the given laser profile and no faults.
    #[must_use]
    pub fn new(laser_profile: Profile) -> SimOptions {
        SimOptions {
            laser_profile,
            galvo_time_scale: 1.0,
            cnc_time_scale: 1.0,
            faults: SimFaults::default(),
            twin: None,
        }
    }
}

/// The three simulators, sharing one [`SafetyMonitor`].
pub struct SimCell {
    /// The galvo simulator (loopback TCP).
    pub galvo: GalvoSim,
    /// The laser simulator (pty).
    pub laser: LaserSim,
    /// The CNC simulator (loopback TCP, linuxcncrsh protocol).
    pub cnc: CncSim,
    /// The cell's event log and interlock checks.
    pub monitor: SafetyMonitor,
    profile: Profile,
}

/// A simulator that could not start.
#[derive(Debug, thiserror::Error)]
#[error("simulator: {0}")]
pub struct SimError(pub String);

impl SimCell {
    /// Starts the three simulators on 127.0.0.1 (free ports) and a pty.
    pub async fn start(options: SimOptions) -> Result<SimCell, SimError> {
        let monitor = SafetyMonitor::new();
        let lo: SocketAddr = ([127, 0, 0, 1], 0).into();
        let galvo = GalvoSim::start(
            lo,
            GalvoSimConfig {
                time_scale: options.galvo_time_scale,
                twin: options.twin.clone(),
                ..GalvoSimConfig::default()
            },
            monitor.clone(),
            FaultSwitch::new(options.faults.galvo),
        )
        .await
        .map_err(|e| SimError(format!("galvo: {e}")))?;
        let laser = LaserSim::start(
            options.laser_profile.clone(),
            monitor.clone(),
            FaultSwitch::new(options.faults.laser),
        )
        .map_err(|e| SimError(e.to_string()))?;
        let cnc = CncSim::start(
            lo,
            CncSimConfig {
                time_scale: options.cnc_time_scale,
                // The in-process simulated cell stands ready (the demo needs no flags); a
                // machine after power-up is `trimctl sim`'s.
                start_ready: true,
                ..CncSimConfig::default()
            },
            monitor.clone(),
            FaultSwitch::new(options.faults.cnc),
        )
        .await
        .map_err(|e| SimError(format!("cnc: {e}")))?;
        if let Some(twin) = &options.twin {
            twin.attach_cnc(cnc.pose_source());
        }
        Ok(SimCell {
            galvo,
            laser,
            cnc,
            monitor,
            profile: options.laser_profile,
        })
    }

    /// The simulators' addresses (the laser's pty node and profile included).
    #[must_use]
    pub fn addresses(&self) -> CellAddresses {
        CellAddresses {
            galvo: self.galvo.addr(),
            laser_path: self.laser.path().to_owned(),
            laser_profile: self.profile.clone(),
            cnc: self.cnc.addr(),
        }
    }

    /// Disarms every fault and releases stalls and dropped links.
    pub fn clear_faults(&self) {
        self.galvo.faults().clear();
        self.laser.faults().clear();
        self.cnc.faults().clear();
    }
}
