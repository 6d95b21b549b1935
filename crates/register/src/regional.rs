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
//!    part ([`crate::field`]), fitted by Gauss-Newton to scan → CAD point-to-plane residuals
//!    `r = n'·(F(c) − q)` (CAD normals carried by `F`), with a Huber kernel, a maximum
//!    distance shrinking from the coarse residual to a few noise levels, and a second-difference
//!    smoothness prior that leaves affine motion free. Directions that a patch cannot fix (a
//!    straight strip sliding along itself) are carried by the field from the holes, slot ends
//!    and corners around it; the path stays continuous because the field is.
//! 4. **Path.** Each point moves by `scan_from_cad · F`; feature vectors by `(I + ∂d/∂x)⁻ᵀ`.
//! 5. **Quality.** Per contour: scan coverage, point-to-plane residual, the translational
//!    degeneracy of the scan near it (eigenvalues of `Σ n nᵀ`), and whether the surroundings
//!    support its weakest direction. A contour that fails a test is flagged untrustworthy.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen};
use rayon::prelude::*;
use trim_geom::crop::crop_near_polyline;
use trim_geom::{Contour, ContourId, KdTree, Path, Point3, PointCloud, Similarity3, Vector3};

use crate::banded::solve_banded_spd;
use crate::error::{RegisterError, Result};
use crate::field::{BSplineField, SUPPORT};
use crate::icp::{IcpMethod, IcpResult, IcpSettings, IcpTarget, PyramidLevel, icp};
use crate::kdtree::{self, Scratch};
use crate::kernel::RobustKernel;
use crate::sampling::{View, dense_voxel_centroids, facing_indices, spatial_order, voxel_pick};

/// Levenberg-Marquardt damping of the field's Gauss-Newton step, relative to the mean data
/// weight per unknown.
pub const FIELD_DAMPING: f64 = 1e-3;

/// The coarse stage refuses a scale change beyond `exp(±0.1)` (±10 %) from the fixture's: no
/// part is that far off, and a scan → CAD fit that gets there is shrinking onto the surface.
pub const MAX_COARSE_LOG_SCALE_CHANGE: f64 = 0.1;

/// The centroid start may move the scan at most this far from the nominal pose, mm (three times
/// the 5 mm fixture error trimctl is specified for): a larger shift means the scan is not of
/// this part at this fixture, refused as not overlapping.
pub const MAX_INIT_TRANSLATION_MM: f64 = 15.0;

/// Principal axes count as defined when consecutive variances differ by this factor.
pub const MIN_AXIS_VARIANCE_RATIO: f64 = 1.3;

/// What the registration does.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Coarse similarity, then the deformation field (the default).
    #[default]
    Regional,
    /// Coarse similarity only (a rigid-plus-scale part).
    Global,
}

/// Where the coarse stage starts.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum CoarseInit {
    /// The fixture's nominal pose as given.
    Nominal,
    /// The nominal rotation; the translation that matches the centroids of the scan and of the
    /// visible CAD.
    Centroid,
    /// Centroids, and the principal axes of the scan and the visible CAD (the sign choice
    /// nearest the nominal rotation; the nominal rotation when the axes are ambiguous or more
    /// than `max_init_rotation_deg` from it).
    #[default]
    PrincipalAxes,
}

/// The coarse stage.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CoarseSettings {
    /// Where to start.
    pub init: CoarseInit,
    /// The principal-axes start is refused beyond this rotation from the nominal pose, degrees.
    pub max_init_rotation_deg: f64,
    /// A voxel must hold this many scan points to count (drops isolated outliers).
    pub min_voxel_points: usize,
    /// Pyramid levels, coarse to fine (scan voxel size, maximum distance, iterations).
    pub levels: Vec<PyramidLevel>,
    /// Estimate a uniform scale at the finest level (the coarser levels are rigid: a scan → CAD fit
    /// with a free scale at coarse resolution can shrink the scan onto the surface).
    pub with_scale: bool,
    /// Huber threshold as a fraction of each level's maximum distance.
    pub huber_fraction: f64,
}

impl Default for CoarseSettings {
    fn default() -> Self {
        let level = |voxel_mm, max_correspondence_distance_mm, max_iterations| PyramidLevel {
            voxel_mm,
            max_correspondence_distance_mm,
            max_iterations,
        };
        CoarseSettings {
            init: CoarseInit::PrincipalAxes,
            max_init_rotation_deg: 15.0,
            min_voxel_points: 3,
            levels: vec![
                level(2.0, 12.0, 30),
                level(1.0, 4.0, 30),
                level(0.5, 1.5, 30),
            ],
            with_scale: true,
            huber_fraction: 0.25,
        }
    }
}

/// The deformation-field stage.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields, default)]
pub struct DeformationSettings {
    /// Control-point spacing, mm.
    pub spacing_mm: f64,
    /// Scan thinning voxel for the fit (one real point kept per voxel), mm.
    pub voxel_mm: f64,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Maximum correspondence distance at the first iteration, mm.
    pub max_distance_start_mm: f64,
    /// …shrinking geometrically to this by iteration `iterations − 3`, mm.
    pub max_distance_end_mm: f64,
    /// Huber threshold, mm.
    pub huber_mm: f64,
    /// Weight of the second-difference prior relative to the mean data weight per unknown.
    pub smoothness: f64,
}

