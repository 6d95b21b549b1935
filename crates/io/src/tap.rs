//! A tap on device traffic: every command and reply of the device clients, timestamped, for the
//! run record's per-device channels.

use std::sync::Arc;
use std::time::SystemTime;

/// Which device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Device {
    /// The galvo scanner (TCP).
    Galvo,
    /// The laser (RS-232).
    Laser,
    /// The CNC (TCP).
    Cnc,
}

impl Device {
    /// The lower-case name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Device::Galvo => "galvo",
            Device::Laser => "laser",
            Device::Cnc => "cnc",
        }
    }
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Command (host to device) or reply (device to host).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Host to device.
    Command,
    /// Device to host.
    Reply,
}

/// One message on a device link (the run record's trimctl.DeviceIo).
#[derive(Debug, Clone, PartialEq, serde::Serialize, schemars::JsonSchema)]
#[schemars(title = "trimctl.DeviceIo")]
pub struct DeviceIo {
    /// Wall-clock time (ns since the Unix epoch).
    pub time_ns: u64,
    /// The device.
    pub device: Device,
    /// The direction.
    pub direction: Direction,
    /// The message, as text (binary frames described).
    pub text: String,
}

/// Receives device traffic; `Tap::none()` drops it.
#[derive(Clone, Default)]
pub struct Tap(Option<Arc<dyn Fn(DeviceIo) + Send + Sync>>);

impl std::fmt::Debug for Tap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Tap(on)"
        } else {
            "Tap(off)"
        })
    }
}

impl Tap {
    /// A tap that drops everything.
    #[must_use]
    pub fn none() -> Tap {
        Tap(None)
    }

    /// A tap that calls `f` for every message.
    pub fn new(f: impl Fn(DeviceIo) + Send + Sync + 'static) -> Tap {
        Tap(Some(Arc::new(f)))
    }

    /// Records one message; `text` is only built when the tap is on.
    pub fn record(&self, device: Device, direction: Direction, text: impl FnOnce() -> String) {
        if let Some(f) = &self.0 {
            f(DeviceIo {
                time_ns: now_ns(),
                device,
                direction,
                text: text(),
            });
        }
    }
}

/// Wall-clock now in ns since the Unix epoch.
#[must_use]
pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}
