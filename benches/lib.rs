//! Criterion benchmarks of the trimctl hot paths (see `benches/*.rs` and `benches/benches/`).
//! This library holds the seeded generators the registration benches share; the plan and hatch
//! benches generate their cases with `trim_synth::testing` and their own surface.

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{Point3, PointCloud, Similarity3, Vector3};

/// A wavy surface patch with normals (z = 2 sin(x/7) cos(y/5)): `n` points drawn uniformly
/// over 100 × 100 mm with the generator seeded by `seed`.
#[must_use]
pub fn wavy_surface(n: usize, seed: u64) -> PointCloud {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut points = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    for _ in 0..n {
        let (x, y): (f64, f64) = (rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0));
        let z = 2.0 * (x / 7.0).sin() * (y / 5.0).cos();
        let dzdx = 2.0 / 7.0 * (x / 7.0).cos() * (y / 5.0).cos();
        let dzdy = -2.0 / 5.0 * (x / 7.0).sin() * (y / 5.0).sin();
        points.push(Point3::new(x, y, z));
        normals.push(Vector3::new(-dzdx, -dzdy, 1.0));
    }
    PointCloud::with_normals(points, normals).expect("the generated points are finite")
}

/// The small similarity the registration benches move the source by: 0.37 mm, about 1.3°.
#[must_use]
pub fn small_motion() -> Similarity3 {
    Similarity3::new(
        Vector3::new(0.3, -0.2, 0.1),
        Vector3::new(0.01, -0.005, 0.02),
        1.0,
    )
}