impl Default for DeformationSettings {
    fn default() -> Self {
        DeformationSettings {
            spacing_mm: 20.0,
            voxel_mm: 0.4,
            iterations: 10,
            max_distance_start_mm: 1.5,
            max_distance_end_mm: 0.1,
            huber_mm: 0.02,
            smoothness: 0.1,
        }
    }
}

/// The per-contour quality tests.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields, default)]
pub struct QualitySettings {
    /// A contour point is covered when a matched scan point lies within this, mm.
    pub coverage_radius_mm: f64,
    /// Scan points within this of a contour make its local patch, mm.
    pub patch_radius_mm: f64,
    /// Flag a contour covered on less than this fraction of its points.
    pub min_coverage: f64,
    /// Flag a contour whose patch residual (RMS, mm) exceeds this.
    pub max_residual_mm: f64,
    /// A patch is degenerate when `λmin/λmax` of its `Σ n nᵀ` is below this.
    pub min_degeneracy_ratio: f64,
    /// The surroundings (within this, mm) must constrain a degenerate patch's weakest direction.
    pub support_radius_mm: f64,
    /// Refuse the whole registration when fewer than this fraction of scan points lie within
    /// `overlap_distance_mm` of the CAD after the coarse stage.
    pub min_overlap: f64,
    /// Distance for the overlap test, mm.
    pub overlap_distance_mm: f64,
}

impl Default for QualitySettings {
    fn default() -> Self {
        QualitySettings {
            coverage_radius_mm: 0.75,
            patch_radius_mm: 1.5,
            min_coverage: 0.6,
            max_residual_mm: 0.05,
            min_degeneracy_ratio: 0.02,
            support_radius_mm: 15.0,
            min_overlap: 0.3,
            overlap_distance_mm: 1.0,
        }
    }
}

/// Registration settings: the `[register]` table of job.toml.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RegisterSettings {
    /// Regional (field) or global (similarity only).
    pub mode: Mode,
    /// The scanner's position in the scan frame, mm. When absent the scanner is taken to look along
    /// `−view_direction` from infinitely far.
    pub scanner_viewpoint_mm: Option<[f64; 3]>,
    /// Direction toward the scanner in the scan frame (used without a viewpoint).
    pub view_direction: [f64; 3],
    /// CAD points whose normal makes `cos < facing_min_cos` with the direction to the scanner are
    /// culled (−0.2 keeps walls up to 102° off the view).
    pub facing_min_cos: f64,
    /// Points sampled from a CAD mesh.
    pub cad_sample_points: usize,
    /// The coarse stage: a global similarity from the fixture pose.
    pub coarse: CoarseSettings,
    /// The field stage: a smooth deformation field over the part.
    pub field: DeformationSettings,
    /// The quality tests that flag a contour untrustworthy.
    pub quality: QualitySettings,
}

impl Default for RegisterSettings {
    fn default() -> Self {
        RegisterSettings {
            mode: Mode::Regional,
            scanner_viewpoint_mm: None,
            view_direction: [0.0, 0.0, 1.0],
            facing_min_cos: -0.2,
            cad_sample_points: 300_000,
            coarse: CoarseSettings::default(),
            field: DeformationSettings::default(),
            quality: QualitySettings::default(),
        }
    }
}

fn positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(RegisterError::setting(
            name,
            format!("must be finite and > 0, got {v}"),
        ))
    }
}

fn fraction(name: &str, v: f64) -> Result<()> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(RegisterError::setting(
            name,
            format!("must be in [0, 1], got {v}"),
        ))
    }
}

