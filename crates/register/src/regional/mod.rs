//! Regional registration of a trimming path onto a scan of a deformed part (DESIGN.md
//! "Registration").
//!
//! 1. **Visibility.** Only CAD faces that face the scanner (`n·v ≥ facing_min_cos`) take part:
//!    the far side of the slab and walls turned away can never be in the scan.
//! 2. **Coarse similarity.** Scan → CAD point-to-plane ICP with scale on a voxel pyramid (coarse
//!    scan voxels and a large maximum distance, shrinking), from the fixture's nominal pose. The
//!    scan is the source: every scan point has its counterpart on the (whole, unclipped) CAD, so
//!    no clip border pulls the fit inward and no unseen face attracts it.
//! 3. **Deformation field.** A quadratic B-spline displacement field `F(x) = x + d(x)` over the
//!    part ([`crate::deformation`]), fitted by Gauss-Newton to scan → CAD point-to-plane residuals
//!    `r = n'·(F(c) − q)` (CAD normals carried by `F`; scan points matched within a sample
//!    spacing of a sharp edge left out, their face being a biased guess; a match whose scan
//!    normal turns from its CAD face's, or that lies beyond the face's extent, left out: burr
//!    webs and films over holes are what the laser removes, not the part), with a Huber kernel,
//!    a maximum distance shrinking from the coarse residual to a few noise levels, and a
//!    second-difference smoothness prior that leaves affine motion free. Directions that a patch
//!    cannot fix (a straight strip sliding along itself) are carried by the field from the
//!    holes, slot ends and corners around it; the path stays continuous because the field is.
//! 4. **Path.** Each point moves by `scan_from_cad · F`; feature vectors by `(I + ∂d/∂x)⁻ᵀ`.
//! 5. **Quality.** Per contour: scan coverage, point-to-plane residual, and a predicted
//!    bound on its largest cross-edge error from the field's posterior covariance across it,
//!    its residual and its coverage. A contour whose bound exceeds the tolerance, or whose coverage
//!    or residual fails, is flagged untrustworthy. The opening check then slides each closed
//!    contour's opening over the raw scan around it; an opening the scan shows elsewhere flags
//!    its contour and refuses the part (a slide along the part that every match hides). The
//!    scanned-edge check reads where each strip's edge really is; one off by more than the
//!    tolerance, or more than half the contours flagged, puts the part in doubt
//!    (`quality::judge_part`).
//!
//! The stages live in the submodules `settings`, `coarse`, `field_fit`, `quality` and
//! `openings`; their public items are re-exported here by name.

mod coarse;
mod edge_terms;
mod field_fit;
mod openings;
mod quality;
mod scanned_edge;
mod settings;

