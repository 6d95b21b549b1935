//! The coarse similarity (DESIGN.md "Registration", steps 2–3). The *capture* fits starts from
//! the fixture's nominal pose at the pyramid's top level, scores each by how much of the scan it
//! lays on the CAD, keeps the best and refuses it when it puts the part beyond the capture range;
//! the *refinement* then runs scan → CAD point-to-plane ICP with scale down the whole voxel
//! pyramid again, against the CAD culled at the captured pose.

use super::settings::{CoarseInit, CoarseSettings};
use crate::error::{RegisterError, Result};
use crate::icp::{IcpMethod, IcpResult, IcpSettings, IcpTarget, PyramidLevel, icp};
use crate::kdtree;
use crate::kdtree::Scratch;
use crate::kernel::RobustKernel;
use crate::sampling::{VoxelPyramid, dense_voxel_centroids};
use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;
use trim_geom::{Point3, PointCloud, Similarity3, Vector3};

/// The coarse stage refuses a scale change beyond `exp(±0.1)` (±10 %) from the fixture's: no
/// part is that far off, and a scan → CAD fit that gets there is shrinking onto the surface.
pub const MAX_COARSE_LOG_SCALE_CHANGE: f64 = 0.1;

/// Principal axes count as defined when consecutive variances differ by this factor.
pub const MIN_AXIS_VARIANCE_RATIO: f64 = 1.3;

/// A fit may put the part this far beyond `capture_rotation_deg`, degrees, before it is refused:
/// the coarse similarity of a deformed part differs from the fixture's placement by the share of
/// bend and twist it absorbs (0.03° on the synthetic cores), so a part placed at the range's edge
/// is not refused for rounding.
pub const CAPTURE_MARGIN_DEG: f64 = 1.0;

/// The same beyond `capture_translation_mm`, mm: the offset is measured at the visible CAD's
/// centroid, which a rotation about another point also moves (0.7 mm at 20° for the synthetic
/// core's centroid, 2 mm off its origin; 1.1 mm with the fixed-view scanner, whose visible
/// faces lie farther off it).
pub const CAPTURE_MARGIN_MM: f64 = 1.5;

/// A start is scored by the share of the scan's points (its top-level voxels, each weighted by
/// its points) within this distance of the CAD after its fit, mm: above the rigid top level's misfit on a deformed part (bend ≤ 0.5 mm),
/// below what a start that slid or turned off the part leaves.
pub const CAPTURE_INLIER_MM: f64 = 1.0;

/// The first start is kept, and no other tried, when its score reaches this (the synthetic cores
/// score 0.97–0.99 when captured).
pub const CAPTURE_ACCEPT_SCORE: f64 = 0.9;

/// The best start must score at least this, or nothing captured the part.
pub const CAPTURE_MIN_SCORE: f64 = 0.6;

/// The further starts turn the nominal rotation by ± this about each principal axis of the
/// visible CAD, degrees: with the nominal rotation itself they cover the capture range with
/// starts that each lie well inside the top level's basin (above 20° on the cores).
pub const CAPTURE_STEP_DEG: f64 = 15.0;

/// Two starts closer than this (rotation, radians) are the same start.
const SAME_START_RAD: f64 = 1e-6;

/// How far a `scan_from_cad` puts the part from the fixture's nominal one: the angle of the
/// rotation between them and the distance the visible CAD's centroid moves (scan frame), so that
/// neither depends on where the CAD's origin lies.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseOffset {
    /// Rotation angle, degrees.
    pub rotation_deg: f64,
    /// Displacement of the CAD's centroid, mm.
    pub translation_mm: f64,
}

