//! Criterion benchmarks of trim-register: `register/<op>/<size>`.
//!
//! - `kdtree_build`: registration's kd-tree over the target.
//! - `correspondences`: each source point's nearest target point within 1 mm, on registration's
//!   tree (bounded search, parallel over 256-point chunks).
//! - `correspondences_kiddo`: the same queries on trim-geom's kiddo tree (nearest, then the bound),
//!   chunked the same way: the comparison docs/DESIGN.md quotes for the deviation from kiddo.
//! - `icp_iteration_cold`: one point-to-plane iteration from fresh buffers (no previous
//!   correspondences to start the searches from), as an ICP run's first iteration.
//! - `icp_10_iterations`: a point-to-plane run held to exactly 10 iterations (convergence
//!   disabled): the first cold, the other nine warm-started from the previous correspondences.
//! - `umeyama`: the closed-form scaled fit of the moved source onto the source.
//! - `full/500k`: the whole regional registration of a 500k-point synthetic core scan, at the
//!   size a CAM export and a fine CAD give (issue 21's outside cases): a path of 0.05 mm spacing
//!   (~18k rows) and 200k CAD points sampled from a mesh of 0.35 mm steps (~122k triangles).
//!   File reading is not timed here; `benches/peers/run` times the whole CLI on the same case.
//!
//! `cargo bench -p trimctl-benches --bench register -- --warm-up-time 1 --measurement-time 5`
#![expect(
    missing_docs,
    reason = "criterion_group! generates an undocumented pub fn"
)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use rayon::prelude::*;
use trim_geom::{Point3, Similarity3};
use trim_register::icp::{
    IcpMethod, IcpSettings, IcpTarget, icp, icp_step, nearest_correspondences,
};
use trim_register::kdtree::KdTree;
use trim_register::regional::{RegisterSettings, register};
use trim_register::umeyama::umeyama;
use trim_synth::{SynthParams, generate};
use trimctl_benches::{small_motion, wavy_surface};

/// Source points per parallel task, as registration's own correspondence search.
const QUERY_CHUNK: usize = 256;
/// The correspondence bound of the ICP benches, mm.
const MAX_DISTANCE_MM: f64 = 1.0;

/// Seed of every generated cloud.
const SEED: u64 = 20_261_121;
const SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];

fn bench_ops(c: &mut Criterion) {
    let mut group = c.benchmark_group("register");
    group.sample_size(10);
    for n in SIZES {
        let target = wavy_surface(n, SEED);
        let source = wavy_surface(n, SEED + 1)
            .transformed(&small_motion())
            .expect("a finite motion");
        group.bench_with_input(BenchmarkId::new("kdtree_build", n), &target, |b, t| {
            b.iter(|| KdTree::build(t.points()));
        });
        let prepared = IcpTarget::new(target.clone()).expect("non-empty");
        group.bench_with_input(BenchmarkId::new("correspondences", n), &source, |b, s| {
            b.iter(|| nearest_correspondences(s.points(), prepared.tree(), MAX_DISTANCE_MM));
        });
        let kiddo = trim_geom::kdtree::KdTree::build(target.points());
        group.bench_with_input(
            BenchmarkId::new("correspondences_kiddo", n),
            &source,
            |b, s| {
                b.iter(|| {
                    let max_sq = MAX_DISTANCE_MM * MAX_DISTANCE_MM;
                    let mut found: Vec<Option<(usize, f64)>> = vec![None; s.len()];
                    found
                        .par_chunks_mut(QUERY_CHUNK)
                        .zip(s.points().par_chunks(QUERY_CHUNK))
                        .for_each(|(out, pts)| {
                            for (o, p) in out.iter_mut().zip(pts) {
                                *o = kiddo
                                    .nearest(p)
                                    .filter(|nb| nb.distance_sq <= max_sq)
                                    .map(|nb| (nb.index, nb.distance_sq));
                            }
                        });
                    found
                });
            },
        );
        let settings = IcpSettings {
            method: IcpMethod::PointToPlane,
            max_correspondence_distance_mm: MAX_DISTANCE_MM,
            ..IcpSettings::default()
        };
        group.bench_with_input(
            BenchmarkId::new("icp_iteration_cold", n),
            &source,
            |b, s| {
                b.iter(|| {
                    icp_step(s, &prepared, &Similarity3::identity(), &settings, "bench")
                        .expect("step")
                });
            },
        );
        let ten = IcpSettings {
            max_iterations: 10,
            translation_epsilon_mm: 0.0,
            rotation_epsilon_rad: 0.0,
            scale_epsilon: 0.0,
            ..settings
        };
        let once = icp(&source, &prepared, &Similarity3::identity(), &ten).expect("icp");
        assert_eq!(
            once.iterations, 10,
            "the run must take exactly 10 iterations"
        );
        group.bench_with_input(BenchmarkId::new("icp_10_iterations", n), &source, |b, s| {
            b.iter(|| icp(s, &prepared, &Similarity3::identity(), &ten).expect("icp"));
        });
        let moved: Vec<Point3> = source.points().iter().map(|p| small_motion() * p).collect();
        group.bench_with_input(BenchmarkId::new("umeyama", n), &moved, |b, m| {
            b.iter(|| umeyama(source.points(), m, true).expect("fit"));
        });
    }
    group.finish();
}

/// `full/500k`'s path spacing, mm: ~18k path rows, as a CAM export at 0.05 mm.
const FULL_PATH_SPACING_MM: f64 = 0.05;
/// `full/500k`'s CAD mesh step, mm: ~122k triangles.
const FULL_MESH_STEP_MM: f64 = 0.35;

fn bench_full(c: &mut Criterion) {
    let case = generate(&SynthParams {
        seed: SEED,
        sag_mm: 0.5,
        twist_deg: 1.0,
        scale_range: 0.02,
        scan_points: 500_000,
        cad_points: 200_000,
        path_spacing_mm: FULL_PATH_SPACING_MM,
        mesh_step_mm: FULL_MESH_STEP_MM,
        ..SynthParams::default()
    })
    .expect("synthetic case");
    eprintln!(
        "register/full/500k: {} path rows, {} CAD triangles, {} scan points",
        case.path.points().count(),
        case.cad_triangles.len(),
        case.scan.len()
    );
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
