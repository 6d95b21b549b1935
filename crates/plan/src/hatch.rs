//! Surface hatching: parallel tracks with equal neighbour spacing, measured across a scanned
//! freeform surface (`papers/equal-overlap-cladding-freeform.txt`, "the cladding paper").
//!
//! Given a surface point cloud (world frame, mm; normals optional), a closed boundary polyline
//! lying on it, a track pitch (or a spot diameter `d` and overlap `η`: pitch = (1 − η)·d, paper
//! §2.3 step 3) and a hatch direction, [`hatch`] returns tracks in serpentine order, each point
//! carrying the unit surface normal (the laser-axis feature vector of the path CSV contract).
//!
//! Two methods ([`HatchMethod`]):
//! - `slab` — the paper's method, faithfully (§2.2–2.4): the first track is a fitted section of
//!   the cloud placed at equal 3D steps; each next track is found, for every point of the
//!   previous one, on the contour that the slabs either side of the plane normal to the track
//!   cut from the cloud, (1 − η)·d along the fitted contour; the new points are fitted, cut at
//!   the boundary by ray casting and extended along the fitted curve to it; the posture is
//!   V = P_sa × P_se (§2.4).
//! - `geodesic` (default) — iso-lines of the geodesic distance from a seed line, by fast marching
//!   on a smooth height field fitted to the scan (see [`geodesic`] module docs for why). The
//!   levels are centred so the first and last tracks lie within pitch/2 of the boundary.
//!
//! Both end every track on the boundary (exact crossing with the boundary polygon in the plane
//! frame) and add, unless disabled, an outline track along the boundary: without it, points in
//! the corner between a track end and a boundary that meets the tracks at a shallow angle are
//! up to a whole pitch from any track. [`measure`] reports neighbour spacing measured along the
//! surface, coverage and the boundary error.
//!
//! *Frames.* Input and output points are in the cloud's (world) frame, mm. Internally the patch
//! is a height field over its best-fit plane ([`surface::PlaneFrame`]); the hatch direction is
//! `cos(angle)·e1 + sin(angle)·e2` with `e1` world X projected onto the plane. The patch must be
//! single-valued over that plane (slopes under 80°); a folded patch is refused.

mod geodesic;
mod measure;
pub mod opening;
mod polygon;
mod sample;
mod slab;
pub mod surface;
pub mod track_ids;

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use trim_geom::{Contour, GeomError, Path, Point3, PointCloud, Vector3};

pub use measure::{HatchReport, SpacingStats, measure};
use polygon::Polygon;
use surface::{PlaneFrame, Surface};

/// A boundary whose last point is within this distance of its first (mm) repeats its first
/// point: it is closed as given.
pub const BOUNDARY_CLOSURE_TOL_MM: f64 = 0.01;
/// A boundary is a polygon: when its last point does not repeat its first, the closing edge is
/// implied, provided it is no longer than this many times the boundary's longest edge. A wider
/// gap is an open curve (a trimming line, say), not a region, and is refused.
pub const BOUNDARY_CLOSING_EDGE_FACTOR: f64 = 1.5;
/// A boundary vertex farther than this from the fitted surface (mm) is refused as off it.
pub const BOUNDARY_ON_SURFACE_TOL_MM: f64 = 0.1;
/// The fewest distinct boundary vertices.
pub const MIN_BOUNDARY_POINTS: usize = 3;
/// The smallest `pitch_mm`, `step_mm` and `grid_mm` (mm): 1 µm, a fortieth of an ultrafast
/// spot; below it a region holds more tracks, points or grid nodes than memory.
pub const MIN_HATCH_LENGTH_MM: f64 = 1e-3;
/// The most tracks one region may get (its width across the hatch direction over the pitch).
pub const MAX_TRACKS: usize = 100_000;
/// The most points one region's tracks may hold together (about its area over pitch × step).
pub const MAX_POINTS: usize = 5_000_000;
/// The most height-field nodes one region may get (`hatch.grid_mm`, or 2.5 × the scan spacing).
pub const MAX_GRID_NODES: usize = 4_000_000;
/// Coverage counts a surface point covered within this factor × pitch/2 of a track.
pub const COVERAGE_FACTOR: f64 = 1.05;

/// How tracks are planned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HatchMethod {
    /// Iso-lines of the geodesic distance on a fitted height field (the default).
    #[default]
    Geodesic,
    /// The cladding paper's slab method (§2.2–2.3), faithfully.
    Slab,
}