impl PoseOffset {
    /// The offset of `scan_from_cad` from `scan_from_cad_nominal`, the displacement taken at
    /// `centroid_cad` (CAD frame).
    #[must_use]
    pub fn between(
        scan_from_cad_nominal: &Similarity3,
        scan_from_cad: &Similarity3,
        centroid_cad: &Point3,
    ) -> Self {
        let rotation =
            scan_from_cad_nominal.isometry.rotation.inverse() * scan_from_cad.isometry.rotation;
        PoseOffset {
            rotation_deg: rotation.angle().to_degrees(),
            translation_mm: (scan_from_cad * centroid_cad - scan_from_cad_nominal * centroid_cad)
                .norm(),
        }
    }

    /// Whether it lies within the capture range of `settings` (plus the margins).
    #[must_use]
    pub fn within(&self, settings: &CoarseSettings) -> bool {
        self.rotation_deg <= settings.capture_rotation_deg + CAPTURE_MARGIN_DEG
            && self.translation_mm <= settings.capture_translation_mm + CAPTURE_MARGIN_MM
    }
}

/// The capture's result: the start kept, fitted at the pyramid's top level.
#[derive(Debug, Clone)]
pub struct Capture {
    /// The top level's fit from the kept start (`target_from_source` is `cad_from_scan`).
    pub fit: IcpResult,
    /// Its score: the share of the scan's points (top-level voxels weighted by their points)
    /// within [`CAPTURE_INLIER_MM`] of the whole CAD.
    pub score: f64,
    /// Starts fitted (1 when the first was kept at once).
    pub starts: usize,
    /// How far the fit puts the part from the fixture's nominal pose.
    pub offset: PoseOffset,
    /// The visible CAD's longest principal axis (unit, CAD frame; the CAD frame's x when the
    /// axes are ambiguous): where a slide along the span goes ([`refine_across_slides`]).
    pub long_axis: Vector3,
}

/// The coarse similarity `cad_from_scan`: [`capture`], then [`refine`] against the same target.
pub fn coarse_fit(
    scan: &PointCloud,
    target: &IcpTarget,
    cad_from_scan_nominal: &Similarity3,
    settings: &CoarseSettings,
) -> Result<IcpResult> {
    let pyramid = scan_pyramid(scan, settings)?;
    let captured = capture(
        &pyramid,
        target,
        target.tree(),
        cad_from_scan_nominal,
        settings,
    )?;
    refine(&pyramid, target, &captured, settings)
}

/// The scan's voxel sums at the finest pyramid level, for [`capture`] and [`refine`].
pub fn scan_pyramid<'a>(
    scan: &'a PointCloud,
    settings: &CoarseSettings,
) -> Result<VoxelPyramid<'a>> {
    let finest = settings
        .levels
        .iter()
        .map(|l| l.voxel_mm)
        .fold(f64::INFINITY, f64::min);
    if finest.is_infinite() {
        return Err(RegisterError::setting(
            "coarse.levels",
            "needs at least one level",
        ));
    }
    VoxelPyramid::new(scan.points(), finest)
}

/// A scan voxel takes part in the coarse fit when it holds at least this share of the points
/// of a typical voxel on the surface (the count-weighted median: the voxel a scan point lies
/// in, at the median), besides `min_voxel_points`. Stray points (the synthetic scans' 1 % within
/// 2 mm of the part) fill a voxel ever more often as the scan gets denser: on the project's
/// three-view core at 2M points, a 2 mm voxel held about four of them, and past the three of
/// `min_voxel_points` they outnumbered the surface's voxels at the capture, which laid 27 % of
/// the scan on the CAD and refused the part. A surface voxel held about 800. At the 200k–500k
/// points of the outside cases the share asks for at most 3, so nothing changes there.
pub const SCAN_VOXEL_MIN_SHARE: f64 = 0.01;

