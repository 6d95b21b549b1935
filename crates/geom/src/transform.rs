//! Rigid and similarity transforms: conversions to and from 4×4 matrices and comparisons.
//!
//! Names follow `b_from_a`: a transform that takes coordinates in frame `a` to frame `b`.

use nalgebra::{Matrix3, Matrix4, Rotation3 as NaRotation3, Translation3, UnitQuaternion};

use crate::error::{GeomError, Result};
use crate::math::{Rigid3, Similarity3, Vector3};

/// A 4×4 matrix whose upper-left block deviates from a scaled rotation by more than this
/// (relative, Frobenius) is refused by [`similarity_from_matrix`].
pub const MATRIX_ORTHOGONALITY_TOLERANCE: f64 = 1e-6;

/// A similarity with unit scale from a rigid transform.
#[must_use]
pub fn similarity_from_rigid(b_from_a: &Rigid3) -> Similarity3 {
    Similarity3::from_isometry(*b_from_a, 1.0)
}

/// Refuses a transform with a NaN or infinite entry, or a scale that is not > 0, naming it
/// `b_from_a` (the caller adds where it came from: a job.toml key, a file).
pub fn check_transform(b_from_a: &Similarity3) -> Result<()> {
    let iso = &b_from_a.isometry;
    let finite = iso.translation.vector.iter().all(|c| c.is_finite())
        && iso.rotation.coords.iter().all(|c| c.is_finite())
        && b_from_a.scaling().is_finite();
    if !finite {
        return Err(GeomError::invalid(
            "b_from_a",
            "the transform has a NaN or infinite entry",
        ));
    }
    if b_from_a.scaling() <= 0.0 {
        return Err(GeomError::invalid(
            "b_from_a",
            format!(
                "the transform's scale must be > 0, got {}",
                b_from_a.scaling()
            ),
        ));
    }
    Ok(())
}

/// The homogeneous 4×4 matrix of a similarity: `[s·R t; 0 1]`.
#[must_use]
pub fn to_matrix(b_from_a: &Similarity3) -> Matrix4<f64> {
    b_from_a.to_homogeneous()
}

/// A similarity from a homogeneous 4×4 matrix `[s·R t; 0 1]`, with `s > 0` and `R` a proper
/// rotation. Refuses non-finite entries, a bottom row other than `[0 0 0 1]`, reflections,
/// shears and anisotropic scale.
pub fn similarity_from_matrix(m: &Matrix4<f64>) -> Result<Similarity3> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(GeomError::invalid("matrix", "has NaN or infinite entries"));
    }
    let bottom = m.fixed_view::<1, 4>(3, 0);
    if (bottom - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).norm() > 1e-12 {
        return Err(GeomError::invalid("matrix", "bottom row is not [0 0 0 1]"));
    }
    let sr: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let det = sr.determinant();
    if det <= 0.0 {
        return Err(GeomError::invalid(
            "matrix",
            format!("rotation block has determinant {det:.3e}: not a proper rotation"),
        ));
    }
    let scale = det.cbrt();
    let r = sr / scale;
    let err = (r.transpose() * r - Matrix3::identity()).norm();
    if err > MATRIX_ORTHOGONALITY_TOLERANCE {
        return Err(GeomError::invalid(
            "matrix",
            format!("rotation block is not a scaled rotation (orthogonality error {err:.3e})"),
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&NaRotation3::from_matrix_unchecked(r));
    let translation = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Similarity3::from_parts(translation, rotation, scale))
}

/// The rotation angle (radians) of `b_from_a⁻¹ · c_from_a`'s rotation: how far apart two
/// transforms' rotations are.
#[must_use]
pub fn rotation_angle_between(x: &Similarity3, y: &Similarity3) -> f64 {
    x.isometry.rotation.angle_to(&y.isometry.rotation)
}

/// The distance (mm) between two transforms' translations.
#[must_use]
pub fn translation_distance(x: &Similarity3, y: &Similarity3) -> f64 {
    (x.isometry.translation.vector - y.isometry.translation.vector).norm()
}

/// A similarity from an axis-angle vector (radians), a translation (mm) and a scale.
#[must_use]
pub fn similarity(translation: Vector3, axis_angle: Vector3, scale: f64) -> Similarity3 {
    Similarity3::new(translation, axis_angle, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_round_trip() {
        let s = similarity(
            Vector3::new(1.0, -2.0, 3.0),
            Vector3::new(0.1, 0.2, -0.3),
            1.04,
        );
        let back = similarity_from_matrix(&to_matrix(&s)).unwrap();
        assert!((back.scaling() - 1.04).abs() < 1e-12);
        assert!(rotation_angle_between(&s, &back) < 1e-12);
        assert!(translation_distance(&s, &back) < 1e-12);
    }

    #[test]
    fn refuses_reflection_shear_and_nan() {
        let mut m = Matrix4::identity();
        m[(0, 0)] = -1.0;
        assert!(similarity_from_matrix(&m).is_err());
        let mut m = Matrix4::identity();
        m[(0, 1)] = 0.5;
        assert!(similarity_from_matrix(&m).is_err());
        let mut m = Matrix4::identity();
        m[(2, 3)] = f64::NAN;
        assert!(similarity_from_matrix(&m).is_err());
    }
}