impl HatchMethod {
    /// The name used in settings and on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            HatchMethod::Geodesic => "geodesic",
            HatchMethod::Slab => "slab",
        }
    }
}

impl fmt::Display for HatchMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for HatchMethod {
    type Err = HatchError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "geodesic" => Ok(HatchMethod::Geodesic),
            "slab" => Ok(HatchMethod::Slab),
            _ => Err(HatchError::setting(
                "hatch.method",
                s,
                "must be \"geodesic\" or \"slab\"",
            )),
        }
    }
}

/// How points are placed along a track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PointSpacing {
    /// Equal 3D steps along the surface curve (the pulse pitch, mm); the end point on the
    /// boundary closes the last, shorter step.
    Pitch {
        /// The step, mm.
        step_mm: f64,
    },
    /// The fewest points whose chords stay within this distance of the track (mm), for vector
    /// marking.
    Chord {
        /// The chord tolerance, mm.
        tolerance_mm: f64,
    },
}

/// Hatching settings (the `[hatch]` keys: lengths in mm, angles in degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HatchSettings {
    /// Track pitch: the neighbour spacing across the surface, mm.
    pub pitch_mm: f64,
    /// Hatch direction in the patch's best-fit plane, degrees from world X projected onto it
    /// (world Y when X is nearly normal to the plane), counter-clockwise about the plane normal.
    pub angle_deg: f64,
    /// The method.
    pub method: HatchMethod,
    /// Point step along a track, mm (the pulse pitch); unset: the track pitch.
    pub step_mm: Option<f64>,
    /// Chord tolerance for vector marking, mm; when set, points are placed by it instead of a
    /// step (set at most one of `step_mm` and `chord_tolerance_mm`).
    pub chord_tolerance_mm: Option<f64>,
    /// Add an outline track along the boundary (last in the order).
    pub outline: bool,
    /// Height-field grid spacing, mm; unset: 2.5 × the mean scan point spacing.
    pub grid_mm: Option<f64>,
}

impl Default for HatchSettings {
    fn default() -> Self {
        HatchSettings {
            pitch_mm: 0.05,
            angle_deg: 0.0,
            method: HatchMethod::Geodesic,
            step_mm: None,
            chord_tolerance_mm: None,
            outline: true,
            grid_mm: None,
        }
    }
}

impl HatchSettings {
    /// Settings with this pitch (mm) and the other keys at their defaults.
    #[must_use]
    pub fn with_pitch(pitch_mm: f64) -> Self {
        HatchSettings {
            pitch_mm,
            ..HatchSettings::default()
        }
    }

    /// Settings from a spot diameter `d` (mm) and an overlap ratio `η ∈ [0, 1)`: pitch =
    /// (1 − η)·d (paper §2.3 step 3).
    pub fn from_spot(spot_diameter_mm: f64, overlap: f64) -> Result<Self, HatchError> {
        positive("hatch.spot_diameter_mm", spot_diameter_mm)?;
        if !(overlap.is_finite() && (0.0..1.0).contains(&overlap)) {
            return Err(HatchError::setting(
                "hatch.overlap",
                overlap,
                "must be within [0, 1)",
            ));
        }
        Ok(HatchSettings::with_pitch(
            (1.0 - overlap) * spot_diameter_mm,
        ))
    }

    /// Checks every key, naming the one at fault.
    ///
    /// `pitch_mm`, `step_mm` and `grid_mm` must be at least [`MIN_HATCH_LENGTH_MM`]; what a
    /// region gets of them is capped when it is hatched ([`MAX_TRACKS`], [`MAX_POINTS`],
    /// [`MAX_GRID_NODES`]).
    pub fn validate(&self) -> Result<(), HatchError> {
        at_least_a_micrometre("hatch.pitch_mm", self.pitch_mm)?;
        if !(self.angle_deg.is_finite() && self.angle_deg.abs() <= 360.0) {
            // Beyond a few turns an angle's degrees lose the digits its direction is in
            // (1e300° turns the tracks any way at all).
            return Err(HatchError::setting(
                "hatch.angle_deg",
                self.angle_deg,
                "must be within [-360, 360] degrees",
            ));
        }
        if let Some(s) = self.step_mm {
            at_least_a_micrometre("hatch.step_mm", s)?;
        }
        if let Some(t) = self.chord_tolerance_mm {
            positive("hatch.chord_tolerance_mm", t)?;
            if self.step_mm.is_some() {
                return Err(HatchError::setting(
                    "hatch.chord_tolerance_mm",
                    t,
                    "set either hatch.step_mm or hatch.chord_tolerance_mm, not both",
                ));
            }
        }
        if let Some(g) = self.grid_mm {
            at_least_a_micrometre("hatch.grid_mm", g)?;
        }
        Ok(())
    }

