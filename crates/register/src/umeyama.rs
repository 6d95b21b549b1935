//! Closed-form least-squares similarity (or rigid) transform between paired points.
//!
//! S. Umeyama, "Least-squares estimation of transformation parameters between two point
//! patterns", IEEE TPAMI 13(4), 1991: Eq. 34–42. With weights `wᵢ ≥ 0`, every mean and
//! covariance below is the weighted one.

use nalgebra::{Matrix3, Translation3, UnitQuaternion};
use trim_geom::{Point3, Similarity3, Vector3};

use crate::error::{RegisterError, Result};

/// Fewest pairs that fix a similarity (three non-collinear points).
pub const MIN_PAIRS: usize = 3;

/// The source spread (weighted variance, mm²) below which the pairs are called degenerate.
pub const MIN_SOURCE_VARIANCE_MM2: f64 = 1e-24;

/// The result of an Umeyama fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UmeyamaFit {
    /// The transform that takes source points onto target points.
    pub target_from_source: Similarity3,
    /// The weighted root-mean-square residual `|T·xᵢ − yᵢ|`, mm.
    pub rms_mm: f64,
}

/// The most iterations of the Umeyama SVD (a 3 × 3 converges in a few).
const SVD_MAX_ITERATIONS: usize = 1000;

/// Fits `target ≈ s·R·source + t` (Umeyama Eq. 40–42); `with_scale = false` fixes `s = 1`.
///
/// Refuses fewer than [`MIN_PAIRS`] pairs, unequal lengths, non-finite input and coincident
/// source points.
pub fn umeyama(source: &[Point3], target: &[Point3], with_scale: bool) -> Result<UmeyamaFit> {
    umeyama_weighted(source, target, None, with_scale)
}