/// The scan's voxel centroids at `voxel_mm` with their point counts, those holding fewer than
/// `settings.min_voxel_points` or [`SCAN_VOXEL_MIN_SHARE`] of a typical surface voxel's left
/// out (a subset of the pyramid's dense voxels, in their order).
pub fn scan_voxels(
    scan: &VoxelPyramid<'_>,
    voxel_mm: f64,
    settings: &CoarseSettings,
) -> Result<Vec<(Point3, usize)>> {
    let mut voxels = scan.dense_counted(voxel_mm, settings.min_voxel_points)?;
    let mut counts: Vec<usize> = voxels.iter().map(|&(_, n)| n).collect();
    counts.sort_unstable();
    let total: usize = counts.iter().sum();
    let mut seen = 0;
    let typical = counts
        .iter()
        .find(|&&n| {
            seen += n;
            2 * seen >= total
        })
        .copied()
        .unwrap_or(0);
    let floor = (SCAN_VOXEL_MIN_SHARE * typical as f64).ceil() as usize;
    if floor > settings.min_voxel_points {
        voxels.retain(|&(_, n)| n >= floor);
    }
    Ok(voxels)
}

/// The capture: from the fixture's nominal `cad_from_scan`, the start of `settings.init` is
/// fitted at the pyramid's top level against `target` and kept when it scores
/// [`CAPTURE_ACCEPT_SCORE`]; otherwise the other starts (the nominal rotation, the principal
/// axes, the nominal rotation turned by ±[`CAPTURE_STEP_DEG`] about each principal axis; each
/// with the centroids matched) are fitted too and the best kept: a fit within the capture range
/// before one beyond it, then the best score, the earliest on a tie. Deterministic.
///
/// A fit's score is the share of the scan's points (the top level's voxels, each weighted by its
/// points) within [`CAPTURE_INLIER_MM`] of `part`, the whole CAD (every face, not only those
/// `target` keeps toward the assumed view): a
/// scanner that also looks from below sees faces the view culls, and scored against the culled
/// CAD the project's three-view core (two views above, one below) scored 0.74 at 500k points and
/// 0.57 at 1M, refused below [`CAPTURE_MIN_SCORE`] for being scanned more densely. Scored
/// against every face, a start turned over onto the far faces may score as well as the right
/// one: hence a fit within the range first.
///
/// Refused: [`RegisterError::NotCaptured`] when the best scores below [`CAPTURE_MIN_SCORE`],
/// [`RegisterError::OutsideCaptureRange`] when it puts the part beyond the capture range, the
/// first start's error when no start could be fitted at all.
pub fn capture(
    scan: &VoxelPyramid<'_>,
    target: &IcpTarget,
    part: &kdtree::KdTree,
    cad_from_scan_nominal: &Similarity3,
    settings: &CoarseSettings,
) -> Result<Capture> {
    let level = settings
        .levels
        .first()
        .ok_or_else(|| RegisterError::setting("coarse.levels", "needs at least one level"))?;
    let counted = scan_voxels(scan, level.voxel_mm, settings)?;
    let counts: Vec<usize> = counted.iter().map(|&(_, n)| n).collect();
    let source = PointCloud::new(counted.into_iter().map(|(p, _)| p).collect())?;
    let frame = StartFrame::new(&source, target, cad_from_scan_nominal, level.voxel_mm)?;
    let scan_from_cad_nominal = cad_from_scan_nominal.inverse();
    let last = settings.levels.len() == 1;
    let total: usize = counts.iter().sum();
    let d2 = CAPTURE_INLIER_MM * CAPTURE_INLIER_MM;
    let score = |fit: &IcpResult| {
        let near: usize = source
            .points()
            .par_iter()
            .zip(&counts)
            .map_init(Scratch::default, |scratch, (p, &n)| {
                if part.any_within(&(fit.target_from_source * p), d2, scratch) {
                    n
                } else {
                    0
                }
            })
            .sum();
        near as f64 / total.max(1) as f64
    };
    // Starts are ranked by (within the capture range, score).
    let rank = |fit: &IcpResult| {
        let within = PoseOffset::between(
            &scan_from_cad_nominal,
            &fit.target_from_source.inverse(),
            &frame.cad_centroid,
        )
        .within(settings);
        (within, score(fit))
    };

    let first = frame.first_start(settings, cad_from_scan_nominal);
    let mut tried: Vec<Option<Rotation3>> = vec![first.0];
    let mut first_error = None;
    let mut best: Option<((bool, f64), IcpResult)> = None;
    match fit_level(0, level, last, &source, target, &first.1, settings) {
        Ok(fit) => best = Some((rank(&fit), fit)),
        Err(e) => first_error = Some(e),
    }
    if best
        .as_ref()
        .is_none_or(|((_, s), _)| *s < CAPTURE_ACCEPT_SCORE)
    {
        for rotation in frame.further_rotations() {
            trim_geom::cancel::check()?;
            if tried
                .iter()
                .any(|r| r.is_some_and(|r| r.angle_to(&rotation) < SAME_START_RAD))
            {
                continue;
            }
            tried.push(Some(rotation));
            let start = frame.start(&rotation, cad_from_scan_nominal);
            // A start that cannot be fitted (too few correspondences) is a start that failed.
            if let Ok(fit) = fit_level(0, level, last, &source, target, &start, settings) {
                let r = rank(&fit);
                if best.as_ref().is_none_or(|(b, _)| r > *b) {
                    best = Some((r, fit));
                }
            }
        }
    }
    let starts = tried.len();
    let Some(((_, score), fit)) = best else {
        return Err(first_error.unwrap_or(RegisterError::NotCaptured {
            score_pct: 0.0,
            distance_mm: CAPTURE_INLIER_MM,
            needed_pct: 100.0 * CAPTURE_MIN_SCORE,
            starts,
            max_rotation_deg: settings.capture_rotation_deg,
            max_translation_mm: settings.capture_translation_mm,
        }));
    };
    if score < CAPTURE_MIN_SCORE {
        return Err(RegisterError::NotCaptured {
            score_pct: 100.0 * score,
            distance_mm: CAPTURE_INLIER_MM,
            needed_pct: 100.0 * CAPTURE_MIN_SCORE,
            starts,
            max_rotation_deg: settings.capture_rotation_deg,
            max_translation_mm: settings.capture_translation_mm,
        });
    }
    let offset = PoseOffset::between(
        &scan_from_cad_nominal,
        &fit.target_from_source.inverse(),
        &frame.cad_centroid,
    );
    if !offset.within(settings) {
        return Err(RegisterError::OutsideCaptureRange {
            rotation_deg: offset.rotation_deg,
            translation_mm: offset.translation_mm,
            max_rotation_deg: settings.capture_rotation_deg,
            max_translation_mm: settings.capture_translation_mm,
        });
    }
    Ok(Capture {
        fit,
        score,
        starts,
        offset,
        long_axis: frame.cad_axes.column(0).into_owned(),
    })
}

