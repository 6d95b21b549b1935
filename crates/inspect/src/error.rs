//! The error type of trim-inspect: every variant says what was wrong and where.

use trim_geom::{ContourId, GeomError};

/// Result alias for trim-inspect.
pub type Result<T, E = InspectError> = std::result::Result<T, E>;

/// Everything that can go wrong in an inspection. Bad input is refused, never measured as if
/// it were good.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InspectError {
    /// A cloud that must hold points is empty.
    #[error("{what} holds no points")]
    Empty {
        /// Which input ("scan", "CAD mesh").
        what: String,
    },
    /// An input value is NaN or infinite.
    #[error("{what}: point {index} is not finite ({value})")]
    NonFinite {
        /// Which input ("scan", "path contour 3").
        what: String,
        /// The point's index in that input.
        index: usize,
        /// The offending point, as printed.
        value: String,
    },
    /// A setting is out of range.
    #[error("setting `{name}`: {message}")]
    InvalidSetting {
        /// The setting's key (`band_mm`, `tolerance_um`, …).
        name: &'static str,
        /// What is wrong and what is accepted.
        message: String,
    },
    /// A contour cannot be measured.
    #[error("contour {contour}: {message}")]
    Contour {
        /// The contour's id.
        contour: ContourId,
        /// What is wrong.
        message: String,
    },
    /// The registration does not describe the path inspected.
    #[error("the registration's quality report has no contour {contour}")]
    MissingBound {
        /// The contour's id.
        contour: ContourId,
    },
    /// A contour lies far outside the CAD's bounding box: the path and the CAD are in
    /// different frames or units.
    #[error(
        "contour {contour} lies {outside_mm:.0} mm outside the CAD's bounding box (its point {index}; \
         {margin_mm:.1} mm allowed): the path and the CAD must share a frame and units"
    )]
    OutsideCad {
        /// The contour's id.
        contour: ContourId,
        /// Its point furthest outside, by index in the contour.
        index: usize,
        /// How far that point lies outside the box, mm.
        outside_mm: f64,
        /// How far outside is allowed, mm ([`crate::inputs::CadExtent::margin_mm`]).
        margin_mm: f64,
    },
    /// A scan holds too few points to be fitted or measured.
    #[error("{what} holds {got} points, too few to inspect: {why}, at least {needed} points")]
    TooFewPoints {
        /// The scan (its file, or "scan").
        what: String,
        /// Its points.
        got: usize,
        /// The fewest that can be inspected.
        needed: usize,
        /// Why that many.
        why: String,
    },
    /// No scan point lies near a contour or opening: the scan is not of the part, or the fit
    /// placed it elsewhere.
    #[error(
        "scan: none of its {points} points lies within {reach_mm:.2} mm of a registered contour \
         or opening: the scan is not of this part, or the fit placed it off the part"
    )]
    OffPart {
        /// The scan's points.
        points: usize,
        /// The crop's reach, mm.
        reach_mm: f64,
    },
    /// A point's signed distance to the CAD mesh cannot be measured (not finite, or so far off
    /// that the distance overflows).
    #[error("{what}: point {index} ({value}) cannot be measured against the CAD mesh")]
    Unmeasurable {
        /// Which input ("CAD-frame points").
        what: String,
        /// The point's index in that input.
        index: usize,
        /// The point, as printed.
        value: String,
    },
    /// A geometry error (a mesh or a contour trim-geom refused).
    #[error(transparent)]
    Geom(#[from] GeomError),
}
