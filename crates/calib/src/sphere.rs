//! Robust sphere fits with a known radius: RANSAC on three-point hypotheses, then Gauss–Newton
//! on the inliers (thesis §3: the standard sphere as the calibration artefact).

use nalgebra::{Matrix3, Vector3 as V3};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::Serialize;
use trim_geom::{Point3, Vector3};

use crate::error::CalibError;

/// Fewest points a sphere fit takes.
pub const MIN_SPHERE_POINTS: usize = 30;
/// RANSAC hypotheses.
const RANSAC_ITERATIONS: usize = 600;
/// Points scored per hypothesis (a random subset of a large scan).
const SCORE_POINTS: usize = 3000;
/// Gauss–Newton iterations of the refinement.
const REFINE_ITERATIONS: usize = 20;

/// A fitted sphere.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SphereFit {
    /// The centre (the scan's frame, mm).
    pub centre: Point3,
    /// RMS of the inliers' radial residuals (µm).
    pub rms_um: f64,
    /// Points used in the final fit.
    pub inliers: usize,
    /// Points in the scan.
    pub points: usize,
    /// The centre's covariance (mm²): σ²·(JᵀJ)⁻¹.
    #[serde(skip)]
    pub covariance: Matrix3<f64>,
}

/// The two centres of spheres of radius r through three points (none when the points are
/// collinear or farther apart than the sphere allows).
fn centres_through(a: &Point3, b: &Point3, c: &Point3, r: f64) -> Option<[Point3; 2]> {
    let (ab, ac) = (b - a, c - a);
    let n = ab.cross(&ac);
    let n2 = n.norm_squared();
    if n2 < 1e-12 {
        return None;
    }
    // Circumcentre of the triangle.
    let cc = a + (ac.norm_squared() * n.cross(&ab) + ab.norm_squared() * ac.cross(&n)) / (2.0 * n2);
    let rho2 = (cc - a).norm_squared();
    let h2 = r * r - rho2;
    if h2 < 0.0 {
        return None;
    }
    let off = n / n2.sqrt() * h2.sqrt();
    Some([cc + off, cc - off])
}

/// Fits a sphere of radius `radius_mm` to a scan of its visible cap among other points (table,
/// outliers). Deterministic for a seed.
pub fn fit_sphere(points: &[Point3], radius_mm: f64, seed: u64) -> Result<SphereFit, CalibError> {
    if !(radius_mm.is_finite() && radius_mm > 0.0) {
        return Err(CalibError::Invalid {
            key: "sphere radius".into(),
            message: format!("must be > 0, got {radius_mm}"),
        });
    }
    if points.len() < MIN_SPHERE_POINTS {
        return Err(CalibError::TooFew {
            what: "scan points".into(),
            needed: MIN_SPHERE_POINTS,
            got: points.len(),
        });
    }
    if let Some(i) = points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        return Err(CalibError::Invalid {
            key: format!("point {i}"),
            message: "is not finite".into(),
        });
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let score_set: Vec<&Point3> = if points.len() > SCORE_POINTS {
        (0..SCORE_POINTS)
            .map(|_| &points[rng.random_range(0..points.len())])
            .collect()
    } else {
        points.iter().collect()
    };
    // Inlier band: a fraction of the radius, at least 50 µm (scanner noise is ~10 µm).
    let band = (0.01 * radius_mm).max(0.05);
    let mut best: Option<(usize, Point3)> = None;
    for _ in 0..RANSAC_ITERATIONS {
        let pick = |rng: &mut Xoshiro256PlusPlus| points[rng.random_range(0..points.len())];
        let (a, b, c) = (pick(&mut rng), pick(&mut rng), pick(&mut rng));
        let Some(cands) = centres_through(&a, &b, &c, radius_mm) else {
            continue;
        };
        for centre in cands {
            let count = score_set
                .iter()
                .filter(|p| ((**p - centre).norm() - radius_mm).abs() < band)
                .count();
            if best.is_none_or(|(n, _)| count > n) {
                best = Some((count, centre));
            }
        }
    }
    let Some((count, mut centre)) = best else {
        return Err(CalibError::Degenerate(
            "no sphere of the given radius found in the scan".into(),
        ));
    };
    if count < MIN_SPHERE_POINTS.min(score_set.len() / 20).max(10) {
        return Err(CalibError::Degenerate(format!(
            "no sphere of radius {radius_mm} mm found (best: {count} of {} points within {band} mm)",
            score_set.len()
        )));
    }
    // Refine: Gauss–Newton on the inliers, the band shrinking to 3σ.
    let mut band = band;
    let mut fit = None;
    for _ in 0..REFINE_ITERATIONS {
        let inliers: Vec<&Point3> = points
            .iter()
            .filter(|p| ((*p - centre).norm() - radius_mm).abs() < band)
            .collect();
        if inliers.len() < MIN_SPHERE_POINTS {
            break;
        }
        let (mut jtj, mut jtr, mut ss) = (Matrix3::zeros(), V3::zeros(), 0.0);
        for p in &inliers {
            let d: Vector3 = *p - centre;
            let dist = d.norm();
            if dist < 1e-12 {
                continue;
            }
            let r = dist - radius_mm;
            let j = -d / dist;
            jtj += j * j.transpose();
            jtr += j * r;
            ss += r * r;
        }
        let Some(inv) = jtj.try_inverse() else {
            return Err(CalibError::Degenerate(
                "the sphere's inlier points do not fix its centre".into(),
            ));
        };
        let step = -(inv * jtr);
        centre += step;
        let sigma2 = ss / (inliers.len().saturating_sub(3).max(1)) as f64;
        fit = Some(SphereFit {
            centre,
            rms_um: sigma2.sqrt() * 1e3,
            inliers: inliers.len(),
            points: points.len(),
            covariance: inv * sigma2,
        });
        band = (3.0 * sigma2.sqrt()).max(1e-3).min(band);
        if step.norm() < 1e-9 {
            break;
        }
    }
    let fit =
        fit.ok_or_else(|| CalibError::Degenerate("too few sphere points after refinement".into()))?;
    // A sphere cutting a plane finds a ring of coplanar "inliers": a real cap has depth.
    let inliers: Vec<Vector3> = points
        .iter()
        .filter(|p| ((*p - fit.centre).norm() - radius_mm).abs() < band)
        .map(|p| p.coords)
        .collect();
    let mean = inliers.iter().sum::<Vector3>() / inliers.len() as f64;
    let scatter = inliers
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>()
        / inliers.len() as f64;
    let depth = scatter.symmetric_eigenvalues().min().max(0.0).sqrt();
    if depth < MIN_CAP_DEPTH_FRACTION * radius_mm {
        return Err(CalibError::Degenerate(format!(
            "the points that fit a sphere of radius {radius_mm} mm lie in a plane (depth {depth:.3} mm): no sphere cap in the scan"
        )));
    }
    Ok(fit)
}