    /// How points are placed along tracks.
    #[must_use]
    pub fn point_spacing(&self) -> PointSpacing {
        match (self.chord_tolerance_mm, self.step_mm) {
            (Some(t), _) => PointSpacing::Chord { tolerance_mm: t },
            (None, Some(s)) => PointSpacing::Pitch { step_mm: s },
            (None, None) => PointSpacing::Pitch {
                step_mm: self.pitch_mm,
            },
        }
    }

    /// The hatch direction `(cos, sin)` in plane coordinates.
    #[must_use]
    pub fn along(&self) -> [f64; 2] {
        let a = self.angle_deg.to_radians();
        [a.cos(), a.sin()]
    }
}

/// Refuses a length that is not a finite number ≥ [`MIN_HATCH_LENGTH_MM`], naming the key.
fn at_least_a_micrometre(key: &'static str, v: f64) -> Result<(), HatchError> {
    if v.is_finite() && v >= MIN_HATCH_LENGTH_MM {
        Ok(())
    } else {
        Err(HatchError::setting(
            key,
            v,
            format!("must be a finite number ≥ {MIN_HATCH_LENGTH_MM} mm (1 µm)"),
        ))
    }
}

/// Refuses a region whose tracks would number more than [`MAX_TRACKS`] or hold more than
/// [`MAX_POINTS`] points, naming the key that sets the count: the width across the hatch
/// direction over the pitch, and that times the length along it over the point step (a lower
/// bound: tracks run along the surface, not its plane).
fn check_track_budget(
    polygon: &Polygon,
    settings: &HatchSettings,
    along: [f64; 2],
    across: [f64; 2],
) -> Result<(), HatchError> {
    let extent = |dir: [f64; 2]| {
        let (lo, hi) = polygon
            .vertices()
            .iter()
            .map(|v| v[0] * dir[0] + v[1] * dir[1])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            });
        hi - lo
    };
    let (width, length) = (extent(across), extent(along));
    let tracks = (width / settings.pitch_mm).ceil();
    if tracks.is_nan() || tracks > MAX_TRACKS as f64 {
        return Err(HatchError::setting(
            "hatch.pitch_mm",
            settings.pitch_mm,
            format!(
                "the region is {width:.4} mm across the hatch direction: {tracks} tracks, more than \
                 the {MAX_TRACKS} a region may have"
            ),
        ));
    }
    let (key, step) = match settings.point_spacing() {
        PointSpacing::Pitch { step_mm } if settings.step_mm.is_some() => ("hatch.step_mm", step_mm),
        PointSpacing::Pitch { step_mm } => ("hatch.pitch_mm", step_mm),
        // Chord placement keeps at most the dense samples, bounded by the grid.
        PointSpacing::Chord { .. } => return Ok(()),
    };
    let points = (tracks + 1.0) * (length / step).ceil();
    if points.is_nan() || points > MAX_POINTS as f64 {
        return Err(HatchError::setting(
            key,
            step,
            format!(
                "{tracks} tracks over the region's {length:.4} mm along the hatch direction hold \
                 about {points} points, more than the {MAX_POINTS} a region may have"
            ),
        ));
    }
    Ok(())
}

fn positive(key: &'static str, v: f64) -> Result<(), HatchError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(HatchError::setting(key, v, "must be a finite number > 0"))
    }
}

