//! The ablation process (job.toml `[process]`): how much material one pass of the beam removes
//! and how wide it cuts (DESIGN.md "Ablation and the twin's part").
//!
//! An ultrafast pulse ablates a depth that grows with the logarithm of the fluence over the
//! threshold; a pass of the galvo overlaps many pulses, so one pass at the job's fluence and
//! marking speed removes a fixed depth. That depth is a measured property of the material and
//! the operating point (a test cut and a profilometer), so it is a setting, not derived here.
//! The cut's width is the spot's: twice the waist radius unless a measured kerf is given.

use serde::{Deserialize, Serialize};

use crate::beam::Beam;
use crate::error::{CellError, require_range};

/// The most passes the planner may give one polyline: a burr that needs more is not a burr
/// (an uncut web of ten times the depth per pass is a wall), and a long repeat is a long dwell
/// on one edge.
pub const MAX_PASSES: u32 = 20;

/// The ablation figures of the material at the job's operating point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ProcessSettings {
    /// Depth one pass removes at the job's fluence and marking speed, µm.
    pub depth_per_pass_um: f64,
    /// The cut's width, µm; `None`: the spot's diameter (twice the beam's waist radius).
    pub kerf_width_um: Option<f64>,
}

impl Default for ProcessSettings {
    fn default() -> Self {
        ProcessSettings {
            depth_per_pass_um: 40.0,
            kerf_width_um: None,
        }
    }
}

impl ProcessSettings {
    /// Refuses values out of range, naming the job.toml key.
    pub fn validate(&self) -> Result<(), CellError> {
        require_range(
            "process.depth_per_pass_um",
            self.depth_per_pass_um,
            0.1,
            1000.0,
        )?;
        if let Some(w) = self.kerf_width_um {
            require_range("process.kerf_width_um", w, 1.0, 1000.0)?;
        }
        Ok(())
    }

    /// The cut's width, mm: the given kerf, or the spot diameter of `beam`.
    #[must_use]
    pub fn kerf_width_mm(&self, beam: &Beam) -> f64 {
        self.kerf_width_um
            .map_or_else(|| 2.0 * beam.waist_radius_mm(), |w| w * 1e-3)
    }

    /// Depth one pass removes, mm.
    #[must_use]
    pub fn depth_per_pass_mm(&self) -> f64 {
        self.depth_per_pass_um * 1e-3
    }

    /// The passes that cut through a web `thickness_mm` thick (at least 1, at most
    /// [`MAX_PASSES`]); `None` when even that many do not.
    #[must_use]
    pub fn passes_through(&self, thickness_mm: f64) -> Option<u32> {
        if !thickness_mm.is_finite() || thickness_mm < 0.0 {
            return None;
        }
        let n = (thickness_mm / self.depth_per_pass_mm() - 1e-9)
            .ceil()
            .max(1.0);
        (n <= f64::from(MAX_PASSES)).then_some(n as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_cover_the_thickness_and_stop_at_the_limit() {
        let p = ProcessSettings::default();
        assert_eq!(p.passes_through(0.0), Some(1));
        assert_eq!(p.passes_through(0.040), Some(1));
        assert_eq!(p.passes_through(0.041), Some(2));
        assert_eq!(p.passes_through(0.1), Some(3));
        assert_eq!(p.passes_through(0.8), Some(20));
        assert_eq!(p.passes_through(0.801), None);
        assert_eq!(p.passes_through(f64::NAN), None);
    }

    #[test]
    fn the_kerf_is_the_spot_unless_measured() {
        let beam = Beam::default();
        let p = ProcessSettings::default();
        assert!((p.kerf_width_mm(&beam) - 2.0 * beam.waist_radius_mm()).abs() < 1e-15);
        let measured = ProcessSettings {
            kerf_width_um: Some(25.0),
            ..p
        };
        assert!((measured.kerf_width_mm(&beam) - 0.025).abs() < 1e-15);
    }

    #[test]
    fn out_of_range_settings_name_their_key() {
        let bad = ProcessSettings {
            depth_per_pass_um: 0.0,
            ..ProcessSettings::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("process.depth_per_pass_um")
        );
        let bad = ProcessSettings {
            kerf_width_um: Some(f64::NAN),
            ..ProcessSettings::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("process.kerf_width_um")
        );
        ProcessSettings::default().validate().unwrap();
    }
}