impl RegisterSettings {
    /// Refuses out-of-range values, naming the key as in job.toml (`register.field.spacing_mm`).
    pub fn validate(&self) -> Result<()> {
        if let Some(v) = self.scanner_viewpoint_mm {
            if !v.iter().all(|c| c.is_finite()) {
                return Err(RegisterError::setting(
                    "scanner_viewpoint_mm",
                    "must be finite",
                ));
            }
        }
        let d = Vector3::from(self.view_direction);
        if !(d.iter().all(|c| c.is_finite()) && d.norm() > 0.0) {
            return Err(RegisterError::setting(
                "view_direction",
                "must be a finite non-zero vector",
            ));
        }
        if !(-1.0..=1.0).contains(&self.facing_min_cos) {
            return Err(RegisterError::setting(
                "facing_min_cos",
                "must be in [−1, 1]",
            ));
        }
        if self.cad_sample_points < 1000 {
            return Err(RegisterError::setting(
                "cad_sample_points",
                "must be at least 1000",
            ));
        }
        if self.coarse.levels.is_empty() {
            return Err(RegisterError::setting(
                "coarse.levels",
                "needs at least one level",
            ));
        }
        for (k, l) in self.coarse.levels.iter().enumerate() {
            positive(&format!("coarse.levels[{k}].voxel_mm"), l.voxel_mm)?;
            positive(
                &format!("coarse.levels[{k}].max_correspondence_distance_mm"),
                l.max_correspondence_distance_mm,
            )?;
            if l.max_iterations == 0 {
                return Err(RegisterError::setting(
                    format!("coarse.levels[{k}].max_iterations"),
                    "must be at least 1",
                ));
            }
        }
        positive("coarse.huber_fraction", self.coarse.huber_fraction)?;
        positive(
            "coarse.max_init_rotation_deg",
            self.coarse.max_init_rotation_deg,
        )?;
        let f = &self.field;
        positive("field.spacing_mm", f.spacing_mm)?;
        positive("field.voxel_mm", f.voxel_mm)?;
        positive("field.max_distance_start_mm", f.max_distance_start_mm)?;
        positive("field.max_distance_end_mm", f.max_distance_end_mm)?;
        positive("field.huber_mm", f.huber_mm)?;
        if !(f.smoothness.is_finite() && f.smoothness >= 0.0) {
            return Err(RegisterError::setting(
                "field.smoothness",
                "must be finite and ≥ 0",
            ));
        }
        if f.iterations == 0 {
            return Err(RegisterError::setting(
                "field.iterations",
                "must be at least 1",
            ));
        }
        let q = &self.quality;
        positive("quality.coverage_radius_mm", q.coverage_radius_mm)?;
        positive("quality.patch_radius_mm", q.patch_radius_mm)?;
        positive("quality.max_residual_mm", q.max_residual_mm)?;
        positive("quality.support_radius_mm", q.support_radius_mm)?;
        positive("quality.overlap_distance_mm", q.overlap_distance_mm)?;
        fraction("quality.min_coverage", q.min_coverage)?;
        fraction("quality.min_degeneracy_ratio", q.min_degeneracy_ratio)?;
        fraction("quality.min_overlap", q.min_overlap)?;
        Ok(())
    }
}

/// Why a contour is flagged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Flag {
    /// No scan point near the contour at all.
    NoScanPoints,
    /// Less than `min_coverage` of the contour has scan points near it.
    LowCoverage,
    /// The scan near the contour does not fit the registered CAD.
    HighResidual,
    /// The patch alone cannot fix some direction (informational when supported).
    Degenerate,
    /// Degenerate, and the surroundings do not fix that direction either.
    Unsupported,
}

/// The quality of one registered contour (report JSON).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ContourQuality {
    /// The contour id.
    pub id: ContourId,
    /// Contour points.
    pub points: usize,
    /// Matched scan points within `patch_radius_mm`.
    pub scan_points: usize,
    /// Fraction of contour points with a matched scan point within `coverage_radius_mm`.
    pub coverage: f64,
    /// RMS point-to-plane residual of the patch, mm; `None` (JSON `null`) when the patch holds
    /// no scan point (then `flags` holds `NoScanPoints`).
    pub residual_rms_mm: Option<f64>,
    /// `λmin/λmax` of the patch's translational normal matrix `Σ n nᵀ` (1: all directions
    /// fixed, 0: sliding freely).
    pub degeneracy_ratio: f64,
    /// The patch's least-constrained direction, scan frame.
    pub weakest_direction: [f64; 3],
    /// The same ratio along that direction over `support_radius_mm`.
    pub support_ratio: f64,
    /// Largest field displacement along the contour, mm (how far it moved beyond the coarse
    /// similarity).
    pub max_field_displacement_mm: f64,
    /// What was found wrong.
    pub flags: Vec<Flag>,
    /// Whether the planner may use the contour.
    pub trustworthy: bool,
}

/// The whole-part figures (report JSON).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GlobalQuality {
    /// The coarse similarity `scan_from_cad` as a row-major 4×4 matrix.
    pub scan_from_cad: [[f64; 4]; 4],
    /// Its scale.
    pub scale: f64,
    /// Coarse RMS point-to-plane residual, mm.
    pub coarse_rmse_mm: f64,
    /// Fraction of scan points within `overlap_distance_mm` of the CAD after the coarse stage.
    pub overlap: f64,
    /// RMS point-to-plane residual after the field, mm (none in global mode).
    pub field_rmse_mm: Option<f64>,
    /// Scan points used by the field fit.
    pub field_points: usize,
    /// Contours flagged untrustworthy.
    pub untrustworthy: usize,
}

/// The quality report: global figures and one entry per contour, in path order.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct QualityReport {
    /// Whole-part figures.
    pub global: GlobalQuality,
    /// Per-contour figures.
    pub contours: Vec<ContourQuality>,
    /// Stage wall-clock times, seconds.
    pub timings_s: Vec<(String, f64)>,
}

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

/// CAD candidates per scan point; the one whose surface passes closest wins.
pub const MATCH_CANDIDATES: usize = 6;

/// Neighbours used to estimate each CAD point's shape operator.
pub const CURVATURE_NEIGHBOURS: usize = 6;