/// Everything that makes hatching refuse.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HatchError {
    /// A settings value is out of range.
    #[error("setting {key} = {value}: {message}")]
    InvalidSetting {
        /// The dotted key (`hatch.pitch_mm`).
        key: &'static str,
        /// The value given, as text.
        value: String,
        /// What is accepted.
        message: String,
    },
    /// The scan holds no points.
    #[error("the scan is empty")]
    EmptyScan,
    /// A point is NaN or infinite.
    #[error("{what} point {index} is not finite")]
    NonFinite {
        /// "scan" or "boundary".
        what: &'static str,
        /// 0-based index.
        index: usize,
    },
    /// The boundary has too few distinct points.
    #[error("the boundary needs at least {needed} distinct points, got {got}")]
    BoundaryTooShort {
        /// The minimum.
        needed: usize,
        /// Distinct points given.
        got: usize,
    },
    /// The boundary's last point is too far from its first for the closing edge to be implied.
    #[error(
        "the boundary is not closed: its last point is {gap_mm:.4} mm from its first, more than \
         {BOUNDARY_CLOSING_EDGE_FACTOR} × its longest edge ({longest_edge_mm:.4} mm), so it is an \
         open curve, not a region (the closing edge is implied when it is no longer than that)"
    )]
    BoundaryNotClosed {
        /// The gap, mm.
        gap_mm: f64,
        /// The longest edge between consecutive points, mm.
        longest_edge_mm: f64,
    },
    /// The boundary crosses or touches itself (seen on the patch's plane): it is no simple
    /// loop, so it encloses no one region (a figure eight's halves cancel in its area).
    #[error(
        "the boundary crosses itself: its edge from point {first} to the next crosses its edge \
         from point {second} to the next, near ({:.3}, {:.3}, {:.3}) mm; a region's boundary is \
         one loop that does not cross itself",
        at.x,
        at.y,
        at.z
    )]
    BoundaryCrossesItself {
        /// The first edge's starting point (0-based, in the boundary's order).
        first: usize,
        /// The second edge's starting point.
        second: usize,
        /// The first edge's starting point, mm.
        at: Point3,
    },
    /// A boundary vertex does not lie on the scanned surface.
    #[error(
        "boundary point {index} is {distance_mm:.4} mm off the scanned surface (at most \
         {BOUNDARY_ON_SURFACE_TOL_MM} mm)"
    )]
    BoundaryOffSurface {
        /// 0-based vertex index.
        index: usize,
        /// Its distance from the fitted surface (mm; infinite where there is no scan under it).
        distance_mm: f64,
    },
    /// Too few scan points for a step.
    #[error("{what}: needs at least {needed}, got {got}")]
    TooFewPoints {
        /// What was being fitted.
        what: &'static str,
        /// The minimum.
        needed: usize,
        /// What was found.
        got: usize,
    },
    /// The pitch is wider than the region across the hatch direction.
    #[error(
        "pitch {pitch_mm} mm is larger than the region, {width_mm:.4} mm across the hatch direction"
    )]
    PitchTooLarge {
        /// The pitch, mm.
        pitch_mm: f64,
        /// The region's width across the tracks (along the surface), mm.
        width_mm: f64,
    },
    /// The patch folds over its best-fit plane.
    #[error(
        "the surface inside the boundary is not single-valued over its best-fit plane (slope \
         {slope_deg:.1}° > 80°): split the region"
    )]
    NotAHeightField {
        /// The steepest slope found, degrees.
        slope_deg: f64,
    },
    /// An opening's rim moved inward by the inset turns over: the opening is too narrow.
    #[error(
        "the opening ({area_mm2:.4} mm²) is too narrow to hatch inside its rim moved {inset_mm} mm \
         inward"
    )]
    OpeningTooNarrow {
        /// The inset, mm.
        inset_mm: f64,
        /// The opening's area, mm².
        area_mm2: f64,
    },
    /// Part of the region has no scan support.
    #[error("no scan support at plane coordinates ({s:.3}, {t:.3}) mm inside the boundary")]
    NoSupport {
        /// Plane coordinate s, mm.
        s: f64,
        /// Plane coordinate t, mm.
        t: f64,
    },
    /// A geometry error (building the output path).
    #[error(transparent)]
    Geom(#[from] GeomError),
}

impl HatchError {
    /// An out-of-range setting.
    pub fn setting(key: &'static str, value: impl ToString, message: impl Into<String>) -> Self {
        HatchError::InvalidSetting {
            key,
            value: trim_geom::number::compact(value.to_string()),
            message: message.into(),
        }
    }
}

/// What a track is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackKind {
    /// A hatch track; `level` counts the tracks across the region from the seed side (0-based),
    /// pieces of one level (a non-convex region) share it.
    Hatch {
        /// The level index.
        level: usize,
    },
    /// The outline along the boundary.
    Outline,
}