/// A cap's inliers must spread at least this fraction of the radius across their flattest
/// direction (a cap of 30° half-angle spreads about 0.04 R).
const MIN_CAP_DEPTH_FRACTION: f64 = 0.02;

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn finds_a_cap_among_table_points_and_outliers() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let noise = Normal::new(0.0, 0.01).expect("normal");
        let centre = Point3::new(3.0, -4.0, -150.0);
        let r = 12.7;
        let mut pts = Vec::new();
        while pts.len() < 3000 {
            let n = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            if n.norm() > 1.0 || n.norm() < 0.1 || n.normalize().z < 0.3 {
                continue;
            }
            let p = centre + n.normalize() * r;
            pts.push(
                p + Vector3::new(
                    noise.sample(&mut rng),
                    noise.sample(&mut rng),
                    noise.sample(&mut rng),
                ),
            );
        }
        for _ in 0..1500 {
            pts.push(Point3::new(
                rng.random_range(-40.0..40.0),
                rng.random_range(-40.0..40.0),
                -170.0 + noise.sample(&mut rng),
            ));
        }
        for _ in 0..100 {
            pts.push(Point3::new(
                rng.random_range(-40.0..40.0),
                rng.random_range(-40.0..40.0),
                rng.random_range(-180.0..-120.0),
            ));
        }
        let f = fit_sphere(&pts, r, 1).expect("fit");
        assert!((f.centre - centre).norm() < 0.002, "{f:?}");
        assert!(f.rms_um > 5.0 && f.rms_um < 15.0, "{f:?}");
        assert!(f.covariance.trace().sqrt() < 0.002);
    }

    #[test]
    fn refuses_a_scan_without_the_sphere() {
        let pts: Vec<Point3> = (0..500)
            .map(|i| Point3::new(f64::from(i % 25), f64::from(i / 25), 0.0))
            .collect();
        assert!(fit_sphere(&pts, 12.7, 1).is_err());
        assert!(fit_sphere(&pts[..10], 12.7, 1).is_err());
        let mut nan = pts.clone();
        nan[7].y = f64::NAN;
        let e = fit_sphere(&nan, 12.7, 1).expect_err("NaN").to_string();
        assert!(e.contains("point 7"), "{e}");
    }
}
