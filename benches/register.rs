//! Criterion benchmarks of trim-register: `register/<op>/<size>`.
//!
//! `cargo bench -p trimctl-benches --bench register -- --warm-up-time 1 --measurement-time 5`
#![expect(
    missing_docs,
    reason = "criterion_group! generates an undocumented pub fn"
)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::synth::{SynthParams, generate};
use trim_geom::{Point3, PointCloud, Similarity3, Vector3};
use trim_register::icp::{IcpMethod, IcpSettings, IcpTarget, icp_step, nearest_correspondences};
use trim_register::kdtree::KdTree;
use trim_register::regional::{RegisterSettings, register};
use trim_register::umeyama::umeyama;

/// Seed of every generated cloud.
const SEED: u64 = 20_261_121;
const SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];

/// A wavy surface patch with normals (z = 2 sin(x/7) cos(y/5)), `n` points over 100 × 100 mm.
fn surface(n: usize, seed: u64) -> PointCloud {
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
    PointCloud::with_normals(points, normals).expect("finite")
}

fn small_motion() -> Similarity3 {
    Similarity3::new(
        Vector3::new(0.3, -0.2, 0.1),
        Vector3::new(0.01, -0.005, 0.02),
        1.0,
    )
}

fn bench_ops(c: &mut Criterion) {
    let mut group = c.benchmark_group("register");
    group.sample_size(10);
    for n in SIZES {
        let target = surface(n, SEED);
        let source = surface(n, SEED + 1).transformed(&small_motion());
        group.bench_with_input(BenchmarkId::new("kdtree_build", n), &target, |b, t| {
            b.iter(|| KdTree::build(t.points()));
        });
        let prepared = IcpTarget::new(target.clone()).expect("non-empty");
        group.bench_with_input(BenchmarkId::new("correspondences", n), &source, |b, s| {
            b.iter(|| nearest_correspondences(s.points(), prepared.tree(), 1.0));
        });
        let settings = IcpSettings {
            method: IcpMethod::PointToPlane,
            max_correspondence_distance_mm: 1.0,
            ..IcpSettings::default()
        };
        group.bench_with_input(BenchmarkId::new("icp_iteration", n), &source, |b, s| {
            b.iter(|| {
                icp_step(s, &prepared, &Similarity3::identity(), &settings, "bench").expect("step")
            });
        });
        let moved: Vec<Point3> = source.points().iter().map(|p| small_motion() * p).collect();
        group.bench_with_input(BenchmarkId::new("umeyama", n), &moved, |b, m| {
            b.iter(|| umeyama(source.points(), m, true).expect("fit"));
        });
    }
    group.finish();
}

fn bench_full(c: &mut Criterion) {
    let case = generate(&SynthParams {
        seed: SEED,
        sag_mm: 0.5,
        twist_deg: 1.0,
        scale_range: 0.02,
        scan_points: 500_000,
        cad_points: 200_000,
        ..SynthParams::default()
    })
    .expect("synthetic case");
    let settings = RegisterSettings {
        scanner_viewpoint_mm: Some(case.scanner_in_scan.coords.into()),
        ..RegisterSettings::default()
    };
    let mut group = c.benchmark_group("register");
    group.sample_size(10);
    group.bench_function("full/500k", |b| {
        b.iter(|| {
            register(
                &case.cad_points,
                &case.scan,
                &case.path,
                &case.scan_from_cad_nominal,
                &settings,
            )
            .expect("registered")
        });
    });
    group.finish();
}

criterion_group!(benches, bench_ops, bench_full);
criterion_main!(benches);