use coarse::overlap_fraction;
pub use coarse::{
    CAPTURE_ACCEPT_SCORE, CAPTURE_INLIER_MM, CAPTURE_MARGIN_DEG, CAPTURE_MARGIN_MM,
    CAPTURE_MIN_SCORE, CAPTURE_STEP_DEG, Capture, MAX_COARSE_LOG_SCALE_CHANGE,
    MIN_AXIS_VARIANCE_RATIO, PoseOffset, SLIDE_SHIFTS_MM, capture, coarse_fit, moments,
    principal_axes, refine, refine_across_slides, scan_pyramid, scan_voxels,
};
pub use field_fit::{
    CURVATURE_NEIGHBOURS, EARLY_STRIDE, FIELD_DAMPING, FieldPosterior, LocalShape,
    MATCH_CANDIDATES, MIN_SAME_FACE_COS, POSTERIOR_PRIOR_SCALE, PRIOR_REACH, SCAN_NORMAL_MIN_COS,
    SCAN_NORMAL_NEIGHBOURS, SCAN_NORMAL_RADIUS_MM, TANGENT_GATE_SPACINGS, WARMUP_REACH_FACTOR,
    WARMUP_STRIDE, local_shapes,
};
use field_fit::{final_matches, fit_field, move_contour, scan_normals, turn_normals};
pub use openings::{
    OPENING_BAND_MM, OPENING_CELL_MM, OPENING_CLEAR_MM, OPENING_COVER_SHARE, OPENING_FACE_MIN_COS,
    OPENING_MIN_CELLS, OPENING_MIN_SLIDE_MM, OPENING_MISMATCH_SHARE, OPENING_PROBE_RADIUS_MM,
    OPENING_SEARCH_MM, OpeningCheck, check_openings,
};
pub use quality::{
    BOUND_BIAS_MM, BOUND_COVERAGE_FACTOR, BOUND_DISTANCE_SLOPE, BOUND_MODEL_FACTOR,
    BOUND_RESIDUAL_FACTOR, BOUND_SAMPLE_STEP, BOUND_SIGMA_FACTOR, CLOSED_GAP_SPACINGS,
    ContourQuality, EDGE_GAP_P95_FRACTION, END_SUPPORT_MIN_COS, EdgeReading, Flag, GlobalQuality,
    MATERIAL_BEYOND_MM, MODEL_CHECK_SPACING_RATIO, PART_BOUND_SIGMA_FACTOR, QualityReport,
    REGION_DOUBT_FRACTION, REGION_FAR_OFF_FRACTION, REGION_MIN_FAR_OFF, SUPPORT_MIN_COS,
    SlideRetry, is_open, p95_risk, predicted_bound_mm, strips_sharing_ends,
};
use quality::{
    contour_quality, judge_edge_gaps, judge_edges, judge_p95_risk, judge_part, judge_region,
    material_beyond,
};
pub use scanned_edge::{
    EDGE_GAP_SIGMAS, EDGE_STRETCH_MM, EDGE_WINDOW_MM, EdgeFrom, ScannedEdge, scanned_edges,
};
pub use settings::{
    CoarseInit, CoarseSettings, DeformationSettings, MAX_CAD_SAMPLE_POINTS, Mode, QualitySettings,
    RegisterSettings, Visibility, gate,
};

use crate::deformation::BSplineField;
use crate::error::{RegisterError, Result};
use crate::icp::{IcpResult, IcpTarget};
use crate::kdtree::{self, Scratch};
use crate::sampling::{View, VoxelPyramid, facing_indices, spatial_order, voxel_pick};
use rayon::prelude::*;
use std::time::Instant;
use trim_geom::{Path, Point3, PointCloud, Similarity3, Vector3};

/// The registration's result.
#[derive(Debug, Clone)]
pub struct Registration {
    /// The registered path, scan frame.
    pub path: Path,
    /// The coarse similarity.
    pub scan_from_cad: Similarity3,
    /// The displacement field, CAD frame (none in global mode).
    pub field: Option<BSplineField>,
    /// The coarse ICP's result (`target_from_source` is `cad_from_scan`).
    pub coarse: IcpResult,
    /// The quality report.
    pub report: QualityReport,
}

impl Registration {
    /// A registered position of a CAD-frame point, scan frame.
    #[must_use]
    pub fn scan_from_cad_point(&self, p_cad: &Point3) -> Point3 {
        let moved = self.field.as_ref().map_or(*p_cad, |f| f.apply(p_cad));
        self.scan_from_cad * moved
    }
}

/// Voxel size of the CAD's spatially coherent order, mm.
pub const CAD_ORDER_VOXEL_MM: f64 = 1.0;

/// The coarse capture uses every this-many-th CAD point (the visible CAD is culled again, whole,
/// at the captured pose: culled at the nominal pose, a core 10° off registered with a
/// cross-edge P95 of 24 µm instead of 9 µm).
pub const CAPTURE_CAD_STRIDE: usize = 4;

/// …when that still leaves this many CAD points; a sparser CAD is used whole.
pub const CAPTURE_CAD_MIN_POINTS: usize = 20_000;

/// Where the scanner is, CAD frame, for a `cad_from_scan`.
fn view_in_cad(settings: &RegisterSettings, cad_from_scan: &Similarity3) -> View {
    match settings.scanner_viewpoint_mm {
        Some(v) => View::From(cad_from_scan * Point3::from(v)),
        None => {
            View::Along(cad_from_scan.isometry.rotation * Vector3::from(settings.view_direction))
        }
    }
}

/// The CAD points facing the scanner, in a spatially coherent order, as the ICP target.
fn visible_target(cad: &PointCloud, view: View, facing_min_cos: f64) -> Result<IcpTarget> {
    let facing = facing_indices(cad, view, facing_min_cos)?;
    if facing.is_empty() {
        return Err(RegisterError::EmptyCloud {
            which: "CAD (faces toward the scanner)",
        });
    }
    let visible = cad.select(&facing)?;
    // Spatially coherent order: the curvature pass walks the CAD in it.
    let order = spatial_order(visible.points(), CAD_ORDER_VOXEL_MM);
    IcpTarget::new(visible.select(&order)?)
}

