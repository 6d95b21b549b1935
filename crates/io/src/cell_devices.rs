//! The cell: galvo, laser and CNC clients together ([`Cell`]), their addresses and timeouts.
//! The three simulators started in-process are trim-sim's `SimCell`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::cnc::Cnc;
use crate::cnc::linuxcnc::{LinuxCnc, LinuxCncConfig};
use crate::galvo::{GalvoClient, GalvoClientConfig};
use crate::laser::{LaserClient, Profile};
use crate::tap::Tap;

/// Default galvo reply timeout (ms).
pub const GALVO_REPLY_TIMEOUT_MS: u64 = crate::galvo::client::REPLY_TIMEOUT_MS;
/// Default laser reply timeout (ms).
pub const LASER_REPLY_TIMEOUT_MS: u64 = crate::laser::client::REPLY_TIMEOUT_MS;
/// Default CNC reply timeout (ms).
pub const CNC_REPLY_TIMEOUT_MS: u64 = crate::cnc::linuxcnc::REPLY_TIMEOUT_MS;
/// Default timeout of one CNC move until in position (s).
pub const CNC_MOTION_TIMEOUT_S: u64 = 120;
/// A list may take this many times its modelled time before it counts as stalled.
pub const LIST_TIME_FACTOR: f64 = 3.0;
/// Plus this margin (ms).
pub const LIST_TIME_MARGIN_MS: u64 = 2000;
/// Timeout of each laser-off / galvo-stop / motion-stop command on the way down (ms): short,
/// because the link may be the thing that failed.
pub const SHUTDOWN_STEP_TIMEOUT_MS: u64 = 500;
/// How long the way down keeps trying the serial emission-off (ms): the port already open, then
/// reopened, again, until acknowledged. The galvo's laser signals go off meanwhile; the galvo
/// stop and the motion stop wait for this.
pub const LASER_OFF_BUDGET_MS: u64 = 2000;
/// Timeout of one journal write with its fsync (ms): past it the disk counts as hung and the run
/// takes the way down.
pub const JOURNAL_WRITE_TIMEOUT_MS: u64 = 5000;

/// Every timeout of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timeouts {
    /// One galvo reply.
    pub galvo_reply: Duration,
    /// Galvo resends after a reply timeout.
    pub galvo_resends: u32,
    /// The heartbeat timeout asked of the galvo controller (ms).
    pub galvo_heartbeat_ms: u32,
    /// One laser reply.
    pub laser_reply: Duration,
    /// One CNC reply (commands that do not wait for motion).
    pub cnc_reply: Duration,
    /// One CNC move until in position.
    pub cnc_motion: Duration,
    /// A list's timeout: modelled time × this factor ...
    pub list_time_factor: f64,
    /// ... plus this margin.
    pub list_time_margin: Duration,
    /// Each step of the way down (galvo laser signals off, galvo stop, motion stop).
    pub shutdown_step: Duration,
    /// The serial emission-off on the way down, all its attempts together.
    pub laser_off_budget: Duration,
    /// One journal write with its fsync.
    pub journal_write: Duration,
}

/// What a device call's guard allows beyond its client's own timeouts, so that the client's
/// timeout fires first and marks its link lost (a call cut off by the guard mid-reply would
/// leave the client thinking its link in step).
const GUARD_SLACK: Duration = Duration::from_millis(100);

impl Timeouts {
    /// A galvo request's timeout: every attempt's reply timeout plus slack.
    #[must_use]
    pub fn galvo_request(&self) -> Duration {
        self.galvo_reply * (self.galvo_resends + 1) + GUARD_SLACK
    }

    /// The timeout of `exchanges` laser exchanges in a row (a status runs one per query): each
    /// one's reply timeout plus slack.
    #[must_use]
    pub fn laser_request(&self, exchanges: usize) -> Duration {
        self.laser_reply * u32::try_from(exchanges.max(1)).unwrap_or(u32::MAX) + GUARD_SLACK
    }