/// The refinement: every level of the pyramid against `target` (the CAD the scanner saw, culled
/// at the captured pose), from the capture's fit (scale freed at the finest level). The top
/// level is fitted again: the capture's CAD was culled at the *nominal* pose, and on a one-view
/// scan that culling alone decided which pose along the span the top level settled in (seed
/// 202 of the project's core slid 2.1 mm, beyond the finer levels' reach). The result's
/// `iterations` count the capture's too.
pub fn refine(
    scan: &VoxelPyramid<'_>,
    target: &IcpTarget,
    captured: &Capture,
    settings: &CoarseSettings,
) -> Result<IcpResult> {
    let mut result = captured.fit.clone();
    let mut iterations = result.iterations;
    for (k, level) in settings.levels.iter().enumerate() {
        let source = PointCloud::new(
            scan_voxels(scan, level.voxel_mm, settings)?
                .into_iter()
                .map(|(p, _)| p)
                .collect(),
        )?;
        let last = k + 1 == settings.levels.len();
        result = fit_level(
            k,
            level,
            last,
            &source,
            target,
            &result.target_from_source,
            settings,
        )?;
        iterations += result.iterations;
    }
    result.iterations = iterations;
    Ok(result)
}

/// The starts [`refine_across_slides`] tries besides the captured pose: the captured scan
/// moved this far along the CAD's long axis, mm. A slid coarse fit (the project's one-view
/// cores: the scan seen from one side, the span's ends and the holes' far walls only, the
/// capture 1–3 mm along the span and the refinement keeping it there) settles back from a start
/// 1.5–3 mm toward the truth: own seeds 618, 679 and 717 did from +1.5 and +3 mm, 717 from
/// −3 mm too (DESIGN.md "Registration", *A slide along the span, retried*).
pub const SLIDE_SHIFTS_MM: [f64; 4] = [-3.0, -1.5, 1.5, 3.0];