/// The shape operator `S` of each CAD point (`n(c + t) ≈ n(c) + S t` for a tangential `t`),
/// least squares over its [`CURVATURE_NEIGHBOURS`] nearest neighbours' normals. The residual
/// `n·(q − c) + ½ tᵀ S t` is then the distance to the osculating quadric instead of the tangent
/// plane: without it a scan point on a 1.2 mm hole wall, 0.12 mm from its nearest CAD sample,
/// reads `t²/2R ≈ 6 µm` off, always toward the hole, and half-visible holes shift by that.
#[must_use]
pub fn shape_operators(cad: &PointCloud, tree: &kdtree::KdTree) -> Vec<Matrix3<f64>> {
    let pts = cad.points();
    let Some(normals) = cad.normals() else {
        return vec![Matrix3::zeros(); pts.len()];
    };
    pts.par_iter()
        .zip(normals.par_iter())
        .map_init(Scratch::default, |scratch, (c, n)| {
            // Tangent basis.
            let helper = if n.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let e1 = n.cross(&helper).normalize();
            let e2 = n.cross(&e1);
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = Vector3::zeros();
            for nb in tree.knn_within(c, CURVATURE_NEIGHBOURS + 1, f64::INFINITY, scratch) {
                let d = pts[nb.index] - c;
                let dn = normals[nb.index] - n;
                // Only neighbours on the same smooth face (normals within ~25°).
                if d.norm_squared() == 0.0 || normals[nb.index].dot(n) < MIN_SAME_FACE_COS {
                    continue;
                }
                let (t1, t2) = (d.dot(&e1), d.dot(&e2));
                let (g1, g2) = (dn.dot(&e1), dn.dot(&e2));
                // S = [[a, b], [b, c]]: g1 = a t1 + b t2, g2 = b t1 + c t2.
                for (row, rhs) in [
                    (Vector3::new(t1, t2, 0.0), g1),
                    (Vector3::new(0.0, t1, t2), g2),
                ] {
                    ata += row * row.transpose();
                    atb += row * rhs;
                }
            }
            let Some(abc) = (ata + Matrix3::identity() * 1e-12)
                .try_inverse()
                .map(|inv| inv * atb)
            else {
                return Matrix3::zeros();
            };
            let (a, b, cc) = (abc[0], abc[1], abc[2]);
            a * e1 * e1.transpose()
                + b * (e1 * e2.transpose() + e2 * e1.transpose())
                + cc * e2 * e2.transpose()
        })
        .collect()
}

/// Neighbours whose normals differ by more than this (cosine) lie across an edge.
pub const MIN_SAME_FACE_COS: f64 = 0.9;

/// One scan point matched to the CAD in the field's last iteration (CAD frame).
#[derive(Debug, Clone, Copy)]
struct Match {
    /// The scan point, CAD frame.
    q: Point3,
    /// Deformed CAD normal.
    n: Vector3,
    /// Point-to-plane residual, mm.
    r: f64,
}

fn stage<T>(
    timings: &mut Vec<(String, f64)>,
    name: &str,
    f: impl FnOnce() -> Result<T>,
) -> Result<T> {
    let t0 = Instant::now();
    let out = f()?;
    timings.push((name.to_string(), t0.elapsed().as_secs_f64()));
    Ok(out)
}