    /// Loading a list of `commands` commands: one galvo request per frame of
    /// [`crate::galvo::client::COMMANDS_PER_FRAME`].
    #[must_use]
    pub fn galvo_load(&self, commands: usize) -> Duration {
        let frames = u32::try_from(commands.div_ceil(crate::galvo::client::COMMANDS_PER_FRAME))
            .unwrap_or(u32::MAX)
            .max(1);
        self.galvo_request() * frames
    }
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            galvo_reply: Duration::from_millis(GALVO_REPLY_TIMEOUT_MS),
            galvo_resends: crate::galvo::client::RESENDS,
            galvo_heartbeat_ms: crate::galvo::client::HEARTBEAT_TIMEOUT_MS,
            laser_reply: Duration::from_millis(LASER_REPLY_TIMEOUT_MS),
            cnc_reply: Duration::from_millis(CNC_REPLY_TIMEOUT_MS),
            cnc_motion: Duration::from_secs(CNC_MOTION_TIMEOUT_S),
            list_time_factor: LIST_TIME_FACTOR,
            list_time_margin: Duration::from_millis(LIST_TIME_MARGIN_MS),
            shutdown_step: Duration::from_millis(SHUTDOWN_STEP_TIMEOUT_MS),
            laser_off_budget: Duration::from_millis(LASER_OFF_BUDGET_MS),
            journal_write: Duration::from_millis(JOURNAL_WRITE_TIMEOUT_MS),
        }
    }
}

/// Where the devices are.
#[derive(Debug, Clone)]
pub struct CellAddresses {
    /// The galvo controller (TCP).
    pub galvo: SocketAddr,
    /// The laser's serial device node.
    pub laser_path: PathBuf,
    /// The laser's command profile.
    pub laser_profile: Profile,
    /// The CNC's linuxcncrsh (TCP).
    pub cnc: SocketAddr,
}

/// The three devices, connected.
pub struct Cell {
    /// The galvo client.
    pub galvo: GalvoClient,
    /// The laser client.
    pub laser: LaserClient,
    /// The CNC.
    pub cnc: Box<dyn Cnc>,
}

/// A device that could not be reached.
#[derive(Debug, thiserror::Error)]
pub enum CellError {
    /// The galvo.
    #[error("{0}")]
    Galvo(String),
    /// The laser.
    #[error("{0}")]
    Laser(String),
    /// The CNC.
    #[error("{0}")]
    Cnc(String),
}

impl Cell {
    /// Connects to the three devices (galvo session with heartbeat, laser port, LinuxCNC session).
    pub async fn connect(
        addrs: &CellAddresses,
        timeouts: &Timeouts,
        tap: Tap,
    ) -> Result<Cell, CellError> {
        let galvo = GalvoClient::connect(
            addrs.galvo,
            GalvoClientConfig {
                reply_timeout: timeouts.galvo_reply,
                resends: timeouts.galvo_resends,
                heartbeat_timeout_ms: timeouts.galvo_heartbeat_ms,
                ..GalvoClientConfig::default()
            },
            tap.clone(),
        )
        .await
        .map_err(|e| CellError::Galvo(e.to_string()))?
        .map_err(|f| CellError::Galvo(f.to_string()))?;
        let laser = LaserClient::open(
            &addrs.laser_path.to_string_lossy(),
            addrs.laser_profile.clone(),
            timeouts.laser_reply,
            tap.clone(),
        )
        .map_err(|e| CellError::Laser(e.to_string()))?;
        let cnc = LinuxCnc::connect(
            addrs.cnc,
            LinuxCncConfig {
                reply_timeout: timeouts.cnc_reply,
                ..LinuxCncConfig::default()
            },
            tap,
        )
        .await
        .map_err(|e| CellError::Cnc(e.to_string()))?
        .map_err(|f| CellError::Cnc(f.to_string()))?;
        Ok(Cell {
            galvo,
            laser,
            cnc: Box::new(cnc),
        })
    }
}
