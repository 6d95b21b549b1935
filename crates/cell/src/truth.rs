//! job.toml `[sim.truth]`: the true cell the digital twin (trim-sim) carries in the simulators,
//! where it differs from the nominal one (DESIGN.md "Frames and the calibration chain"). The
//! settings live with the cell model so that a job file reads the same in a build without the
//! simulators.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::cell_model::Calibration;
use crate::kinematics::KinematicsKind;
use crate::lens::LensDistortion;

/// job.toml `[sim.truth]`: the true cell, read as a `[calibration]` (its keys, the true
/// values: axis lines, scanner pose, `[sim.truth.lens] pivot_to_focal_plane_mm`) plus the lens
/// distortion of the true galvo head (`[sim.truth.head]`) and the true trimming line (`path`). A
/// missing key is the nominal value (lines of `[machine]`, identity scanner, a perfect head, L =
/// the focal length).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default)]
pub struct TruthSettings {
    /// The true cell in `[calibration]`'s keys (flattened: `[sim.truth]` holds them directly).
    /// `field_correction` has no meaning here (the true head is `head`) and is refused.
    #[serde(flatten)]
    pub calibration: Calibration,
    /// The true trimming line (path CSV, work-piece frame) the spot error is measured against; the
    /// built-in demo part brings its own.
    pub path: Option<PathBuf>,
    /// The galvo head's true field: where a command c lands on the focal plane, offset +
    /// rotation·(c·(1 + barrel·|c|²) + trapezoid terms).
    pub head: LensDistortion,
}

/// Keys of `[sim.truth]` that moved, with where they went (job.toml refuses the old key,
/// naming the new place).
pub const MOVED_TRUTH_KEYS: &[(&str, &str)] = &[(
    "pivot_to_focal_plane_mm",
    "[sim.truth.lens] pivot_to_focal_plane_mm, as in [calibration]",
)];

impl TruthSettings {
    /// Refuses unusable values, naming the key (`sim.truth.…`).
    pub fn validate(&self, kind: KinematicsKind) -> Result<(), String> {
        if self.calibration.field_correction.is_some() {
            return Err(
                "sim.truth.field_correction: the true head's field is [sim.truth.head] \
                 (a distortion), not a correction file"
                    .to_owned(),
            );
        }
        self.calibration
            .validate(kind)
            .map_err(|e| e.to_string().replacen("calibration.", "sim.truth.", 1))?;
        self.head
            .validate()
            .map_err(|reason| format!("sim.truth.head: {reason}"))
    }
}