/// The CAD points within `distance_mm` of the scan (its dense voxels at the finest coarse
/// level, which drop isolated outliers, carried into the CAD frame by `cad_from_scan`), in a
/// spatially coherent order, as the ICP target: the faces the scanner really saw, from
/// wherever it looked. A face farther than that from every scan voxel (the far side of a
/// single-sided scan, a wall turned away) is left out.
fn supported_target(
    cad: &PointCloud,
    pyramid: &VoxelPyramid<'_>,
    cad_from_scan: &Similarity3,
    coarse: &CoarseSettings,
    distance_mm: f64,
) -> Result<IcpTarget> {
    let finest = coarse
        .levels
        .iter()
        .map(|l| l.voxel_mm)
        .fold(f64::INFINITY, f64::min);
    let voxels: Vec<Point3> = scan_voxels(pyramid, finest, coarse)?
        .iter()
        .map(|(p, _)| cad_from_scan * p)
        .collect();
    let tree = kdtree::KdTree::build(&voxels);
    let d2 = distance_mm * distance_mm;
    let supported: Vec<usize> = cad
        .points()
        .par_iter()
        .enumerate()
        .map_init(Scratch::default, |scratch, (i, p)| {
            tree.any_within(p, d2, scratch).then_some(i)
        })
        .flatten()
        .collect();
    if supported.is_empty() {
        return Err(RegisterError::EmptyCloud {
            which: "CAD (near the scan)",
        });
    }
    let seen = cad.select(&supported)?;
    let order = spatial_order(seen.points(), CAD_ORDER_VOXEL_MM);
    IcpTarget::new(seen.select(&order)?)
}

fn stage<T>(
    timings: &mut Vec<(String, f64)>,
    name: &str,
    f: impl FnOnce() -> Result<T>,
) -> Result<T> {
    // A cancelled registration stops between stages as well as inside their loops.
    trim_geom::cancel::check()?;
    let t0 = Instant::now();
    let out = f()?;
    timings.push((name.to_string(), t0.elapsed().as_secs_f64()));
    Ok(out)
}

/// A similarity as a row-major 4×4 matrix.
fn matrix_rows(s: &Similarity3) -> [[f64; 4]; 4] {
    let m = s.to_homogeneous();
    [0, 1, 2, 3].map(|i| [0, 1, 2, 3].map(|j| m[(i, j)]))
}

/// What the coarse fit yields: the capture, the CAD the scanner saw (with its kd-tree), the
/// coarse similarity with the shift along the long axis its refinement started from
/// ([`refine_across_slides`]), and the CAD's local shapes (empty unless `Mode::Regional`).
type CoarseStages = (Capture, IcpTarget, (IcpResult, f64), Vec<LocalShape>);

/// The coarse stages, each timed into `timings`: the capture from the fixture's nominal pose,
/// the CAD the scanner saw at the captured pose, then scan → CAD point-to-plane with scale down
/// the scan pyramid (the CAD's local shapes, for the field's matching, worked out beside it).
fn coarse_stages(
    cad: &PointCloud,
    pyramid: &VoxelPyramid<'_>,
    (capture_target, part): (&IcpTarget, &kdtree::KdTree),
    cad_from_scan_initial: &Similarity3,
    settings: &RegisterSettings,
    slide_shifts_mm: &[f64],
    timings: &mut Vec<(String, f64)>,
) -> Result<CoarseStages> {
    let captured = stage(timings, "coarse capture", || {
        capture(
            pyramid,
            capture_target,
            part,
            cad_from_scan_initial,
            &settings.coarse,
        )
    })?;
    // What the scanner saw, at the captured pose: the CAD points with scan data near them
    // (`Visibility::Support`), or those facing an assumed view (`Visibility::View`, the
    // captured pose's: with the nominal pose's, a part 10° off keeps walls the scanner never
    // saw and drops some it did).
    let target = stage(timings, "cad visibility + kd-tree", || {
        match settings.visibility {
            Visibility::Support => supported_target(
                cad,
                pyramid,
                &captured.fit.target_from_source,
                &settings.coarse,
                settings.visible_within_mm,
            ),
            Visibility::View => visible_target(
                cad,
                view_in_cad(settings, &captured.fit.target_from_source),
                settings.facing_min_cos,
            ),
        }
    })?;
    let regional = settings.mode == Mode::Regional;
    let (coarse, shapes) = stage(timings, "coarse similarity + cad curvature", || {
        let cancel = trim_geom::cancel::current();
        let (coarse, shapes) = rayon::join(
            || {
                cancel.run(|| {
                    refine_across_slides(
                        pyramid,
                        &target,
                        &captured,
                        &settings.coarse,
                        slide_shifts_mm,
                    )
                })
            },
            || regional.then(|| local_shapes(target.cloud(), target.tree())),
        );
        Ok((coarse?, shapes.unwrap_or_default()))
    })?;
    Ok((captured, target, coarse, shapes))
}

