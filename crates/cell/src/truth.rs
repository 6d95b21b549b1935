//! job.toml `[sim.truth]`: the true cell the digital twin (trim-sim) carries in the simulators,
//! where it differs from the nominal one (DESIGN.md "Frames and the calibration chain"). The
//! settings live with the cell model so that a job file reads the same in a build without the
//! simulators.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::cell_model::Calibration;
use crate::kinematics::KinematicsKind;
use crate::lens::LensDistortion;

/// job.toml `[sim.truth]`: the true cell. A missing key is the nominal value (lines of
/// `[machine]`, identity scanner, a perfect head, L = the focal length).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TruthSettings {
    /// The true A line's point, machine frame, mm.
    pub a_axis_point_mm: Option<[f64; 3]>,
    /// The true A line's direction.
    pub a_axis_direction: Option<[f64; 3]>,
    /// The true B line's point (xyzbc-trt), mm.
    pub b_axis_point_mm: Option<[f64; 3]>,
    /// The true B line's direction (xyzbc-trt).
    pub b_axis_direction: Option<[f64; 3]>,
    /// The true C line's point, mm.
    pub c_axis_point_mm: Option<[f64; 3]>,
    /// The true C line's direction.
    pub c_axis_direction: Option<[f64; 3]>,
    /// The scanner's true rotation on the head (3×3, rows).
    pub scanner_rotation: Option<[[f64; 3]; 3]>,
    /// The scanner's true translation on the head, mm.
    pub scanner_translation_mm: Option<[f64; 3]>,
    /// The lens's true pivot height L, mm (unset: beam.focal_length_mm).
    pub pivot_to_focal_plane_mm: Option<f64>,
    /// The true trimming line (path CSV, work-piece frame) the spot error is measured against; the
    /// built-in demo part brings its own.
    pub path: Option<PathBuf>,
    /// The galvo head's true field: where a command c lands on the focal plane, offset +
    /// rotation·(c·(1 + barrel·|c|²) + trapezoid terms).
    pub head: LensDistortion,
}

impl TruthSettings {
    /// The axis lines and scanner pose as a [`Calibration`] (the same keys, the true values).
    #[must_use]
    pub fn as_calibration(&self) -> Calibration {
        Calibration {
            a_axis_point_mm: self.a_axis_point_mm,
            a_axis_direction: self.a_axis_direction,
            b_axis_point_mm: self.b_axis_point_mm,
            b_axis_direction: self.b_axis_direction,
            c_axis_point_mm: self.c_axis_point_mm,
            c_axis_direction: self.c_axis_direction,
            scanner_rotation: self.scanner_rotation,
            scanner_translation_mm: self.scanner_translation_mm,
            ..Calibration::default()
        }
    }

    /// Refuses unusable values, naming the key (`sim.truth.…`).
    pub fn validate(&self, kind: KinematicsKind) -> Result<(), String> {
        self.as_calibration()
            .validate(kind)
            .map_err(|e| e.to_string().replacen("calibration.", "sim.truth.", 1))?;
        if let Some(l) = self.pivot_to_focal_plane_mm
            && !(l.is_finite() && l > 0.0)
        {
            return Err(format!(
                "sim.truth.pivot_to_focal_plane_mm: must be a finite number > 0, got {l}"
            ));
        }
        self.head
            .validate()
            .map_err(|reason| format!("sim.truth.head: {reason}"))
    }
}
