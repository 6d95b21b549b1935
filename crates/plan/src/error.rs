//! The error type of trim-plan: every variant says what was wrong and where (contour id, zone,
//! settings key). Settings the cell owns are checked by trim-cell ([`CellError`]).

use trim_cell::CellError;
use trim_geom::ContourId;

/// Everything that can make planning refuse.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// A setting is out of range (trim-cell's checks of the cell, beam, galvo and machine, and
    /// the planner's own through [`PlanError::setting`]), or the beam is outside the laser's
    /// limits.
    #[error(transparent)]
    Cell(#[from] CellError),
    /// A contour has a point or feature vector that is NaN or infinite.
    #[error("contour {contour}: {what} {index} is not finite")]
    NonFinite {
        /// The contour id from the input path.
        contour: ContourId,
        /// "point" or "feature vector".
        what: &'static str,
        /// The 0-based index of the point in the contour.
        index: usize,
    },
    /// A contour's feature vector is zero (or its per-point vectors cancel out).
    #[error("contour {contour}: feature vector {index} has zero length")]
    ZeroFeature {
        /// The contour id.
        contour: ContourId,
        /// The 0-based point index.
        index: usize,
    },
    /// A contour has zero length (all points coincide) or fewer than two points.
    #[error("contour {contour}: zero-length contour ({points} points, length {length_mm} mm)")]
    ZeroLength {
        /// The contour id.
        contour: ContourId,
        /// How many points it has.
        points: usize,
        /// Its length (mm).
        length_mm: f64,
    },
    /// A contour id appears twice.
    #[error("contour {contour}: id appears more than once")]
    DuplicateContour {
        /// The repeated id.
        contour: ContourId,
    },
    /// Nothing to plan.
    #[error("the path has no contours")]
    EmptyPath,
    /// More zones were asked for than there are contours (pieces) to put in them.
    #[error("zoning.k = {k} but there are only {contours} contours (pieces after splitting)")]
    TooManyZones {
        /// The k asked for.
        k: usize,
        /// The number of samples (contour pieces).
        contours: usize,
    },
    /// A fixed k gives a zone that breaks the incidence limit.
    #[error(
        "zone {zone} (contours {contours:?}): incidence {incidence_deg:.3}° exceeds the limit \
         {limit_deg:.3}° with zoning.k = {k}; leave k unset to choose it automatically"
    )]
    IncidenceLimit {
        /// The zone index in the zoning result.
        zone: usize,
        /// Its contour ids.
        contours: Vec<ContourId>,
        /// Its largest incidence (degrees).
        incidence_deg: f64,
        /// The limit (degrees).
        limit_deg: f64,
        /// The fixed k.
        k: usize,
    },
    /// A zone would get more layers than [`crate::layer::MAX_LAYERS_PER_ZONE`]: ΔH far below
    /// the zone's depth along its axis, or a point far off the part.
    #[error(
        "layers.step_mm: contours {contours:?} span {span_mm} mm along their zone axis, which at \
         ΔH = {step_mm} mm is {layers} layers, more than the {max} a zone may have (check ΔH and \
         the path's coordinates)"
    )]
    TooManyLayers {
        /// The zone's contour ids.
        contours: Vec<ContourId>,
        /// Its depth along the zone axis (mm).
        span_mm: f64,
        /// ΔH (mm).
        step_mm: f64,
        /// The layers it would get.
        layers: usize,
        /// The cap.
        max: usize,
    },
    /// The pieces no galvo field holds alone, halved until one does, are more than the planner
    /// takes ([`crate::cover::MAX_ATOMS`]): a field far smaller than a lens's.
    #[error(
        "galvo.field_mm: the path needs {pieces} pieces to fit a field of radius \
         {field_radius_mm:.3} mm (after its margins), more than the {max} the pose covering \
         takes: is galvo.field_mm the lens's field, in mm?"
    )]
    TooManyFieldPieces {
        /// The pieces after the field splits.
        pieces: usize,
        /// The field radius the pieces were fitted to (mm, margins taken off).
        field_radius_mm: f64,
        /// The cap.
        max: usize,
    },
    /// A contour would be cut into more cover atoms than the planner takes
    /// ([`crate::cover::MAX_ATOMS`] over the path): a point far off the part.
    #[error(
        "contour {contour}: {length_mm} mm long (its point {point} is {distance_mm} mm from its \
         first), {atoms} pieces of at most {atom_mm} mm, and the path {total} in all, more than \
         the {max} the pose covering takes: is a point off the part or in the wrong units?"
    )]
    TooManyAtoms {
        /// The contour id.
        contour: ContourId,
        /// Its length (mm).
        length_mm: f64,
        /// Its 0-based point farthest from its first point.
        point: usize,
        /// That point's distance from the first point (mm).
        distance_mm: f64,
        /// The pieces it alone would be cut into.
        atoms: usize,
        /// The longest piece (mm).
        atom_mm: f64,
        /// The pieces of the whole path up to and including this contour.
        total: usize,
        /// The cap.
        max: usize,
    },
    /// k-means failed inside linfa.
    #[error("k-means with k = {k} failed: {message}")]
    KMeans {
        /// The k.
        k: usize,
        /// linfa's message.
        message: String,
    },
    /// A contour offset by kerf compensation is no valid contour (trim-geom's check, naming
    /// the contour).
    #[error("kerf compensation: {0}")]
    Geom(#[from] trim_geom::GeomError),
    /// The caller asked the planning to stop (`trim_geom::cancel`; Ctrl-C in Python).
    #[error("planning cancelled")]
    Cancelled,
}

/// `Err(PlanError::Cancelled)` once the caller has asked the work on this thread to stop
/// (`trim_geom::cancel`); the planner's long loops call it once per step.
pub(crate) fn check_cancel() -> Result<(), PlanError> {
    if trim_geom::cancel::is_cancelled() {
        Err(PlanError::Cancelled)
    } else {
        Ok(())
    }
}

impl PlanError {
    /// An out-of-range setting.
    pub fn setting(key: &'static str, value: impl ToString, message: impl Into<String>) -> Self {
        PlanError::Cell(CellError::setting(key, value, message))
    }
}