/// One track in execution order: world points (mm) with unit surface normals (toward the
/// patch's `e3` side: the input normals' side when given, else world +Z).
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// The track id (the path CSV `contour`), 0-based in execution order.
    pub id: i64,
    /// Hatch level or outline.
    pub kind: TrackKind,
    /// The points in marking order, world frame, mm.
    pub points: Vec<Point3>,
    /// One unit normal per point, world frame.
    pub normals: Vec<Vector3>,
}

/// Long-running stages of [`hatch_with_progress`], in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HatchStage {
    /// Fitting the surface model to the scan.
    Fit,
    /// Planning tracks (the distance field, or the slab iterations).
    Tracks,
    /// Placing points along the tracks.
    Sample,
}

/// The planned hatch.
#[derive(Debug, Clone)]
pub struct Hatch {
    /// Tracks in serpentine execution order (the outline, if any, last).
    pub tracks: Vec<Track>,
    /// The method used.
    pub method: HatchMethod,
    /// The pitch, mm.
    pub pitch_mm: f64,
    /// The hatch direction at the plane, world, unit.
    pub direction: Vector3,
    /// The surface model the tracks were planned on (frame, height field, scan points inside).
    pub surface: Surface,
    /// The boundary polygon's vertices in plane coordinates (mm).
    pub boundary_plane: Vec<[f64; 2]>,
}

impl Hatch {
    /// The hatch tracks (without the outline).
    pub fn hatch_tracks(&self) -> impl Iterator<Item = &Track> {
        self.tracks
            .iter()
            .filter(|t| matches!(t.kind, TrackKind::Hatch { .. }))
    }

    /// The number of points over all tracks.
    #[must_use]
    pub fn num_points(&self) -> usize {
        self.tracks.iter().map(|t| t.points.len()).sum()
    }

    /// The plane frame of the patch.
    #[must_use]
    pub fn frame(&self) -> &PlaneFrame {
        self.surface.frame()
    }

    /// The tracks as a path (contour = track id, feature vectors = the normals), for
    /// `trim_geom::formats::write_path`. Tracks of fewer than two points are left out.
    pub fn to_path(&self) -> Result<Path, HatchError> {
        let contours = self
            .tracks
            .iter()
            .filter(|t| t.points.len() >= 2)
            .map(|t| Contour::with_features(t.id, t.points.clone(), t.normals.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Path::new(contours)?)
    }
}

/// Checks a boundary: finite, closed, at least [`MIN_BOUNDARY_POINTS`] distinct vertices.
/// See [`close_boundary`] for what closed means.
pub fn check_boundary(boundary: &[Point3]) -> Result<(), HatchError> {
    close_boundary(boundary).map(|_| ())
}

/// The boundary as a closed polyline (its last point repeats its first): as given when its last
/// point is within [`BOUNDARY_CLOSURE_TOL_MM`] of its first, else with the closing edge added
/// (a boundary is a polygon) when that edge is at most [`BOUNDARY_CLOSING_EDGE_FACTOR`] × the
/// longest edge between its points. Refuses non-finite points, fewer than
/// [`MIN_BOUNDARY_POINTS`] distinct vertices, and a wider gap (an open curve).
pub fn close_boundary(boundary: &[Point3]) -> Result<Vec<Point3>, HatchError> {
    if let Some(i) = boundary
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(HatchError::NonFinite {
            what: "boundary",
            index: i,
        });
    }
    let edges: Vec<f64> = boundary.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
    let gap = match (boundary.first(), boundary.last()) {
        (Some(a), Some(b)) => (b - a).norm(),
        _ => 0.0,
    };
    let repeated = gap <= BOUNDARY_CLOSURE_TOL_MM;
    // Distinct vertices: the points that start an edge of non-zero length, plus the last one
    // unless it repeats the first.
    let distinct = edges.iter().filter(|&&e| e > 1e-9).count() + usize::from(!repeated);
    if boundary.len() < MIN_BOUNDARY_POINTS || distinct < MIN_BOUNDARY_POINTS {
        return Err(HatchError::BoundaryTooShort {
            needed: MIN_BOUNDARY_POINTS,
            got: distinct.min(boundary.len()),
        });
    }
    let mut closed = boundary.to_vec();
    if !repeated {
        let longest_edge_mm = edges.iter().copied().fold(0.0, f64::max);
        if gap > BOUNDARY_CLOSING_EDGE_FACTOR * longest_edge_mm {
            return Err(HatchError::BoundaryNotClosed {
                gap_mm: gap,
                longest_edge_mm,
            });
        }
        closed.push(boundary[0]);
    }
    Ok(closed)
}

