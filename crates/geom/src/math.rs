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

/// `v` scaled to unit length, or `None` when it is NaN, infinite or shorter than `min_norm`.
/// Divides by the largest component first, so vectors with huge components (whose length
/// overflows to infinity) still normalise instead of vanishing.
#[must_use]
pub fn unit_or_none(v: &Vector3, min_norm: f64) -> Option<Vector3> {
    if !is_finite_vector(v) {
        return None;
    }
    let largest = v.amax();
    if largest == 0.0 {
        return None;
    }
    let scaled = v / largest;
    let scaled_norm = scaled.norm();
    // The true length, largest × scaled_norm, may overflow to infinity: that is long enough.
    if largest * scaled_norm < min_norm {
        return None;
    }
    Some(scaled / scaled_norm)
}

/// Two unit vectors completing the unit normal `n` to a right-handed frame `(e1, e2, n)`: `e1`
/// is `n × x` (or `n × y` when `n` lies within about 25° of x), `e2 = n × e1`.
#[must_use]
pub fn tangent_basis(n: &Vector3) -> (Vector3, Vector3) {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    (e1, e2)
}