/// Registers `path` (CAD frame) onto `scan` (scan frame), starting from the fixture's
/// `initial_scan_from_cad`. `cad` must carry outward normals.
pub fn register(
    cad: &PointCloud,
    scan: &PointCloud,
    path: &Path,
    initial_scan_from_cad: &Similarity3,
    settings: &RegisterSettings,
) -> Result<Registration> {
    settings.validate()?;
    if cad.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "CAD" });
    }
    if scan.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "scan" });
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
    let view_in_cad = match settings.scanner_viewpoint_mm {
        Some(v) => View::From(cad_from_scan_initial * Point3::from(v)),
        None => View::Along(
            cad_from_scan_initial.isometry.rotation * Vector3::from(settings.view_direction),
        ),
    };
    let target = stage(&mut timings, "cad visibility + kd-tree", || {
        let facing = facing_indices(cad, view_in_cad, settings.facing_min_cos)?;
        if facing.is_empty() {
            return Err(RegisterError::EmptyCloud {
                which: "CAD (faces toward the scanner)",
            });
        }
        let visible = cad.select(&facing)?;
        // Spatially coherent order: the curvature pass walks the CAD in it.
        let order = spatial_order(visible.points(), CAD_ORDER_VOXEL_MM);
        IcpTarget::new(visible.select(&order)?)
    })?;

    // Coarse: scan → CAD, point-to-plane with scale, over a scan pyramid.
    let coarse = stage(&mut timings, "coarse similarity", || {
        coarse_fit(scan, &target, &cad_from_scan_initial, &settings.coarse)
    })?;
    let cad_from_scan = coarse.target_from_source;
    let scan_from_cad = cad_from_scan.inverse();

    // Field points: one real scan point per voxel, in the CAD frame.
    let field_points: Vec<Point3> = stage(&mut timings, "scan thinning", || {
        let picked = voxel_pick(scan.points(), settings.field.voxel_mm)?;
        Ok(picked
            .par_iter()
            .map(|&i| cad_from_scan * scan.points()[i])
            .collect())
    })?;
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

    let (field, matches) = match settings.mode {
        Mode::Global => (
            None,
            final_matches(
                &field_points,
                &target,
                &[],
                None,
                settings.quality.overlap_distance_mm,
            ),
        ),
        Mode::Regional => {
            let curvature = stage(&mut timings, "cad curvature", || {
                Ok(shape_operators(target.cloud(), target.tree()))
            })?;
            let (f, m) = stage(&mut timings, "deformation field", || {
                fit_field(&field_points, &target, &curvature, &settings.field)
            })?;
            (Some(f), m)
        }
    };

    let registered = stage(&mut timings, "apply to path", || {
        let contours = path
            .contours()
            .par_iter()
            .map(|c| move_contour(c, field.as_ref(), &scan_from_cad))
            .collect::<Result<Vec<_>>>()?;
        Ok(Path::new(contours)?)
    })?;

    let contours = stage(&mut timings, "quality", || {
        Ok(contour_quality(
            path,
            field.as_ref(),
            &matches,
            &scan_from_cad,
            &settings.quality,
        ))
    })?;
    let field_rmse_mm = field.as_ref().map(|_| {
        let n = matches.len().max(1) as f64;
        (matches.iter().map(|m| m.r * m.r).sum::<f64>() / n).sqrt()
    });
    let m = scan_from_cad.to_homogeneous();
    let report = QualityReport {
        global: GlobalQuality {
            scan_from_cad: [0, 1, 2, 3].map(|i| [0, 1, 2, 3].map(|j| m[(i, j)])),
            scale: scan_from_cad.scaling(),
            coarse_rmse_mm: coarse.rmse_mm,
            overlap,
            field_rmse_mm,
            field_points: field_points.len(),
            untrustworthy: contours.iter().filter(|c| !c.trustworthy).count(),
        },
        contours,
        timings_s: timings,
    };
    Ok(Registration {
        path: registered,
        scan_from_cad,
        field,
        coarse,
        report,
    })
}