/// Plans the hatch (see the module docs). `boundary` is a polygon on the surface, world frame,
/// mm: its last point may repeat the first, or the closing edge is implied ([`close_boundary`]).
pub fn hatch(
    cloud: &PointCloud,
    boundary: &[Point3],
    settings: &HatchSettings,
) -> Result<Hatch, HatchError> {
    hatch_with_progress(cloud, boundary, settings, &mut |_| {})
}

/// [`hatch`], calling `progress` as each stage starts.
pub fn hatch_with_progress(
    cloud: &PointCloud,
    boundary: &[Point3],
    settings: &HatchSettings,
    progress: &mut dyn FnMut(HatchStage),
) -> Result<Hatch, HatchError> {
    settings.validate()?;
    if cloud.is_empty() {
        return Err(HatchError::EmptyScan);
    }
    if let Some(i) = cloud
        .points()
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(HatchError::NonFinite {
            what: "scan",
            index: i,
        });
    }
    let boundary = &close_boundary(boundary)?;
    progress(HatchStage::Fit);
    let surface = Surface::fit(cloud, boundary, settings.grid_mm)?;
    for (index, p) in boundary.iter().enumerate() {
        let d = surface.offset(p).unwrap_or(f64::INFINITY);
        if d > BOUNDARY_ON_SURFACE_TOL_MM {
            return Err(HatchError::BoundaryOffSurface {
                index,
                distance_mm: d,
            });
        }
    }
    let frame = *surface.frame();
    let polygon = Polygon::new(boundary.iter().map(|p| frame.to_plane(p)).collect());
    let along = settings.along();
    let across = [-along[1], along[0]];
    check_track_budget(&polygon, settings, along, across)?;
    let spacing = settings.point_spacing();
    progress(HatchStage::Tracks);
    let mut tracks = match settings.method {
        HatchMethod::Geodesic => geodesic_tracks(&surface, &polygon, settings, along, across)?,
        HatchMethod::Slab => slab::slab_tracks(&surface, &polygon, settings, along, across)?,
    };
    progress(HatchStage::Sample);
    if settings.outline {
        let start = tracks
            .last()
            .and_then(|t| t.points.last())
            .map(|p| frame.to_plane(p));
        let mut ring: Vec<[f64; 2]> = polygon.vertices().to_vec();
        if let Some(s) = start {
            let nearest = ring
                .iter()
                .enumerate()
                .min_by(|a, b| dist2(*a.1, s).total_cmp(&dist2(*b.1, s)))
                .map_or(0, |(i, _)| i);
            ring.rotate_left(nearest);
        }
        if let Some(first) = ring.first().copied() {
            ring.push(first);
        }
        if let Some((_, points, normals)) = sample::sample_track(&surface, &ring, spacing) {
            // A closed loop needs three points besides its closing repeat: a step longer than
            // a third of it left the outline as its start twice, a track of zero length.
            if points.len() < 4
                && let PointSpacing::Pitch { step_mm } = spacing
            {
                let perimeter: f64 = ring.windows(2).map(|w| dist2(w[0], w[1]).sqrt()).sum();
                return Err(HatchError::setting(
                    "hatch.step_mm",
                    step_mm,
                    format!(
                        "the outline along the boundary is about {perimeter:.3} mm long, and a \
                         step over a third of it leaves it no loop; give a shorter step, or no \
                         outline"
                    ),
                ));
            }
            tracks.push(Track {
                id: 0,
                kind: TrackKind::Outline,
                points,
                normals,
            });
        }
    }
    for (k, t) in tracks.iter_mut().enumerate() {
        t.id = k as i64;
    }
    Ok(Hatch {
        tracks,
        method: settings.method,
        pitch_mm: settings.pitch_mm,
        direction: frame.plane_vector(along),
        surface,
        boundary_plane: polygon.vertices().to_vec(),
    })
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// The levels `L₀ + k·pitch` centred over `[d_min, d_max]`: `n = ⌈width/pitch⌉` tracks with
/// equal margins (each ≤ pitch/2) at both sides.
pub(crate) fn centred_levels(d_min: f64, d_max: f64, pitch: f64) -> Result<Vec<f64>, HatchError> {
    let width = d_max - d_min;
    if pitch > width {
        return Err(HatchError::PitchTooLarge {
            pitch_mm: pitch,
            width_mm: width,
        });
    }
    let n = ((width / pitch - 1e-9).ceil() as usize).max(1);
    let margin = 0.5 * (width - (n - 1) as f64 * pitch);
    Ok((0..n).map(|k| d_min + margin + k as f64 * pitch).collect())
}