/// How far (mm, at least) a contour point may lie outside the CAD's bounding box; or this
/// share of the box's diagonal, when more. The path is in the CAD frame and lies on its
/// surface; a contour beyond this is in other units or another frame, and its opening check's
/// raster, sized by the contour, asked for terabytes.
pub const PATH_OUTSIDE_CAD_MM: f64 = 10.0;
/// See [`PATH_OUTSIDE_CAD_MM`].
pub const PATH_OUTSIDE_CAD_DIAGONAL_SHARE: f64 = 0.25;

/// Refuses, before any work, a path that does not lie on the CAD (naming the contour and the
/// point) and a field too fine for the CAD (naming `field.spacing_mm`): both would otherwise
/// size a grid or raster without bound.
/// A scan with points, and not all at one place (one point, or copies of it), which failed as
/// "0 correspondences".
fn check_scan(scan: &PointCloud) -> Result<()> {
    let Some(&first) = scan.points().first() else {
        return Err(RegisterError::EmptyCloud { which: "scan" });
    };
    if scan.points().iter().all(|p| *p == first) {
        return Err(RegisterError::AtOnePlace {
            which: "scan",
            points: scan.len(),
            at: first,
        });
    }
    Ok(())
}

fn check_inputs(cad: &PointCloud, path: &Path, settings: &RegisterSettings) -> Result<()> {
    let bounds = cad
        .bounds()
        .ok_or(RegisterError::EmptyCloud { which: "CAD" })?;
    let margin = PATH_OUTSIDE_CAD_MM.max(PATH_OUTSIDE_CAD_DIAGONAL_SHARE * bounds.diagonal());
    for c in path.contours() {
        if let Some((i, p, d)) = c
            .points()
            .iter()
            .enumerate()
            .map(|(i, p)| (i, p, bounds.distance_outside(p)))
            .find(|(_, _, d)| *d > margin)
        {
            return Err(RegisterError::Contour {
                contour: c.id(),
                message: format!(
                    "point {i} at ({:.3}, {:.3}, {:.3}) mm lies {d:.1} mm outside the CAD's bounding box ({:.1}, {:.1}, {:.1})–({:.1}, {:.1}, {:.1}) mm (at most {margin:.1} mm allowed): the path must be in the CAD's frame and units",
                    p.x,
                    p.y,
                    p.z,
                    bounds.min.x,
                    bounds.min.y,
                    bounds.min.z,
                    bounds.max.x,
                    bounds.max.y,
                    bounds.max.z
                ),
            });
        }
    }
    if settings.mode == Mode::Regional {
        let ratio = if settings.quality.model_check {
            MODEL_CHECK_SPACING_RATIO.min(1.0)
        } else {
            1.0
        };
        field_fit::check_field_size(&bounds, settings.field.spacing_mm, ratio)?;
    }
    Ok(())
}

