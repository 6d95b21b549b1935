//! The coarse similarity: a start from the fixture pose or the principal axes, then scan → CAD
//! point-to-plane ICP with scale over a voxel pyramid.

use super::*;

/// The coarse stage refuses a scale change beyond `exp(±0.1)` (±10 %) from the fixture's: no
/// part is that far off, and a scan → CAD fit that gets there is shrinking onto the surface.
pub const MAX_COARSE_LOG_SCALE_CHANGE: f64 = 0.1;

/// The centroid start may move the scan at most this far from the nominal pose, mm (three times
/// the 5 mm fixture error trimctl is specified for): a larger shift means the scan is not of
/// this part at this fixture, refused as not overlapping.
pub const MAX_INIT_TRANSLATION_MM: f64 = 15.0;

/// Principal axes count as defined when consecutive variances differ by this factor.
pub const MIN_AXIS_VARIANCE_RATIO: f64 = 1.3;

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
pub(crate) fn moments(points: &[Point3]) -> (Point3, Matrix3<f64>) {
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
pub(crate) fn principal_axes(cov: &Matrix3<f64>) -> (Matrix3<f64>, bool) {
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
pub(crate) fn initial_guess(
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

pub(crate) fn overlap_fraction(points: &[Point3], tree: &kdtree::KdTree, distance_mm: f64) -> f64 {
    let d2 = distance_mm * distance_mm;
    let near = points
        .par_iter()
        .map_init(Scratch::default, |scratch, p| {
            usize::from(tree.nearest_from(p, d2, None, scratch).is_some())
        })
        .sum::<usize>();
    near as f64 / points.len().max(1) as f64
}