/// [`umeyama`] with one non-negative weight per pair (`None`: all 1).
pub fn umeyama_weighted(
    source: &[Point3],
    target: &[Point3],
    weights: Option<&[f64]>,
    with_scale: bool,
) -> Result<UmeyamaFit> {
    if source.len() != target.len() {
        return Err(RegisterError::LengthMismatch {
            what: "Umeyama target points",
            expected: source.len(),
            got: target.len(),
        });
    }
    if let Some(w) = weights {
        if w.len() != source.len() {
            return Err(RegisterError::LengthMismatch {
                what: "Umeyama weights",
                expected: source.len(),
                got: w.len(),
            });
        }
        if let Some(i) = w.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(RegisterError::NonFinite {
                what: format!("Umeyama weight {i} (must be finite and ≥ 0)"),
            });
        }
    }
    if source.len() < MIN_PAIRS {
        return Err(RegisterError::TooFewCorrespondences {
            stage: "Umeyama".into(),
            needed: MIN_PAIRS,
            got: source.len(),
            max_distance_mm: f64::INFINITY,
        });
    }
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    let total: f64 = (0..source.len()).map(weight).sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(RegisterError::NonFinite {
            what: "sum of Umeyama weights (must be > 0)".into(),
        });
    }
    // Eq. 34–35: means.
    let mut mu_x = Vector3::zeros();
    let mut mu_y = Vector3::zeros();
    for (i, (x, y)) in source.iter().zip(target).enumerate() {
        mu_x += weight(i) * x.coords;
        mu_y += weight(i) * y.coords;
    }
    mu_x /= total;
    mu_y /= total;
    // Eq. 36 and 38: source variance and cross-covariance.
    let mut var_x = 0.0;
    let mut sigma = Matrix3::zeros();
    for (i, (x, y)) in source.iter().zip(target).enumerate() {
        let dx = x.coords - mu_x;
        let dy = y.coords - mu_y;
        var_x += weight(i) * dx.norm_squared();
        sigma += weight(i) * dy * dx.transpose();
    }
    var_x /= total;
    sigma /= total;
    if !(var_x.is_finite() && sigma.iter().all(|v| v.is_finite())) {
        return Err(RegisterError::NonFinite {
            what: "Umeyama input points".into(),
        });
    }
    if var_x < MIN_SOURCE_VARIANCE_MM2 {
        return Err(RegisterError::Singular {
            stage: "Umeyama: source points coincide".into(),
            eigenvalues: vec![var_x],
        });
    }
    // Eq. 39–40: SVD, with S flipping the last axis for a reflection.
    // Bounded: an SVD that does not converge (a covariance near overflow) is an error, not a
    // loop without end.
    let Some(svd) = sigma.try_svd(true, true, f64::EPSILON, SVD_MAX_ITERATIONS) else {
        return Err(RegisterError::Singular {
            stage: "Umeyama: SVD did not converge (are the points' coordinates beyond 1e100 mm?)"
                .into(),
            eigenvalues: Vec::new(),
        });
    };
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(RegisterError::Singular {
            stage: "Umeyama: SVD did not converge".into(),
            eigenvalues: svd.singular_values.iter().copied().collect(),
        });
    };
    let d = svd.singular_values;
    // nalgebra's SVD is not sorted: find the smallest singular value for the reflection fix.
    let imin = (0..3).min_by(|&a, &b| d[a].total_cmp(&d[b])).unwrap_or(2);
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if (u.determinant() * v_t.determinant()) < 0.0 {
        s[imin] = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s) * v_t;
    // The rotation's extraction below iterates until it converges: it must get a rotation.
    if !r.iter().all(|v| v.is_finite()) {
        return Err(RegisterError::NonFinite {
            what: "Umeyama rotation (the points' coordinates overflow the fit)".into(),
        });
    }
    // Eq. 42: scale; Eq. 41: translation.
    let scale = if with_scale { d.dot(&s) / var_x } else { 1.0 };
    if !(scale.is_finite() && scale > 0.0) {
        return Err(RegisterError::Singular {
            stage: format!(
                "Umeyama: the target points coincide or mirror the source (scale {scale})"
            ),
            eigenvalues: d.iter().copied().collect(),
        });
    }
    let t = mu_y - scale * r * mu_x;
    let rotation = UnitQuaternion::from_matrix(&r);
    let target_from_source = Similarity3::from_parts(Translation3::from(t), rotation, scale);
    let mut sq = 0.0;
    for (i, (x, y)) in source.iter().zip(target).enumerate() {
        sq += weight(i) * (target_from_source * x - y).norm_squared();
    }
    let rms_mm = (sq / total).sqrt();
    if !(rms_mm.is_finite() && t.iter().all(|v| v.is_finite())) {
        return Err(RegisterError::NonFinite {
            what: "Umeyama fit (the points' coordinates overflow it)".into(),
        });
    }
    Ok(UmeyamaFit {
        target_from_source,
        rms_mm,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn random_points(n: usize, seed: u64) -> Vec<Point3> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-10.0..10.0),
                )
            })
            .collect()
    }

    #[test]
    fn refuses_a_coincident_target_and_points_that_overflow_instead_of_panicking_or_hanging() {
        let source = random_points(50, 7);
        let e = umeyama(&source, &vec![Point3::origin(); 50], true).unwrap_err();
        assert!(e.to_string().contains("coincide"), "{e}");
        // Finite but so large that the fit overflows (it looped for ever, at 100 % CPU).
        let huge: Vec<Point3> = source
            .iter()
            .map(|p| Point3::from(p.coords * 1e300))
            .collect();
        assert!(umeyama(&source, &huge, true).is_err());
        assert!(umeyama(&huge, &source, true).is_err());
    }

    #[test]
    fn recovers_an_exact_similarity() {
        let src = random_points(100, 1);
        let truth = Similarity3::new(
            Vector3::new(1.0, -2.0, 3.0),
            Vector3::new(0.3, -0.2, 1.1),
            1.3,
        );
        let dst: Vec<Point3> = src.iter().map(|p| truth * p).collect();
        let fit = umeyama(&src, &dst, true).unwrap();
        assert!((fit.target_from_source.scaling() - 1.3).abs() < 1e-12);
        assert!((fit.target_from_source.to_homogeneous() - truth.to_homogeneous()).norm() < 1e-10);
        assert!(fit.rms_mm < 1e-10);
        let rigid = umeyama(&src, &dst, false).unwrap();
        assert_eq!(rigid.target_from_source.scaling(), 1.0);
        assert!(rigid.rms_mm > 1.0);
    }

    #[test]
    fn never_returns_a_reflection() {
        let src = random_points(50, 2);
        let dst: Vec<Point3> = src.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let fit = umeyama(&src, &dst, true).unwrap();
        let m = fit
            .target_from_source
            .isometry
            .rotation
            .to_rotation_matrix();
        assert!((m.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn weights_select_pairs() {
        let src = random_points(60, 3);
        let truth = Similarity3::new(
            Vector3::new(0.5, 0.0, 0.0),
            Vector3::new(0.0, 0.0, 0.2),
            1.0,
        );
        let mut dst: Vec<Point3> = src.iter().map(|p| truth * p).collect();
        let mut w = vec![1.0; 60];
        for i in 0..10 {
            dst[i] += Vector3::new(50.0, 0.0, 0.0);
            w[i] = 0.0;
        }
        let fit = umeyama_weighted(&src, &dst, Some(&w), false).unwrap();
        assert!(fit.rms_mm < 1e-10);
    }

    #[test]
    fn refuses_bad_input() {
        let p = random_points(5, 4);
        assert!(umeyama(&p[..2], &p[..2], true).is_err());
        assert!(umeyama(&p, &p[..4], true).is_err());
        let same = vec![Point3::new(1.0, 1.0, 1.0); 5];
        assert!(matches!(
            umeyama(&same, &p, true),
            Err(RegisterError::Singular { .. })
        ));
        assert!(umeyama_weighted(&p, &p, Some(&[0.0; 5]), true).is_err());
    }
}
