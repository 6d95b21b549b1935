//! Per-contour quality: coverage, residual, translational degeneracy and support, and the flags
//! that make a contour untrustworthy.

use super::*;

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

/// `λmin/λmax` and the weakest direction of `Σ n nᵀ` (unit weights), or `(0, z)` when empty.
pub(crate) fn translational_degeneracy(
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

pub(crate) fn contour_quality(
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