/// Registers `path` (CAD frame) onto `scan` (scan frame), starting from the fixture's
/// `initial_scan_from_cad`. `cad` must carry outward normals.
///
/// A part refused as a whole (`GlobalQuality::refused`) is registered once more with the coarse
/// refinement also started [`SLIDE_SHIFTS_MM`] along the part's long axis
/// (`coarse.slide_retry`): the retry is taken when its best start is not the captured pose and
/// it is not refused itself; either way `GlobalQuality::slide_retry` says what happened, and the
/// stage timings are the kept registration's with the other's wall time as a line of its own.
pub fn register(
    cad: &PointCloud,
    scan: &PointCloud,
    path: &Path,
    initial_scan_from_cad: &Similarity3,
    settings: &RegisterSettings,
) -> Result<Registration> {
    check_inputs(cad, path, settings)?;
    check_scan(scan)?;
    let t0 = Instant::now();
    let (mut first, _) = register_once(cad, scan, path, initial_scan_from_cad, settings, &[])?;
    let first_s = t0.elapsed().as_secs_f64();
    let Some(first_refusal) = first.report.global.refused.clone() else {
        return Ok(first);
    };
    if !settings.coarse.slide_retry {
        return Ok(first);
    }
    let t0 = Instant::now();
    let retry = register_once(
        cad,
        scan,
        path,
        initial_scan_from_cad,
        settings,
        &SLIDE_SHIFTS_MM,
    );
    let retry_s = t0.elapsed().as_secs_f64();
    let (shift_mm, retry) = match retry {
        Ok((retry, shift)) => (shift, Some(retry)),
        // A cancelled retry is a cancelled registration.
        Err(RegisterError::Geom(trim_geom::GeomError::Cancelled)) => {
            return Err(RegisterError::Geom(trim_geom::GeomError::Cancelled));
        }
        // A retry that fails outright leaves the first registration as it was.
        Err(_) => (0.0, None),
    };
    let summary = |taken| SlideRetry {
        first_refusal: first_refusal.clone(),
        first_coarse_rmse_mm: first.report.global.coarse_rmse_mm,
        shift_mm,
        taken,
    };
    // The stages listed are the kept registration's; the other's wall time is a line of its own.
    Ok(match retry {
        Some(mut retry) if shift_mm != 0.0 && retry.report.global.refused.is_none() => {
            retry.report.global.slide_retry = Some(summary(true));
            retry
                .report
                .timings_s
                .push(("first registration (refused, retried)".into(), first_s));
            retry
        }
        _ => {
            first.report.global.slide_retry = Some(summary(false));
            first
                .report
                .timings_s
                .push(("slide retry (after a refusal)".into(), retry_s));
            first
        }
    })
}

