//! Criterion benchmark of surface hatching (`trim_plan::hatch`, default geodesic method): 200k
//! scan points (10 µm noise) of a saddle-like patch, a 40 × 40 mm region, 0.05 mm pitch, points
//! every 0.05 mm (about 800 tracks, 640k points). Name: `plan/hatch/200k`.
//!
//! Setup plans the case once and prints what `measure` reports (spacing across the surface,
//! coverage, boundary error, time) on stderr. The slab method is left out here: at this size
//! (about 800 tracks × 1600 slab contours) it ran over 15 minutes single-threaded; it is
//! compared with the default on the test surfaces (`crates/plan/tests/hatch.rs`).
#![expect(
    missing_docs,
    reason = "criterion_group! generates an undocumented pub fn"
)]

use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{Point3, PointCloud, Vector3};
use trim_plan::hatch::{HatchMethod, HatchSettings, hatch, measure};

/// The seed of the scan.
const SEED: u64 = 0x4a7c_0200;
/// Scan points.
const POINTS: usize = 200_000;
/// Half the region's side, mm.
const HALF_MM: f64 = 20.0;
/// The scanned box extends this far beyond the region, mm.
const MARGIN_MM: f64 = 1.0;
/// Scan noise per coordinate, mm.
const NOISE_MM: f64 = 0.01;
/// Track pitch and point step, mm.
const PITCH_MM: f64 = 0.05;

fn surface(x: f64, y: f64) -> Point3 {
    Point3::new(x, y, (x * x - 0.5 * y * y) / 120.0)
}

fn case() -> (PointCloud, Vec<Point3>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(SEED);
    let half = HALF_MM + MARGIN_MM;
    let gauss = move |rng: &mut Xoshiro256PlusPlus| {
        let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let points = (0..POINTS)
        .map(|_| {
            let p = surface(rng.random_range(-half..half), rng.random_range(-half..half));
            p + Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * NOISE_MM
        })
        .collect();
    let corners = [
        [-HALF_MM, -HALF_MM],
        [HALF_MM, -HALF_MM],
        [HALF_MM, HALF_MM],
        [-HALF_MM, HALF_MM],
    ];
    let mut boundary = Vec::new();
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        for j in 0..200 {
            let t = f64::from(j) / 200.0;
            boundary.push(surface(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])));
        }
    }
    boundary.push(boundary[0]);
    (
        PointCloud::new(points).expect("finite synthetic points"),
        boundary,
    )
}

fn bench(c: &mut Criterion) {
    let (cloud, boundary) = case();
    let settings = |method| HatchSettings {
        pitch_mm: PITCH_MM,
        angle_deg: 30.0,
        method,
        ..HatchSettings::default()
    };
    {
        let method = HatchMethod::Geodesic;
        let start = Instant::now();
        let h = hatch(&cloud, &boundary, &settings(method)).expect("hatch succeeds");
        let time = start.elapsed().as_secs_f64();
        let r = measure(&h);
        eprintln!(
            "hatch 200k {method}: {} tracks, {} points, spacing mean {:.5} mm CV {:.2} % min \
             {:.5} max {:.5}, coverage {:.4} (hatch only {:.4}), max gap {:.4} mm, boundary \
             {:.2e} mm, {time:.3} s",
            r.hatch_tracks,
            r.points,
            r.spacing.mean_mm,
            100.0 * r.spacing.cv,
            r.spacing.min_mm,
            r.spacing.max_mm,
            r.coverage,
            r.coverage_hatch_only,
            r.max_gap_mm,
            r.boundary_error_mm,
        );
    }
    let mut group = c.benchmark_group("plan/hatch");
    group.sample_size(10);
    let geodesic = settings(HatchMethod::Geodesic);
    group.bench_function("200k", |b| {
        b.iter(|| hatch(&cloud, &boundary, &geodesic).expect("hatch succeeds"));
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
