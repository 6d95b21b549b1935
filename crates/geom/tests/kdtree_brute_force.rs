//! kiddo's nearest neighbour over 1M points agrees with a brute-force scan (correctness, not
//! speed: the speed is in benches/geom.rs).

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use trim_geom::{KdTree, Point3};

/// The seed of the cloud and of the queries.
const SEED: u64 = 0x6b64_7472_6565;
const POINTS: usize = 1_000_000;
const QUERIES: usize = 300;

fn squared_distance(a: &Point3, b: &Point3) -> f64 {
    let d = a - b;
    d.x * d.x + d.y * d.y + d.z * d.z
}

#[test]
fn nearest_matches_brute_force_over_a_million_points() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(SEED);
    // A 200 × 200 × 20 mm slab, like a scanned part.
    let points: Vec<Point3> = (0..POINTS)
        .map(|_| {
            Point3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-10.0..10.0),
            )
        })
        .collect();
    let tree = KdTree::build(&points);
    assert_eq!(tree.len(), POINTS);
    // Queries inside the slab, outside it, and on data points.
    let queries: Vec<Point3> = (0..QUERIES)
        .map(|i| match i % 3 {
            0 => Point3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-10.0..10.0),
            ),
            1 => Point3::new(
                rng.random_range(-300.0..300.0),
                rng.random_range(-300.0..300.0),
                rng.random_range(-50.0..50.0),
            ),
            _ => points[rng.random_range(0..POINTS)],
        })
        .collect();
    let mismatches: Vec<String> = queries
        .par_iter()
        .enumerate()
        .filter_map(|(i, q)| {
            let brute = points
                .iter()
                .map(|p| squared_distance(p, q))
                .fold(f64::INFINITY, f64::min);
            let found = tree.nearest(q)?;
            let found_d = squared_distance(&points[found.index], q);
            // Exact: both compute the same sum of squares; ties may pick another index, but the
            // distance must be the smallest.
            (found.distance_sq != brute || found_d != brute).then(|| {
                format!(
                    "query {i} {q}: kiddo {} (index {}, {found_d}), brute force {brute}",
                    found.distance_sq, found.index
                )
            })
        })
        .collect();
    assert!(mismatches.is_empty(), "{mismatches:#?}");
}