/// One registration, the coarse refinement also started at `slide_shifts_mm`
/// ([`refine_across_slides`]); with the shift its kept start came from.
fn register_once(
    cad: &PointCloud,
    scan: &PointCloud,
    path: &Path,
    initial_scan_from_cad: &Similarity3,
    settings: &RegisterSettings,
    slide_shifts_mm: &[f64],
) -> Result<(Registration, f64)> {
    settings.validate()?;
    if cad.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "CAD" });
    }
    if !initial_scan_from_cad
        .to_homogeneous()
        .iter()
        .all(|v| v.is_finite())
    {
        return Err(RegisterError::NonFinite {
            what: "initial scan_from_cad".into(),
        });
    }
    let mut timings = Vec::new();
    let cad_from_scan_initial = initial_scan_from_cad.inverse();
    let view_nominal = view_in_cad(settings, &cad_from_scan_initial);
    let capture_stride = if cad.len() >= CAPTURE_CAD_STRIDE * CAPTURE_CAD_MIN_POINTS {
        CAPTURE_CAD_STRIDE
    } else {
        1
    };
    // Side by side (each sort leaves a sequential pass the other core can fill): the capture's
    // CAD (on 2 mm scan voxels every CAPTURE_CAD_STRIDE-th CAD point is plenty), the scan's
    // voxel sums for the coarse pyramid, and the field's points (one real scan point per voxel).
    let ((capture_target, part), pyramid, picked) =
        stage(&mut timings, "scan voxels + capture cad", || {
            let ((capture_target, pyramid), picked) = rayon::join(
                || {
                    rayon::join(
                        || {
                            let every: Vec<usize> =
                                (0..cad.len()).step_by(capture_stride).collect();
                            let sparse = cad.select(&every)?;
                            // Every face, for the capture's score.
                            let part = kdtree::KdTree::build(sparse.points());
                            let target =
                                visible_target(&sparse, view_nominal, settings.facing_min_cos)?;
                            Ok::<_, RegisterError>((target, part))
                        },
                        || scan_pyramid(scan, &settings.coarse),
                    )
                },
                || voxel_pick(scan.points(), settings.field.voxel_mm),
            );
            Ok((capture_target?, pyramid?, picked?))
        })?;

    let regional = settings.mode == Mode::Regional;
    // The field's scan normals (scan frame) and the scan's kd-tree need only the scan: they are
    // worked out beside the coarse stages below, which leave a core idle at times, and turned
    // into the CAD frame once the coarse fit is known.
    let cancel = trim_geom::cancel::current();
    let (coarse_stages, normals) = rayon::join(
        || {
            cancel.run(|| {
                coarse_stages(
                    cad,
                    &pyramid,
                    (&capture_target, &part),
                    &cad_from_scan_initial,
                    settings,
                    slide_shifts_mm,
                    &mut timings,
                )
            })
        },
        || {
            regional.then(|| {
                cancel.run(|| {
                    let t0 = Instant::now();
                    let normals = scan_normals(scan.points(), &picked);
                    (normals, t0.elapsed().as_secs_f64())
                })
            })
        },
    );
    let (captured, target, (coarse, slide_shift_mm), shapes) = coarse_stages?;
    let cad_from_scan = coarse.target_from_source;
    let scan_from_cad = cad_from_scan.inverse();

    // Field points in the CAD frame.
    let field_points: Vec<Point3> = picked
        .par_iter()
        .map(|&i| cad_from_scan * scan.points()[i])
        .collect();
    let overlap = overlap_fraction(
        &field_points,
        target.tree(),
        settings.quality.overlap_distance_mm,
    );
    if overlap < settings.quality.min_overlap {
        return Err(RegisterError::NotOverlapping {
            fraction_pct: 100.0 * overlap,
            distance_mm: settings.quality.overlap_distance_mm,
            needed_pct: 100.0 * settings.quality.min_overlap,
        });
    }

    let mut check_field = None;
    let mut scan_tree = None;
    // The openings' kd-tree of the whole CAD, built beside the model check when there is one.
    let mut cad_tree = None;
    // The scan normals were worked out in regional mode only.
    let (mut field, matches, mut posterior) = match normals {
        None => (
            None,
            final_matches(
                &field_points,
                &target,
                &[],
                None,
                settings.quality.overlap_distance_mm,
            ),
            None,
        ),
        Some(((normals, tree), beside_s)) => {
            // The check field (`quality.model_check`), fitted to the fit's final matches.
            let check_settings = DeformationSettings {
                spacing_mm: settings.field.spacing_mm * MODEL_CHECK_SPACING_RATIO,
                ..settings.field
            };
            let name = if settings.quality.model_check {
                "deformation field + check"
            } else {
                "deformation field"
            };
            timings.push(("scan normals (beside the coarse stages)".into(), beside_s));
            let normals = stage(&mut timings, "scan normals into the cad frame", || {
                Ok(turn_normals(&normals, &cad_from_scan.isometry.rotation))
            })?;
            scan_tree = Some(tree);
            let (fit, tree) = stage(&mut timings, name, || {
                fit_field(
                    &field_points,
                    &normals,
                    &target,
                    &shapes,
                    &settings.field,
                    settings.quality.model_check.then_some(&check_settings),
                    || kdtree::KdTree::build(cad.points()),
                )
            })?;
            cad_tree = Some(tree);
            check_field = fit.check;
            (Some(fit.field), fit.matches, fit.posterior)
        }
    };

    let apply = |field: Option<&BSplineField>| -> Result<Path> {
        let contours = path
            .contours()
            .par_iter()
            .map(|c| move_contour(c, field, &scan_from_cad))
            .collect::<Result<Vec<_>>>()?;
        Ok(Path::new(contours)?)
    };
    let mut registered = stage(&mut timings, "apply to path", || apply(field.as_ref()))?;
    let scan_tree = scan_tree.unwrap_or_else(|| kdtree::KdTree::build(scan.points()));

    // The scanned edges as observations of the field (`regional::edge_terms`).
    let fitted_field = field.clone();
    // The model check's field as fitted to the faces, before the edge terms condition it too.
    let faces_check = check_field.as_ref().map(|c| c.field.clone());
    let mut edge_terms = None;
    // The strips' gaps the scan showed before the edge terms moved the field, where they still
    // count (`EdgeTermSummary::gaps_before`, `scanned_edge::contour_gap_um`).
    let mut gaps_before: Vec<Option<f64>> = vec![None; path.contours().len()];
    if settings.quality.edge_terms
        && let (Some(f), Some(post)) = (field.as_mut(), posterior.as_mut())
    {
        let summary = stage(&mut timings, "edge terms", || {
            // The strips only (`scanned_edge::strip_edges`).
            let readings: Vec<Vec<ScannedEdge>> = registered
                .contours()
                .par_iter()
                .map(|c| scanned_edge::strip_edges(c, scan.points(), &scan_tree))
                .collect();
            let (summary, taken) =
                edge_terms::condition_on_edges(f, post, path, &readings, &scan_from_cad);
            gaps_before = summary.gaps_before(&readings);
            // The model check takes the readings the fit took, so that the two fields are
            // compared given the same data: faces and scanned edges.
            if let (Some(check), Some(measured_on)) = (check_field.as_mut(), fitted_field.as_ref())
                && let Some(check_post) = check.posterior.as_ref()
            {
                edge_terms::condition_check_on_edges(
                    &mut check.field,
                    check_post,
                    path,
                    &taken,
                    &scan_from_cad,
                    measured_on,
                );
            }
            Ok(summary)
        })?;
        registered = stage(&mut timings, "apply to path", || apply(Some(f)))?;
        edge_terms = Some(summary);
    }

    let mut contours = stage(&mut timings, "quality", || {
        Ok(contour_quality(
            path,
            field.as_ref(),
            check_field.as_ref().map(|c| &c.field).zip(field.as_ref()),
            faces_check.as_ref().zip(fitted_field.as_ref()),
            posterior.as_ref(),
            &matches,
            &scan_from_cad,
            &settings.quality,
        ))
    })?;
    let field_rmse_mm = field.as_ref().map(|_| {
        let n = matches.len().max(1) as f64;
        (matches.iter().map(|m| m.r * m.r).sum::<f64>() / n).sqrt()
    });
    stage(&mut timings, "openings", || {
        let cad_tree = cad_tree.unwrap_or_else(|| kdtree::KdTree::build(cad.points()));
        let checks = check_openings(
            path,
            field.as_ref(),
            &scan_from_cad,
            (&cad_tree, cad.points(), cad.normals()),
            &scan_tree,
        );
        for (c, check) in contours.iter_mut().zip(checks) {
            c.opening_slide_mm = check.map(|o| o.slide_mm.norm() * scan_from_cad.scaling());
            c.opening_gain = check.map(|o| o.gain);
            c.opening_cover_gain = check.map(|o| o.cover_gain);
            if check.is_some_and(|o| o.misplaced()) {
                c.flags.push(Flag::OpeningMisplaced);
                c.trustworthy = false;
            }
        }
        Ok(())
    })?;
    let strips: Vec<&[Point3]> = path.contours().iter().map(|c| c.points()).collect();
    let joins = strips_sharing_ends(&strips);
    // Each contour's widest gap after the update alone (`judge_edge_gaps`).
    let gaps_after_um = stage(&mut timings, "scanned edges", || {
        let readings: Vec<Vec<ScannedEdge>> = registered
            .contours()
            .par_iter()
            .map(|c| scanned_edge::scanned_edges(c, scan.points(), &scan_tree))
            .collect();
        for ((c, edges), before) in contours.iter_mut().zip(&readings).zip(&gaps_before) {
            let gap = scanned_edge::contour_gap_um(edges, *before);
            c.scan_edges = edges.iter().map(quality::EdgeReading::from).collect();
            c.scan_edge_gap_um = gap;
            c.scan_slide_gap_um = scanned_edge::contour_slide_gap_um(edges, *before);
            if gap.is_some_and(|g| g > settings.quality.tolerance_um) {
                c.flags.push(Flag::EdgeOffScan);
                c.trustworthy = false;
            }
        }
        for (c, beyond) in contours
            .iter_mut()
            .zip(material_beyond(&strips, &joins, &readings))
        {
            if beyond {
                c.flags.push(Flag::MaterialBeyond);
                c.trustworthy = false;
            }
        }
        Ok(readings
            .iter()
            .map(|edges| scanned_edge::contour_gap_um(edges, None))
            .collect::<Vec<_>>())
    })?;
    let verdict = judge_part(&mut contours, &joins, &settings.quality);
    let whole = verdict.refused.is_none() && verdict.in_doubt.is_none();
    let edges_in_doubt = whole
        .then(|| judge_edges(&mut contours, &joins, &settings.quality))
        .flatten();
    let region_in_doubt = whole
        .then(|| judge_region(&mut contours, &strips, &joins, &settings.quality))
        .flatten();
    judge_edge_gaps(
        &mut contours,
        &strips,
        &joins,
        &gaps_after_um,
        &settings.quality,
    );
    let expected_over_p95 = judge_p95_risk(&mut contours, &settings.quality);
    let untrustworthy = contours.iter().filter(|c| !c.trustworthy).count();
    let report = QualityReport {
        global: GlobalQuality {
            scan_from_cad: matrix_rows(&scan_from_cad),
            scale: scan_from_cad.scaling(),
            initial_scan_from_cad: matrix_rows(initial_scan_from_cad),
            fixture_offset: captured.offset,
            coarse_starts: captured.starts,
            capture_score: captured.score,
            coarse_rmse_mm: coarse.rmse_mm,
            overlap,
            field_rmse_mm,
            field_points: field_points.len(),
            untrustworthy,
            refused: verdict.refused,
            in_doubt: verdict.in_doubt,
            edges_in_doubt,
            region_in_doubt,
            edge_terms,
            slide_retry: None,
            p95_limit_um: settings.quality.p95_limit_um(),
            expected_over_p95,
        },
        contours,
        timings_s: timings,
    };
    Ok((
        Registration {
            path: registered,
            scan_from_cad,
            field,
            coarse,
            report,
        },
        slide_shift_mm,
    ))
}