/// A refinement's cost, for choosing between starts: the finest level's mean squared
/// point-to-plane residual, each source point without a correspondence counted at the level's
/// maximum distance, mm².
fn refined_cost(fit: &IcpResult, settings: &CoarseSettings) -> f64 {
    let reach = settings
        .levels
        .last()
        .map_or(0.0, |l| l.max_correspondence_distance_mm);
    fit.fitness * fit.rmse_mm * fit.rmse_mm + (1.0 - fit.fitness) * reach * reach
}

/// [`refine`] from the captured pose and from it moved by each of `shifts_mm` along the CAD's
/// long axis ([`Capture::long_axis`]); the refinement of least [`refined_cost`] is kept (the
/// captured pose's on a tie). Returns it and the shift it started from (mm, 0 for the captured
/// pose). The starts are refined side by side.
pub fn refine_across_slides(
    scan: &VoxelPyramid<'_>,
    target: &IcpTarget,
    captured: &Capture,
    settings: &CoarseSettings,
    shifts_mm: &[f64],
) -> Result<(IcpResult, f64)> {
    let (captured_fit, shifted) = rayon::join(
        || refine(scan, target, captured, settings),
        || {
            shifts_mm
                .par_iter()
                .map(|&shift| {
                    let mut moved = captured.clone();
                    moved.fit.target_from_source =
                        nalgebra::Translation3::from(captured.long_axis * shift)
                            * captured.fit.target_from_source;
                    (refine(scan, target, &moved, settings), shift)
                })
                .collect::<Vec<_>>()
        },
    );
    // The captured pose's failure is the answer; a shifted start that fails is one that did not
    // settle.
    let captured_fit = captured_fit?;
    let mut best_cost = refined_cost(&captured_fit, settings);
    let mut best = (captured_fit, 0.0);
    for (fit, shift) in shifted {
        if let Ok(fit) = fit {
            let cost = refined_cost(&fit, settings);
            if cost < best_cost {
                best_cost = cost;
                best = (fit, shift);
            }
        }
    }
    Ok(best)
}

/// Pyramid level `k`: point-to-plane ICP from `current`, rigid but at the `last` level (when
/// `settings.with_scale`), Huber at `huber_fraction` of the level's maximum distance; a scale
/// change beyond [`MAX_COARSE_LOG_SCALE_CHANGE`] is refused.
fn fit_level(
    k: usize,
    level: &PyramidLevel,
    last: bool,
    source: &PointCloud,
    target: &IcpTarget,
    current: &Similarity3,
    settings: &CoarseSettings,
) -> Result<IcpResult> {
    let s = IcpSettings {
        method: IcpMethod::PointToPlane,
        with_scale: settings.with_scale && last,
        max_correspondence_distance_mm: level.max_correspondence_distance_mm,
        max_iterations: level.max_iterations,
        translation_epsilon_mm: 1e-5,
        rotation_epsilon_rad: 1e-7,
        scale_epsilon: 1e-7,
        kernel: RobustKernel::Huber {
            k_mm: settings.huber_fraction * level.max_correspondence_distance_mm,
        },
        trim_fraction: 0.0,
        min_correspondences: 50,
    };
    let r = icp(source, target, current, &s).map_err(|e| match e {
        RegisterError::TooFewCorrespondences { got, .. } => RegisterError::NotOverlapping {
            fraction_pct: 100.0 * got as f64 / source.len().max(1) as f64,
            distance_mm: level.max_correspondence_distance_mm,
            needed_pct: 100.0 * 50.0 / source.len().max(1) as f64,
        },
        RegisterError::Singular { stage, eigenvalues } => RegisterError::Singular {
            stage: format!("coarse level {k}: {stage}"),
            eigenvalues,
        },
        other => other,
    })?;
    let scale_change = (r.target_from_source.scaling() / current.scaling())
        .ln()
        .abs();
    if scale_change > MAX_COARSE_LOG_SCALE_CHANGE {
        return Err(RegisterError::RunawayScale {
            stage: format!("coarse level {k}"),
            from: current.scaling(),
            to: r.target_from_source.scaling(),
        });
    }
    Ok(r)
}