/// The coarse similarity `cad_from_scan`: scan → CAD point-to-plane ICP over a pyramid of scan
/// voxel sizes, against the full-resolution (visible) CAD.
pub fn coarse_fit(
    scan: &PointCloud,
    target: &IcpTarget,
    cad_from_scan_initial: &Similarity3,
    settings: &CoarseSettings,
) -> Result<IcpResult> {
    let first_voxel = settings.levels.first().map_or(1.0, |l| l.voxel_mm);
    let mut current = initial_guess(scan, target, cad_from_scan_initial, settings, first_voxel)?;
    let mut result = None;
    let mut iterations = 0;
    for (k, level) in settings.levels.iter().enumerate() {
        let source = PointCloud::new(dense_voxel_centroids(
            scan.points(),
            level.voxel_mm,
            settings.min_voxel_points,
        )?)?;
        let last = k + 1 == settings.levels.len();
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
        let r = icp(&source, target, &current, &s).map_err(|e| match e {
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
        current = r.target_from_source;
        iterations += r.iterations;
        result = Some(r);
    }
    let mut r = result
        .ok_or_else(|| RegisterError::setting("coarse.levels", "needs at least one level"))?;
    r.iterations = iterations;
    Ok(r)
}

/// Centroid and covariance of points.
fn moments(points: &[Point3]) -> (Point3, Matrix3<f64>) {
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
fn principal_axes(cov: &Matrix3<f64>) -> (Matrix3<f64>, bool) {
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

/// The coarse stage's start `cad_from_scan` (see [`CoarseInit`]).
fn initial_guess(
    scan: &PointCloud,
    target: &IcpTarget,
    cad_from_scan_nominal: &Similarity3,
    settings: &CoarseSettings,
    voxel_mm: f64,
) -> Result<Similarity3> {
    if settings.init == CoarseInit::Nominal {
        return Ok(*cad_from_scan_nominal);
    }
    // Both clouds thinned alike (dense voxels only), the scan taken to the CAD frame.
    let scan_pts: Vec<Point3> =
        dense_voxel_centroids(scan.points(), voxel_mm, settings.min_voxel_points)?
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
    // In the CAD frame: the correction `cad_from_nominal_scan` moves the nominally placed scan.
    let mut rotation = Matrix3::identity();
    if settings.init == CoarseInit::PrincipalAxes {
        let (es, ok_s) = principal_axes(&covs);
        let (ec, ok_c) = principal_axes(&covc);
        if ok_s && ok_c {
            // R·esᵢ = ±ecᵢ; of the four proper sign choices take the one nearest the identity.
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
            if let Some((angle, r)) = best {
                if angle <= settings.max_init_rotation_deg.to_radians() {
                    rotation = r;
                }
            }
        }
    }
    let rot = nalgebra::UnitQuaternion::from_matrix(&rotation);
    let t = cc.coords - rot * cs.coords;
    let shift = (t + rot * cs.coords - cs.coords).norm();
    if shift > MAX_INIT_TRANSLATION_MM {
        let near = overlap_fraction(&scan_pts, target.tree(), MAX_INIT_TRANSLATION_MM);
        return Err(RegisterError::NotOverlapping {
            fraction_pct: 100.0 * near,
            distance_mm: MAX_INIT_TRANSLATION_MM,
            needed_pct: 100.0,
        });
    }
    let correction = Similarity3::from_parts(nalgebra::Translation3::from(t), rot, 1.0);
    Ok(correction * cad_from_scan_nominal)
}

fn overlap_fraction(points: &[Point3], tree: &kdtree::KdTree, distance_mm: f64) -> f64 {
    let d2 = distance_mm * distance_mm;
    let near = points
        .par_iter()
        .map_init(Scratch::default, |scratch, p| {
            usize::from(tree.nearest_from(p, d2, None, scratch).is_some())
        })
        .sum::<usize>();
    near as f64 / points.len().max(1) as f64
}

/// Matches of the field's points: scan point `q` (CAD frame) to its CAD point under the current
/// field (`F⁻¹(q)`'s nearest CAD point), with the residual along the carried normal.
/// A scan point's match: CAD index, CAD point, carried normal, field Jacobian at the CAD point,
/// residual (mm).
type Matched = (usize, Point3, Vector3, Matrix3<f64>, f64);

fn match_points(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
) -> Vec<Option<Matched>> {
    let cad = target.cloud().points();
    let normals = target.cloud().normals();
    let d2max = max_distance_mm * max_distance_mm;
    points
        .par_iter()
        .map_init(Scratch::default, |scratch, q| {
            let p = field.map_or(*q, |f| f.inverse_apply(q, 2));
            // Of the nearest CAD points, the one whose surface passes closest to q: near an
            // edge the nearest sample may lie on the other face (a top-face scan point 0.1 mm
            // from a rim finds a wall sample), and its plane would pull sideways.
            let mut best: Option<(f64, usize, Point3, Vector3, Matrix3<f64>, f64)> = None;
            // The field at the nearest candidate; the others (within a millimetre) use its
            // first-order expansion `d(c) ≈ d₀ + J₀ (c − c₀)` and its normal map.
            let mut at_nearest: Option<(Point3, Vector3, Matrix3<f64>, Matrix3<f64>)> = None;
            for nb in target
                .tree()
                .knn_within(&p, MATCH_CANDIDATES, d2max, scratch)
            {
                let c = cad[nb.index];
                let n0 = normals.map_or(Vector3::z(), |ns| ns[nb.index]);
                let (c0, d0, j, normal_map) = *at_nearest.get_or_insert_with(|| {
                    let (d, j) = field.map_or((Vector3::zeros(), Matrix3::zeros()), |f| {
                        f.displacement_and_jacobian(&c)
                    });
                    let m = (Matrix3::identity() + j)
                        .try_inverse()
                        .map_or_else(Matrix3::identity, |inv| inv.transpose());
                    (c, d, j, m)
                });
                let d = d0 + j * (c - c0);
                let n = (normal_map * n0)
                    .try_normalize(f64::MIN_POSITIVE)
                    .unwrap_or(n0);
                // Distance to the osculating quadric (see `shape_operators`).
                let diff = q - (c + d);
                let t = diff - n * n.dot(&diff);
                let s = curvature
                    .get(nb.index)
                    .copied()
                    .unwrap_or_else(Matrix3::zeros);
                let r = -(n.dot(&diff) + 0.5 * (t.transpose() * s * t)[(0, 0)]);
                if best.is_none_or(|b| r.abs() < b.0) {
                    best = Some((r.abs(), nb.index, c, n, j, r));
                }
            }
            let (_, index, c, n, j, r) = best?;
            Some((index, c, n, j, r))
        })
        .collect()
}

fn final_matches(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
) -> Vec<Match> {
    match_points(points, target, curvature, field, max_distance_mm)
        .into_iter()
        .zip(points)
        .filter_map(|(m, q)| m.map(|(_, _, n, _, r)| Match { q: *q, n, r }))
        .collect()
}

/// Fits the displacement field (CAD frame) to the scan points `q` (CAD frame).
fn fit_field(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    settings: &DeformationSettings,
) -> Result<(BSplineField, Vec<Match>)> {
    let bounds = target
        .cloud()
        .bounds()
        .ok_or(RegisterError::EmptyCloud { which: "CAD" })?;
    let pad = Vector3::repeat(0.25 * settings.spacing_mm);
    let mut field = BSplineField::zero(
        &(bounds.min - pad),
        &(bounds.max + pad),
        settings.spacing_mm,
    );
    let dim = 3 * field.len();
    let stencils = field.second_differences();
    let kernel = RobustKernel::Huber {
        k_mm: settings.huber_mm,
    };
    let shrink_steps = settings.iterations.saturating_sub(3).max(1);
    let ratio = settings.max_distance_end_mm / settings.max_distance_start_mm;
    for it in 0..settings.iterations {
        let t = (it as f64 / shrink_steps as f64).min(1.0);
        let max_d = settings.max_distance_start_mm * ratio.powf(t);
        let matched = match_points(points, target, curvature, Some(&field), max_d);
        let pairs: Vec<(Point3, Vector3, f64, f64)> = matched
            .iter()
            .filter_map(|m| m.map(|(_, c, n, _, r)| (c, n, r, kernel.weight(r))))
            .collect();
        let needed = 3 * SUPPORT;
        if pairs.len() < needed {
            return Err(RegisterError::TooFewCorrespondences {
                stage: format!("deformation field, iteration {it}"),
                needed,
                got: pairs.len(),
                max_distance_mm: max_d,
            });
        }
        let (mut h, mut g) = field_normal_equations(&field, &pairs);
        // Smoothness: λ Σ |Σ cₘ δₘ|² per component, λ relative to the mean data weight.
        let mean_diag = h.diagonal().sum() / dim as f64;
        let lambda = settings.smoothness * mean_diag;
        let coeffs = field.coefficients();
        for (ix, c) in &stencils {
            for x in 0..3 {
                let e: f64 = (0..3).map(|m| c[m] * coeffs[ix[m]][x]).sum();
                for a in 0..3 {
                    g[3 * ix[a] + x] += lambda * c[a] * e;
                    for b in 0..3 {
                        h[(3 * ix[a] + x, 3 * ix[b] + x)] += lambda * c[a] * c[b];
                    }
                }
            }
        }
        // Levenberg-Marquardt damping: directions neither the data nor the prior fix (control
        // points far from the scan) take no step instead of an arbitrary one.
        for i in 0..dim {
            h[(i, i)] += FIELD_DAMPING * mean_diag.max(f64::MIN_POSITIVE);
        }
        let step = solve_banded_spd(&h, &(-&g), field.bandwidth()).ok_or_else(|| {
            RegisterError::Singular {
                stage: format!("deformation field, iteration {it}"),
                eigenvalues: Vec::new(),
            }
        })?;
        if step.iter().any(|v| !v.is_finite()) {
            return Err(RegisterError::NonFinite {
                what: format!("deformation field step, iteration {it}"),
            });
        }
        field.add_step(step.as_slice());
    }
    let matches = final_matches(
        points,
        target,
        curvature,
        Some(&field),
        settings.max_distance_end_mm,
    );
    Ok((field, matches))
}

/// `Σ w a aᵀ` and `Σ w a r` with `a = Bₖ(c) n'` (the residual's gradient in `δₖ`), accumulated
/// per grid cell (the points of a cell share their 27 control points, so each cell is one dense
/// 81-column product `Aᵀ W A`), cells in parallel, scattered in cell order (deterministic).
fn field_normal_equations(
    field: &BSplineField,
    pairs: &[(Point3, Vector3, f64, f64)],
) -> (DMatrix<f64>, DVector<f64>) {
    const LOCAL: usize = 3 * SUPPORT;
    let dim = 3 * field.len();
    let mut keyed: Vec<(usize, usize)> = pairs
        .par_iter()
        .enumerate()
        .map(|(i, p)| (field.cell_index(&p.0), i))
        .collect();
    keyed.par_sort_unstable();
    let mut groups: Vec<&[(usize, usize)]> = Vec::new();
    let mut start = 0;
    while start < keyed.len() {
        let mut end = start + 1;
        while end < keyed.len() && keyed[end].0 == keyed[start].0 {
            end += 1;
        }
        groups.push(&keyed[start..end]);
        start = end;
    }
    let locals: Vec<([usize; SUPPORT], DMatrix<f64>, DVector<f64>)> = groups
        .par_iter()
        .map(|group| {
            let n = group.len();
            let mut a = DMatrix::<f64>::zeros(n, LOCAL);
            let mut aw = DMatrix::<f64>::zeros(n, LOCAL);
            let mut gl = DVector::<f64>::zeros(LOCAL);
            let mut index = [0usize; SUPPORT];
            for (row, &(_, i)) in group.iter().enumerate() {
                let (c, nrm, r, w) = pairs[i];
                let (wt_index, wt_value) = field.values(&c);
                index = wt_index;
                for k in 0..SUPPORT {
                    for x in 0..3 {
                        let v = wt_value[k] * nrm[x];
                        a[(row, 3 * k + x)] = v;
                        aw[(row, 3 * k + x)] = w * v;
                        gl[3 * k + x] += w * v * r;
                    }
                }
            }
            (index, aw.transpose() * a, gl)
        })
        .collect();
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    let mut g = DVector::<f64>::zeros(dim);
    for (index, hl, gl) in &locals {
        for ka in 0..SUPPORT {
            for x in 0..3 {
                let ra = 3 * index[ka] + x;
                g[ra] += gl[3 * ka + x];
                for kb in 0..SUPPORT {
                    for y in 0..3 {
                        h[(ra, 3 * index[kb] + y)] += hl[(3 * ka + x, 3 * kb + y)];
                    }
                }
            }
        }
    }
    (h, g)
}

fn move_contour(
    c: &Contour,
    field: Option<&BSplineField>,
    scan_from_cad: &Similarity3,
) -> Result<Contour> {
    let rot = scan_from_cad.isometry.rotation;
    let points: Vec<Point3> = c
        .points()
        .iter()
        .map(|p| scan_from_cad * field.map_or(*p, |f| f.apply(p)))
        .collect();
    let features: Vec<Vector3> = c
        .points()
        .iter()
        .zip(c.features())
        .map(|(p, n)| rot * field.map_or(*n, |f| f.apply_normal(p, n)))
        .collect();
    Ok(Contour::with_features(c.id(), points, features)?)
}

/// `λmin/λmax` and the weakest direction of `Σ n nᵀ` (unit weights), or `(0, z)` when empty.
fn translational_degeneracy(
    normals: impl Iterator<Item = Vector3>,
) -> (f64, Vector3, Matrix3<f64>) {
    let m: Matrix3<f64> = normals.map(|n| n * n.transpose()).sum();
    let eig = SymmetricEigen::new(m);
    let (mut imin, mut imax) = (0, 0);
    for i in 0..3 {
        if eig.eigenvalues[i] < eig.eigenvalues[imin] {
            imin = i;
        }
        if eig.eigenvalues[i] > eig.eigenvalues[imax] {
            imax = i;
        }
    }
    let hi = eig.eigenvalues[imax];
    if hi <= 0.0 {
        return (0.0, Vector3::z(), m);
    }
    (
        eig.eigenvalues[imin].max(0.0) / hi,
        eig.eigenvectors.column(imin).into_owned(),
        m,
    )
}

fn contour_quality(
    path: &Path,
    field: Option<&BSplineField>,
    matches: &[Match],
    scan_from_cad: &Similarity3,
    q: &QualitySettings,
) -> Vec<ContourQuality> {
    let pts: Vec<Point3> = matches.iter().map(|m| m.q).collect();
    let tree = KdTree::build(&pts);
    let rot = scan_from_cad.isometry.rotation;
    path.contours()
        .par_iter()
        .map(|c| {
            let moved: Vec<Point3> = c
                .points()
                .iter()
                .map(|p| field.map_or(*p, |f| f.apply(p)))
                .collect();
            let max_field_displacement_mm = c
                .points()
                .iter()
                .zip(&moved)
                .map(|(a, b)| (b - a).norm())
                .fold(0.0, f64::max);
            let covered = moved
                .iter()
                .filter(|p| {
                    tree.nearest(p)
                        .is_some_and(|n| n.distance_sq <= q.coverage_radius_mm.powi(2))
                })
                .count();
            let patch =
                crop_near_polyline(&pts, &tree, &moved, q.patch_radius_mm).unwrap_or_default();
            let support =
                crop_near_polyline(&pts, &tree, &moved, q.support_radius_mm).unwrap_or_default();
            let residual_rms_mm = (!patch.is_empty()).then(|| {
                (patch.iter().map(|&i| matches[i].r.powi(2)).sum::<f64>() / patch.len() as f64)
                    .sqrt()
            });
            let (degeneracy_ratio, weakest, _) =
                translational_degeneracy(patch.iter().map(|&i| matches[i].n));
            let (_, _, ms) = translational_degeneracy(support.iter().map(|&i| matches[i].n));
            let ms_max = SymmetricEigen::new(ms).eigenvalues.max();
            let support_ratio = if ms_max > 0.0 {
                (weakest.transpose() * ms * weakest)[(0, 0)] / ms_max
            } else {
                0.0
            };
            let coverage = covered as f64 / c.points().len() as f64;
            let mut flags = Vec::new();
            if patch.is_empty() {
                flags.push(Flag::NoScanPoints);
            }
            if coverage < q.min_coverage {
                flags.push(Flag::LowCoverage);
            }
            if residual_rms_mm.is_some_and(|r| r > q.max_residual_mm) {
                flags.push(Flag::HighResidual);
            }
            if degeneracy_ratio < q.min_degeneracy_ratio {
                flags.push(Flag::Degenerate);
                if support_ratio < q.min_degeneracy_ratio {
                    flags.push(Flag::Unsupported);
                }
            }
            let trustworthy = !flags.iter().any(|f| {
                matches!(
                    f,
                    Flag::NoScanPoints | Flag::LowCoverage | Flag::HighResidual | Flag::Unsupported
                )
            });
            let w = rot * weakest;
            ContourQuality {
                id: c.id(),
                points: c.points().len(),
                scan_points: patch.len(),
                coverage,
                residual_rms_mm,
                degeneracy_ratio,
                weakest_direction: [w.x, w.y, w.z],
                support_ratio,
                max_field_displacement_mm,
                flags,
                trustworthy,
            }
        })
        .collect()
}
