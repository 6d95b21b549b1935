//! A synthetic ceramic-core-like trimming path for tests and benches (roughly the paper's
//! Fig. 10): circular holes on a curved surface plus strip contours whose feature vectors turn
//! along them. The full test case (CAD, scan, ground truth) is `trim_synth`; this is only
//! the path, sized for planning.
//!
//! Geometry (work-piece frame, mm): the surface is a cylinder of radius [`CORE_RADIUS_MM`] about
//! the Z axis, centred on the origin (the part sits on the rotary table's pivot), heights
//! ±[`CORE_HALF_HEIGHT_MM`]. Surface normals lean [`NORMAL_LIFT`] upward, like the paper's
//! feature vectors (w ≈ 0.1–0.19).
//! - Holes (half the contours): circles of 24 segments on a grid over azimuth −40°…−5°.
//! - Strips (the other half): arcs around the cylinder at azimuth 0°…+40°, each spanning
//!   4°–12° of azimuth, so their per-point normals spread up to 6° from their mean and the
//!   wider ones must be split.

use rand_xoshiro_06::Xoshiro256PlusPlus;
use rand_xoshiro_06::rand_core::{RngCore, SeedableRng};
use trim_geom::{Contour, Path, Point3, Vector3};

/// The cylinder radius (mm).
pub const CORE_RADIUS_MM: f64 = 25.0;
/// Half the height of the contour region (mm).
pub const CORE_HALF_HEIGHT_MM: f64 = 25.0;
/// The upward lean of the normals (the w of an unnormalised (cos φ, sin φ, w)).
pub const NORMAL_LIFT: f64 = 0.15;
/// Points per hole circle (the first repeated at the end).
pub const HOLE_SEGMENTS: usize = 24;
/// Points per strip.
pub const STRIP_POINTS: usize = 20;

fn uniform(rng: &mut Xoshiro256PlusPlus) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn surface(phi: f64, z: f64) -> (Point3, Vector3) {
    let n = Vector3::new(phi.cos(), phi.sin(), NORMAL_LIFT).normalize();
    (
        Point3::new(CORE_RADIUS_MM * phi.cos(), CORE_RADIUS_MM * phi.sin(), z),
        n,
    )
}

/// The synthetic core path with `n_contours` contours (≥ 2), seeded. `n_contours = 60` is the
/// paper's case.
///
/// # Panics
/// Never for `n_contours ≥ 2`: every contour is built with distinct points and unit features.
#[must_use]
pub fn synthetic_core_path(n_contours: usize, seed: u64) -> Path {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let n_holes = n_contours / 2;
    let n_strips = n_contours - n_holes;
    let cols = 6usize;
    let rows = n_holes.div_ceil(cols).max(1);
    let dz = 2.0 * CORE_HALF_HEIGHT_MM / rows as f64;
    let hole_radius = (0.3 * dz).min(0.8);
    let mut contours = Vec::with_capacity(n_contours);
    for h in 0..n_holes {
        let (row, col) = (h / cols, h % cols);
        let phi = (-40.0
            + 35.0 * (col as f64 + 0.5 + 0.2 * (uniform(&mut rng) - 0.5)) / cols as f64)
            .to_radians();
        let z = -CORE_HALF_HEIGHT_MM + dz * (row as f64 + 0.5);
        let (c, n) = surface(phi, z);
        // Tangent plane basis: along the azimuth and along Z (orthogonalised).
        let t1 = Vector3::new(-phi.sin(), phi.cos(), 0.0);
        let t2 = n.cross(&t1).normalize();
        let points: Vec<Point3> = (0..=HOLE_SEGMENTS)
            .map(|i| {
                let a = std::f64::consts::TAU * (i % HOLE_SEGMENTS) as f64 / HOLE_SEGMENTS as f64;
                c + (t1 * a.cos() + t2 * a.sin()) * hole_radius
            })
            .collect();
        contours.push(
            Contour::new(h as i64, points, n)
                .expect("a hole has distinct points and a unit feature"),
        );
    }
    let strip_rows = n_strips.div_ceil(2).max(1);
    let strip_dz = 2.0 * CORE_HALF_HEIGHT_MM / strip_rows as f64;
    for s in 0..n_strips {
        let (row, side) = (s / 2, s % 2);
        let span_deg = 4.0 + 8.0 * uniform(&mut rng);
        let start_deg = if side == 0 { 2.0 } else { 22.0 } + 4.0 * uniform(&mut rng);
        let z = -CORE_HALF_HEIGHT_MM + strip_dz * (row as f64 + 0.5);
        let (points, features): (Vec<Point3>, Vec<Vector3>) = (0..STRIP_POINTS)
            .map(|i| {
                let phi =
                    (start_deg + span_deg * i as f64 / (STRIP_POINTS - 1) as f64).to_radians();
                surface(phi, z)
            })
            .unzip();
        let id = (n_holes + s) as i64;
        contours.push(
            Contour::with_features(id, points, features)
                .expect("a strip has distinct points and unit features"),
        );
    }
    Path::new(contours).expect("ids are unique")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn has_the_requested_contours_and_spreading_strips() {
        let p = synthetic_core_path(60, 7);
        assert_eq!(p.len(), 60);
        let wide = p
            .contours()
            .iter()
            .filter(|c| c.feature_spread_rad() > 5f64.to_radians())
            .count();
        assert!(wide > 0, "some strips spread wider than 5°");
        assert_eq!(synthetic_core_path(60, 7), p, "seeded");
        assert_ne!(synthetic_core_path(60, 8), p);
    }
}