type Rotation3 = nalgebra::UnitQuaternion<f64>;

/// What the starts are built from, in the CAD frame with the scan placed at the nominal pose:
/// the centroids and principal axes of the scan's and the visible CAD's dense voxels.
struct StartFrame {
    /// The nominally placed scan's centroid.
    scan_centroid: Point3,
    /// The visible CAD's centroid.
    cad_centroid: Point3,
    /// The rotation taking the scan's principal axes onto the CAD's, the sign choice nearest the
    /// identity; `None` when either set of axes is ambiguous.
    principal: Option<Rotation3>,
    /// The visible CAD's principal axes (columns), or the CAD frame's when ambiguous.
    cad_axes: Matrix3<f64>,
}

impl StartFrame {
    fn new(
        source: &PointCloud,
        target: &IcpTarget,
        cad_from_scan_nominal: &Similarity3,
        voxel_mm: f64,
    ) -> Result<Self> {
        // Both clouds thinned alike (the scan's dense voxels are `source`), the scan taken to the
        // CAD frame.
        let scan_pts: Vec<Point3> = source
            .points()
            .iter()
            .map(|p| cad_from_scan_nominal * p)
            .collect();
        let cad_pts = dense_voxel_centroids(target.cloud().points(), voxel_mm, 1)?;
        if scan_pts.len() < 3 || cad_pts.len() < 3 {
            return Err(RegisterError::TooFewCorrespondences {
                stage: "coarse start (voxel centroids)".into(),
                needed: 3,
                got: scan_pts.len().min(cad_pts.len()),
                max_distance_mm: f64::INFINITY,
            });
        }
        let (cs, covs) = moments(&scan_pts);
        let (cc, covc) = moments(&cad_pts);
        let (es, ok_s) = principal_axes(&covs);
        let (ec, ok_c) = principal_axes(&covc);
        let principal = (ok_s && ok_c).then(|| nearest_axes_rotation(&es, &ec));
        Ok(StartFrame {
            scan_centroid: cs,
            cad_centroid: cc,
            principal,
            cad_axes: if ok_c { ec } else { Matrix3::identity() },
        })
    }

    /// The start `cad_from_scan`: the nominally placed scan turned by `rotation` about its
    /// centroid and moved onto the CAD's centroid.
    fn start(&self, rotation: &Rotation3, cad_from_scan_nominal: &Similarity3) -> Similarity3 {
        let t = self.cad_centroid.coords - rotation * self.scan_centroid.coords;
        Similarity3::from_parts(nalgebra::Translation3::from(t), *rotation, 1.0)
            * cad_from_scan_nominal
    }