/// The default method: geodesic iso-distance tracks.
fn geodesic_tracks(
    surface: &Surface,
    polygon: &Polygon,
    settings: &HatchSettings,
    along: [f64; 2],
    across: [f64; 2],
) -> Result<Vec<Track>, HatchError> {
    let h = surface.grid_mm();
    let c0 = geodesic::seed_offset(polygon, across);
    let field = geodesic::DistanceField::compute(surface, across, c0);
    // Extremes of the distance over the region: on its boundary (a distance function has no
    // interior extremum).
    let (mut d_min, mut d_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let vertices = polygon.vertices();
    for k in 0..vertices.len() {
        let (a, b) = (vertices[k], vertices[(k + 1) % vertices.len()]);
        let n = ((dist2(a, b).sqrt() / (0.5 * h)).ceil() as usize).max(1);
        for m in 0..n {
            let u = m as f64 / n as f64;
            let st = [a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])];
            let d = field
                .at(surface, st)
                .ok_or(HatchError::NoSupport { s: st[0], t: st[1] })?;
            d_min = d_min.min(d);
            d_max = d_max.max(d);
        }
    }
    let levels = centred_levels(d_min, d_max, settings.pitch_mm)?;
    let mut pieces: Vec<geodesic::IsoPiece> = Vec::new();
    for (level, mut line) in field.iso_lines(surface, &levels) {
        let (Some(a), Some(b)) = (line.first(), line.last()) else {
            continue;
        };
        if (b[0] - a[0]) * along[0] + (b[1] - a[1]) * along[1] < 0.0 {
            line.reverse();
        }
        for points in geodesic::clip(polygon, &line) {
            pieces.push(geodesic::IsoPiece { level, points });
        }
    }
    let key = |p: &geodesic::IsoPiece| p.points[0][0] * along[0] + p.points[0][1] * along[1];
    pieces.sort_by(|a, b| a.level.cmp(&b.level).then(key(a).total_cmp(&key(b))));
    // Serpentine: odd levels run backward, their pieces in reverse order.
    let mut ordered: Vec<geodesic::IsoPiece> = Vec::with_capacity(pieces.len());
    let mut k = 0;
    while k < pieces.len() {
        let level = pieces[k].level;
        let end = k + pieces[k..].iter().take_while(|p| p.level == level).count();
        let mut group: Vec<_> = pieces[k..end].to_vec();
        if level % 2 == 1 {
            group.reverse();
            for p in &mut group {
                p.points.reverse();
            }
        }
        ordered.extend(group);
        k = end;
    }
    let spacing = settings.point_spacing();
    let sampled: Vec<Option<Track>> = {
        use rayon::prelude::*;
        ordered
            .par_iter()
            .map(|p| {
                let (_, points, normals) = sample::sample_track(surface, &p.points, spacing)?;
                Some(Track {
                    id: 0,
                    kind: TrackKind::Hatch { level: p.level },
                    points,
                    normals,
                })
            })
            .collect()
    };
    let mut tracks = Vec::with_capacity(sampled.len());
    for (t, p) in sampled.into_iter().zip(&ordered) {
        let t = t.ok_or(HatchError::NoSupport {
            s: p.points[0][0],
            t: p.points[0][1],
        })?;
        tracks.push(t);
    }
    Ok(tracks)
}

