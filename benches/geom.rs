//! Criterion benchmarks of trim-geom: binary PLY reading, kd-tree build and nearest-neighbour
//! queries. Data are seeded (see the constants); names are `geom/op/size`.
#![expect(
    missing_docs,
    reason = "criterion_group! generates an undocumented pub fn"
)]

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::formats::{self, PlyEncoding, PlyScalar};
use trim_geom::{KdTree, Point3, PointCloud};

/// Seed of the benchmark clouds.
const CLOUD_SEED: u64 = 0x6765_6f6d;
/// Seed of the query points.
const QUERY_SEED: u64 = 0x7175_6572;
/// Queries per nearest-neighbour batch.
const QUERY_BATCH: usize = 10_000;

/// `n` points uniform in a 200 × 200 × 20 mm slab (a scanned part's extent).
fn slab(n: usize, seed: u64) -> Vec<Point3> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            Point3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-10.0..10.0),
            )
        })
        .collect()
}

fn label(n: usize) -> String {
    match n {
        1_000_000 => "1M".into(),
        100_000 => "100k".into(),
        other => other.to_string(),
    }
}

/// A temporary file removed when dropped.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn ply_read_binary(c: &mut Criterion) {
    const N: usize = 1_000_000;
    let cloud = PointCloud::new(slab(N, CLOUD_SEED)).expect("finite points");
    // float x y z, little-endian: what scanners and CloudCompare write.
    let bytes = formats::encode_ply(&cloud, PlyEncoding::BinaryLittleEndian, PlyScalar::Float);
    let file =
        TempFile(std::env::temp_dir().join(format!("trimctl-bench-{}-1M.ply", std::process::id())));
    std::fs::write(&file.0, bytes).expect("write the benchmark PLY");
    let mut group = c.benchmark_group("geom/ply_read_binary");
    group.throughput(Throughput::Elements(N as u64));
    group.sample_size(10);
    group.bench_function(label(N), |b| {
        b.iter(|| {
            let read = formats::read_points(black_box(&file.0)).expect("read the benchmark PLY");
            assert_eq!(read.len(), N);
            read
        });
    });
    group.finish();
}

fn kdtree_build(c: &mut Criterion) {
    let mut group = c.benchmark_group("geom/kdtree_build");
    group.sample_size(10);
    for n in [100_000, 1_000_000] {
        let points = slab(n, CLOUD_SEED);
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(label(n)), &points, |b, pts| {
            b.iter(|| KdTree::build(black_box(pts)));
        });
    }
    group.finish();
}

fn kdtree_nearest(c: &mut Criterion) {
    let mut group = c.benchmark_group("geom/kdtree_nearest");
    let queries = slab(QUERY_BATCH, QUERY_SEED);
    group.throughput(Throughput::Elements(QUERY_BATCH as u64));
    for n in [100_000, 1_000_000] {
        let tree = KdTree::build(&slab(n, CLOUD_SEED));
        group.bench_with_input(BenchmarkId::from_parameter(label(n)), &queries, |b, qs| {
            b.iter(|| {
                let mut sum_sq = 0.0;
                for q in qs {
                    sum_sq += tree.nearest(black_box(q)).map_or(0.0, |n| n.distance_sq);
                }
                sum_sq
            });
        });
    }
    group.finish();
}

criterion_group!(benches, ply_read_binary, kdtree_build, kdtree_nearest);
criterion_main!(benches);
