//! Local (zone) frames (paper Eq. 11–13, corrected to right-handed as DESIGN.md says).
//!
//! Paper Eq. 12: Z = zone axis, Y = V − (V·Z)·Z normalised with V the work-piece Z axis. The
//! paper then writes X = Z × Y, which makes a left-handed frame (a mirrored galvo image); here
//! X = Y × Z, so X × Y = Z. When Z is (nearly) parallel to V, Y is undefined; the reference
//! becomes the work-piece Y axis instead, which gives the identity frame for Z = +Z_w.
//!
//! The planner does not use this frame as is for the galvo: see [`crate::kinematics`] — the
//! galvo writes in the machine head's X/Y, so the zone frame's X/Y are the head's X/Y seen from
//! the part at the zone's pose. For xyzac-trt with A ≤ 0 that frame *is* this one; with A > 0
//! it is this one turned 180° about Z. [`paper_frame`] stays the reference the tests compare to.

use trim_geom::{Point3, UnitVector3, Vector3};

use crate::job::Frame;

/// Below this length of V − (V·Z)·Z (|sin| of the angle between Z and V), Z counts as parallel
/// to V and the fallback reference axis is used.
pub const PARALLEL_SIN_LIMIT: f64 = 1e-6;

/// The right-handed paper frame (Eq. 12, X = Y × Z) of a zone axis, in work-piece coordinates.
#[must_use]
pub fn paper_frame(axis: &UnitVector3) -> Frame {
    let z = axis.into_inner();
    let reference = |v: Vector3| v - z * v.dot(&z);
    let mut y = reference(Vector3::z());
    if y.norm() < PARALLEL_SIN_LIMIT {
        y = reference(Vector3::y());
    }
    let y = y.normalize();
    let x = y.cross(&z);
    frame_from_axes(&x, &y, &z)
}

/// A frame from three axis vectors (expected orthonormal and right-handed).
#[must_use]
pub fn frame_from_axes(x: &Vector3, y: &Vector3, z: &Vector3) -> Frame {
    Frame {
        x: [x.x, x.y, x.z],
        y: [y.x, y.y, y.z],
        z: [z.x, z.y, z.z],
    }
}

/// How far a frame is from orthonormal and right-handed: the largest entry of |RᵀR − I| and
/// |det R − 1|.
#[must_use]
pub fn orthonormality_error(frame: &Frame) -> f64 {
    let m = nalgebra::Matrix3::from_columns(&[frame.x_axis(), frame.y_axis(), frame.z_axis()]);
    let gram = m.transpose() * m - nalgebra::Matrix3::identity();
    gram.amax().max((m.determinant() - 1.0).abs())
}

/// A point in the zone frame (origin `origin`, axes `frame`), work-piece to local: paper
/// Eq. 11 with H from Eq. 13.
#[must_use]
pub fn to_local(frame: &Frame, origin: &Point3, point_in_workpiece: &Point3) -> Vector3 {
    let d = point_in_workpiece - origin;
    Vector3::new(
        d.dot(&frame.x_axis()),
        d.dot(&frame.y_axis()),
        d.dot(&frame.z_axis()),
    )
}

/// The inverse of [`to_local`]: a local point back in the work-piece frame.
#[must_use]
pub fn to_workpiece(frame: &Frame, origin: &Point3, point_in_zone: &Vector3) -> Point3 {
    origin
        + frame.x_axis() * point_in_zone.x
        + frame.y_axis() * point_in_zone.y
        + frame.z_axis() * point_in_zone.z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_right_handed_with_y_toward_workpiece_z() {
        let axis = UnitVector3::new_normalize(Vector3::new(0.752, -0.644, 0.136));
        let f = paper_frame(&axis);
        assert!(orthonormality_error(&f) < 1e-12);
        assert!((f.x_axis().cross(&f.y_axis()) - axis.into_inner()).norm() < 1e-12);
        // Y is the work-piece Z with its Z component removed: it leans toward +Z_w.
        assert!(f.y_axis().z > 0.0);
        assert!(f.x_axis().z.abs() < 1e-12, "X is horizontal");
    }

    #[test]
    fn parallel_axis_falls_back_to_y_reference() {
        let f = paper_frame(&UnitVector3::new_normalize(Vector3::z()));
        assert!((f.x_axis() - Vector3::x()).norm() < 1e-12);
        assert!((f.y_axis() - Vector3::y()).norm() < 1e-12);
        let f = paper_frame(&UnitVector3::new_normalize(-Vector3::z()));
        assert!(orthonormality_error(&f) < 1e-12);
        assert!((f.x_axis() + Vector3::x()).norm() < 1e-12);
    }

    #[test]
    fn local_round_trip() {
        let f = paper_frame(&UnitVector3::new_normalize(Vector3::new(0.3, 0.2, 0.9)));
        let o = Point3::new(1.0, 2.0, 3.0);
        let p = Point3::new(-4.0, 5.5, 7.25);
        let back = to_workpiece(&f, &o, &to_local(&f, &o, &p));
        assert!((back - p).norm() < 1e-12);
    }
}