/// The paper's tool posture (§2.4, Eq. 1–2): the tool frame `{T}` with `k` the nozzle (laser)
/// axis along `normal`, `j` the travel direction made perpendicular to it, `i = j × k`, written
/// as Z–Y–X Euler angles `R = Rz(α)·Ry(β)·Rx(γ)`. Returns `(α, β, γ)` in radians, or `None` when
/// `travel` is parallel to `normal`. Both vectors in the same (world) frame.
#[must_use]
pub fn posture_euler_zyx_rad(normal: &Vector3, travel: &Vector3) -> Option<(f64, f64, f64)> {
    let k = normal.try_normalize(1e-12)?;
    let j = (travel - k * travel.dot(&k)).try_normalize(1e-12)?;
    let i = j.cross(&k);
    // R = (i j k) as columns; β = atan2(−r31, √(r11² + r21²)), α = atan2(r21, r11),
    // γ = atan2(r32, r33) (the paper's division by cos β cancels inside atan2).
    let (r11, r21, r31) = (i.x, i.y, i.z);
    let (r32, r33) = (j.z, k.z);
    let beta = (-r31).atan2(r11.hypot(r21));
    let alpha = r21.atan2(r11);
    let gamma = r32.atan2(r33);
    Some((alpha, beta, gamma))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_centred_and_cover() {
        let l = centred_levels(0.0, 10.2, 1.0).unwrap();
        assert_eq!(l.len(), 11);
        assert!((l[0] - 0.1).abs() < 1e-12 && (l[10] - 10.1).abs() < 1e-12);
        let l = centred_levels(0.0, 10.0, 1.0).unwrap();
        assert_eq!(l.len(), 10);
        assert!((l[0] - 0.5).abs() < 1e-12);
        assert!(matches!(
            centred_levels(0.0, 0.5, 1.0),
            Err(HatchError::PitchTooLarge { .. })
        ));
    }

    #[test]
    fn posture_reproduces_its_rotation() {
        let n = Vector3::new(0.3, -0.2, 1.0).normalize();
        let t = Vector3::new(1.0, 0.4, 0.0);
        let (a, b, g) = posture_euler_zyx_rad(&n, &t).unwrap();
        let r = nalgebra::Rotation3::from_euler_angles(g, b, a);
        assert!((r * Vector3::z() - n).norm() < 1e-12);
        assert!(posture_euler_zyx_rad(&n, &n).is_none());
    }

    #[test]
    fn boundary_checks() {
        let sq = |close: bool| {
            let mut v = vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(1.0, 1.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ];
            if close {
                v.push(v[0]);
            }
            v
        };
        assert_eq!(close_boundary(&sq(true)).unwrap(), sq(true));
        // A polygon: the closing edge is implied.
        assert_eq!(close_boundary(&sq(false)).unwrap(), sq(true));
        // A gap of 0.005 mm repeats the first point: kept as given.
        let mut almost = sq(true);
        almost[4].x += 0.005;
        assert_eq!(close_boundary(&almost).unwrap(), almost);
        // Three sides of a square with a point every 0.1 mm: a 1 mm gap is an open curve.
        let u: Vec<Point3> = (0..=30)
            .map(|k| {
                let s = f64::from(k) * 0.1;
                match k {
                    0..=10 => Point3::new(0.0, 1.0 - s, 0.0),
                    11..=20 => Point3::new(s - 1.0, 0.0, 0.0),
                    _ => Point3::new(1.0, s - 2.0, 0.0),
                }
            })
            .collect();
        match close_boundary(&u) {
            Err(e @ HatchError::BoundaryNotClosed { .. }) => {
                let m = e.to_string();
                assert!(m.contains("1.0000 mm") && m.contains("0.1000 mm"), "{m}");
            }
            other => panic!("an open curve: {other:?}"),
        }
        assert!(matches!(
            check_boundary(&sq(true)[3..]),
            Err(HatchError::BoundaryTooShort { .. })
        ));
        assert!(matches!(
            check_boundary(&[sq(true)[0], sq(true)[1], sq(true)[0]]),
            Err(HatchError::BoundaryTooShort { got: 2, .. })
        ));
        let mut nan = sq(true);
        nan[1].x = f64::NAN;
        assert!(matches!(
            check_boundary(&nan),
            Err(HatchError::NonFinite { index: 1, .. })
        ));
        assert!("slab".parse::<HatchMethod>().is_ok());
        assert!("heat".parse::<HatchMethod>().is_err());
        assert!(HatchSettings::with_pitch(0.0).validate().is_err());
        for (angle_deg, ok) in [
            (-360.0, true),
            (359.5, true),
            (361.0, false),
            (1e300, false),
        ] {
            let s = HatchSettings {
                angle_deg,
                ..HatchSettings::with_pitch(0.1)
            };
            match s.validate() {
                Ok(()) => assert!(ok, "{angle_deg} was accepted"),
                Err(e) => {
                    let e = e.to_string();
                    assert!(
                        !ok && e.contains("hatch.angle_deg") && e.contains("[-360, 360]"),
                        "{e}"
                    );
                }
            }
        }
        assert!((HatchSettings::from_spot(2.0, 0.2).unwrap().pitch_mm - 1.6).abs() < 1e-12);
    }
}
