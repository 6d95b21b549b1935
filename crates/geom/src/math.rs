//! Type aliases for the geometry used across trimctl (all `f64`, millimetres and radians).

/// A point in some frame, millimetres.
pub type Point3 = nalgebra::Point3<f64>;
/// A free vector (direction or displacement), millimetres where it has a length.
pub type Vector3 = nalgebra::Vector3<f64>;
/// A unit direction.
pub type UnitVector3 = nalgebra::Unit<nalgebra::Vector3<f64>>;
/// A rigid transform (rotation then translation), named `b_from_a`.
pub type Rigid3 = nalgebra::Isometry3<f64>;
/// A similarity transform (uniform scale, rotation, translation), named `b_from_a`.
pub type Similarity3 = nalgebra::Similarity3<f64>;
/// A 3D rotation.
pub type Rotation3 = nalgebra::UnitQuaternion<f64>;

/// Whether every coordinate of `p` is finite.
#[must_use]
pub fn is_finite_point(p: &Point3) -> bool {
    p.coords.iter().all(|c| c.is_finite())
}

/// Whether every coordinate of `v` is finite.
#[must_use]
pub fn is_finite_vector(v: &Vector3) -> bool {
    v.iter().all(|c| c.is_finite())
}
