//! The error type of trim-register: every variant says what was wrong and where.

use trim_geom::{ContourId, GeomError, Point3};

/// Result alias for trim-register.
pub type Result<T, E = RegisterError> = std::result::Result<T, E>;

/// Everything that can go wrong in registration. Bad input is refused with one of these, never
/// answered with an identity transform.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RegisterError {
    /// A cloud that must hold points is empty.
    #[error("{which} cloud is empty")]
    EmptyCloud {
        /// Which cloud ("source", "target", "scan", "CAD").
        which: &'static str,
    },
    /// Every point of a cloud is at one place (one point, or copies of it): nothing can be
    /// fitted to it.
    #[error(
        "{which} cloud's {points} points are all at one place ({}, {}, {}): a scan of the part \
         spans it",
        at.x,
        at.y,
        at.z
    )]
    AtOnePlace {
        /// Which cloud.
        which: &'static str,
        /// Its points.
        points: usize,
        /// The place, mm.
        at: Point3,
    },
    /// A method needs normals that the cloud does not carry.
    #[error("{which} cloud has no normals; {method} needs them")]
    MissingNormals {
        /// Which cloud.
        which: &'static str,
        /// The method that needs them.
        method: &'static str,
    },
    /// Too few correspondences (within the maximum distance, after trimming) to solve.
    #[error(
        "{stage}: {got} correspondences {}, needs at least {needed}",
        within(*max_distance_mm)
    )]
    TooFewCorrespondences {
        /// Which step (e.g. "icp level 2, iteration 5").
        stage: String,
        /// The minimum.
        needed: usize,
        /// What was found.
        got: usize,
        /// The maximum correspondence distance in force, mm.
        max_distance_mm: f64,
    },
    /// The normal equations are singular: the data does not fix the transform.
    #[error("{stage}: normal equations are singular (eigenvalues {eigenvalues:?})")]
    Singular {
        /// Which step.
        stage: String,
        /// The eigenvalues, ascending.
        eigenvalues: Vec<f64>,
    },
    /// A scaled fit's scale changed beyond what a part can: the scan does not fix it (too flat,
    /// too little of the part, or the wrong part).
    #[error(
        "{stage}: the scale ran away to {to:.4} (from {from:.4}); the scan does not fix it: check that it covers more than one face of the part"
    )]
    RunawayScale {
        /// Which step.
        stage: String,
        /// The scale before the step.
        from: f64,
        /// The scale the step reached.
        to: f64,
    },
    /// Two sequences that must pair up do not.
    #[error("{what}: {expected} entries expected, got {got}")]
    LengthMismatch {
        /// What was paired.
        what: &'static str,
        /// The expected length.
        expected: usize,
        /// The given length.
        got: usize,
    },
    /// A setting is out of range.
    #[error("setting `{name}`: {message}")]
    InvalidSetting {
        /// The setting's key, as in the `[register]` table of job.toml.
        name: String,
        /// What is wrong and what is accepted.
        message: String,
    },
    /// An input value is not finite.
    #[error("{what} is not finite")]
    NonFinite {
        /// What value.
        what: String,
    },
    /// The scan and the CAD do not overlap after coarse alignment.
    #[error(
        "scan and CAD do not overlap: {fraction_pct:.1} % of scan points lie within {distance_mm} mm of the CAD (needs {needed_pct:.0} %)"
    )]
    NotOverlapping {
        /// The fraction of scan points near the CAD, percent.
        fraction_pct: f64,
        /// The distance used, mm.
        distance_mm: f64,
        /// The required fraction, percent.
        needed_pct: f64,
    },
    /// The coarse fit puts the part beyond the capture range from the fixture's nominal pose:
    /// the part is not where the fixture says, or the nominal pose is not this fixture's.
    #[error(
        "the part lies {rotation_deg:.1}° and {translation_mm:.1} mm from the fixture's nominal pose, beyond the capture range of {max_rotation_deg}° and {max_translation_mm} mm (register.coarse.capture_*): check that the part is seated in the fixture, that the nominal pose (job.toml [part.scan_from_cad] or register --initial) is this fixture's, and that the scan is of this part"
    )]
    OutsideCaptureRange {
        /// The fit's rotation from the nominal pose, degrees.
        rotation_deg: f64,
        /// The fit's displacement of the CAD's centroid from the nominal pose's, mm.
        translation_mm: f64,
        /// The capture range's rotation, degrees.
        max_rotation_deg: f64,
        /// The capture range's translation, mm.
        max_translation_mm: f64,
    },
    /// No start within the capture range laid the scan on the CAD.
    #[error(
        "no start within {max_rotation_deg}° and {max_translation_mm} mm of the fixture's nominal pose lays the scan on the CAD: after {starts} starts at best {score_pct:.1} % of the scan lies within {distance_mm} mm of it (needs {needed_pct:.0} %); check that the part is seated in the fixture, that the nominal pose (job.toml [part.scan_from_cad] or register --initial) is this fixture's, and that the scan is of this part"
    )]
    NotCaptured {
        /// The best start's share of scan voxels near the CAD, percent.
        score_pct: f64,
        /// The distance used, mm.
        distance_mm: f64,
        /// The share needed, percent.
        needed_pct: f64,
        /// Starts fitted.
        starts: usize,
        /// The capture range's rotation, degrees.
        max_rotation_deg: f64,
        /// The capture range's translation, mm.
        max_translation_mm: f64,
    },
    /// A contour could not be registered at all.
    #[error("contour {contour}: {message}")]
    Contour {
        /// The contour id.
        contour: ContourId,
        /// What was wrong.
        message: String,
    },
    /// A datum point of the six-point fit cannot be used (`datum` counts from 0, in the datums
    /// file's order).
    #[error("datum {datum}: {message}")]
    Datum {
        /// The datum's index.
        datum: usize,
        /// What was wrong.
        message: String,
    },
    /// A geometry error (bad cloud, bad path).
    #[error(transparent)]
    Geom(#[from] GeomError),
}

impl RegisterError {
    /// An out-of-range setting.
    pub fn setting(name: impl Into<String>, message: impl Into<String>) -> Self {
        RegisterError::InvalidSetting {
            name: name.into(),
            message: message.into(),
        }
    }
}

/// "within D mm", or "at any distance" when no maximum is in force.
fn within(max_distance_mm: f64) -> String {
    if max_distance_mm.is_finite() {
        format!("within {max_distance_mm} mm")
    } else {
        "at any distance".into()
    }
}