    /// The start of `settings.init`: its correction rotation (`None` for the nominal pose as
    /// given) and `cad_from_scan`. The principal axes' rotation is used only within the capture
    /// range; beyond it, or when the axes are ambiguous, the nominal rotation.
    fn first_start(
        &self,
        settings: &CoarseSettings,
        cad_from_scan_nominal: &Similarity3,
    ) -> (Option<Rotation3>, Similarity3) {
        let max_rad = (settings.capture_rotation_deg + CAPTURE_MARGIN_DEG).to_radians();
        let rotation = match (settings.init, self.principal) {
            (CoarseInit::Nominal, _) => return (None, *cad_from_scan_nominal),
            (CoarseInit::PrincipalAxes, Some(r)) if r.angle() <= max_rad => r,
            _ => Rotation3::identity(),
        };
        (Some(rotation), self.start(&rotation, cad_from_scan_nominal))
    }

    /// The further starts' rotations, in order: the nominal rotation, the principal axes' (at
    /// any angle: a part beyond the range is then found and refused as such), and the nominal
    /// rotation turned by ±[`CAPTURE_STEP_DEG`] about each of the CAD's principal axes.
    fn further_rotations(&self) -> Vec<Rotation3> {
        let mut out = vec![Rotation3::identity()];
        out.extend(self.principal);
        for axis in self.cad_axes.column_iter() {
            for sign in [1.0, -1.0] {
                out.push(Rotation3::from_scaled_axis(
                    axis.into_owned() * (sign * CAPTURE_STEP_DEG.to_radians()),
                ));
            }
        }
        out
    }
}

/// The rotation `R` with `R·esᵢ = ±ecᵢ` (principal axes as columns), of the four proper sign
/// choices the one nearest the identity.
fn nearest_axes_rotation(es: &Matrix3<f64>, ec: &Matrix3<f64>) -> Rotation3 {
    let mut best: Option<(f64, Matrix3<f64>)> = None;
    for signs in [
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ] {
        let ec_signed = Matrix3::from_columns(&[0, 1, 2].map(|i| ec.column(i) * signs[i]));
        let mut r = ec_signed * es.transpose();
        if r.determinant() < 0.0 {
            // es or ec is left-handed: flip the least-variance axis.
            let mut e = ec_signed;
            e.set_column(2, &(-ec_signed.column(2)));
            r = e * es.transpose();
        }
        let angle = nalgebra::Rotation3::from_matrix_unchecked(r).angle();
        if best.is_none_or(|(a, _)| angle < a) {
            best = Some((angle, r));
        }
    }
    let r = best.map_or_else(Matrix3::identity, |(_, r)| r);
    Rotation3::from_matrix(&r)
}

/// Centroid and covariance of points.
#[must_use]
pub fn moments(points: &[Point3]) -> (Point3, Matrix3<f64>) {
    let n = points.len().max(1) as f64;
    let c: Vector3 = points.iter().map(|p| p.coords).sum::<Vector3>() / n;
    let cov: Matrix3<f64> = points
        .iter()
        .map(|p| (p.coords - c) * (p.coords - c).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    (Point3::from(c), cov)
}

/// Principal axes (columns, by descending variance) and whether their variances are distinct
/// enough (ratio ≥ [`MIN_AXIS_VARIANCE_RATIO`]) for the axes to be defined.
#[must_use]
pub fn principal_axes(cov: &Matrix3<f64>) -> (Matrix3<f64>, bool) {
    let eig = SymmetricEigen::new(*cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let v = order.map(|i| eig.eigenvalues[i]);
    let distinct = v[1] > 0.0
        && v[0] / v[1] >= MIN_AXIS_VARIANCE_RATIO
        && v[1] / v[2].max(f64::MIN_POSITIVE) >= MIN_AXIS_VARIANCE_RATIO;
    let axes = Matrix3::from_columns(&order.map(|i| eig.eigenvectors.column(i).into_owned()));
    (axes, distinct)
}

pub(crate) fn overlap_fraction(points: &[Point3], tree: &kdtree::KdTree, distance_mm: f64) -> f64 {
    let d2 = distance_mm * distance_mm;
    let near = points
        .par_iter()
        .map_init(Scratch::default, |scratch, p| {
            usize::from(tree.any_within(p, d2, scratch))
        })
        .sum::<usize>();
    near as f64 / points.len().max(1) as f64
}