#[cfg(test)]
mod input_tests {
    use super::*;
    use trim_geom::{Contour, Vector3};

    /// A 60 × 40 × 10 mm box's corners and edges, as a CAD cloud.
    fn box_cloud() -> PointCloud {
        let mut points = Vec::new();
        for i in 0..=60 {
            for j in 0..=40 {
                points.push(Point3::new(f64::from(i), f64::from(j), 0.0));
                points.push(Point3::new(f64::from(i), f64::from(j), 10.0));
            }
        }
        PointCloud::new(points).unwrap()
    }

    fn path_at(x: f64) -> Path {
        let points = vec![Point3::new(x, 0.0, 10.0), Point3::new(x + 5.0, 0.0, 10.0)];
        Path::new(vec![
            Contour::new(
                1,
                vec![Point3::new(1.0, 1.0, 10.0), Point3::new(5.0, 1.0, 10.0)],
                Vector3::z(),
            )
            .unwrap(),
            Contour::new(7, points, Vector3::z()).unwrap(),
        ])
        .unwrap()
    }

    /// A path in other units (or frame) than the CAD, and a field too fine for the CAD, are
    /// refused before any work, naming the contour and the point, or the key. Both sized a
    /// grid without bound: a path in micrometres asked for petabytes.
    #[test]
    fn a_path_off_the_cad_and_a_field_too_fine_are_refused_before_any_work() {
        let cad = box_cloud();
        let settings = RegisterSettings::default();
        check_inputs(&cad, &path_at(30.0), &settings).unwrap();
        // 10 mm beyond the box's end is still within the margin (a quarter of its diagonal).
        check_inputs(&cad, &path_at(60.0), &settings).unwrap();
        let e = register(
            &cad,
            &cad,
            &path_at(10_000.0),
            &Similarity3::identity(),
            &settings,
        )
        .expect_err("a path 10 m off the CAD must be refused")
        .to_string();
        assert!(
            e.contains("contour 7") && e.contains("point 0") && e.contains("frame and units"),
            "{e}"
        );
        let fine = RegisterSettings {
            field: DeformationSettings {
                spacing_mm: 0.5,
                ..settings.field
            },
            ..settings.clone()
        };
        let e = check_inputs(&cad, &path_at(30.0), &fine)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("field.spacing_mm") && e.contains("use at least"),
            "{e}"
        );
        // The suggested spacing passes.
        let at_least: f64 = e
            .split("use at least ")
            .nth(1)
            .and_then(|t| t.split(' ').next())
            .and_then(|t| t.parse().ok())
            .expect("a suggested spacing");
        let ok = RegisterSettings {
            field: DeformationSettings {
                spacing_mm: at_least,
                ..settings.field
            },
            ..settings
        };
        check_inputs(&cad, &path_at(30.0), &ok).unwrap();
    }
}
