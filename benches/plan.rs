//! Criterion benchmarks of trim-plan: zoning (pieces + k-means with automatic k + merging) and
//! layering (paper Eq. 14 cuts of every zone) on the synthetic ceramic-core path with 60 (the
//! paper's case) and 2,000 contours, and the whole planner with its default settings (pose
//! covering, layers, poses, tour, commands, validation). Names: `plan/zoning/{n}`,
//! `plan/layering/{n}`, `plan/plan/{n}`.
#![expect(
    missing_docs,
    reason = "criterion_group! generates an undocumented pub fn"
)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use trim_plan::piece::pieces_of;
use trim_plan::planner::PlanSettings;
use trim_plan::zoning::zone_pieces;
use trim_synth::testing::synthetic_core_path;

/// The seed of the synthetic paths.
const SEED: u64 = 0x7a11_3c0e;

/// Contour counts: the paper's 60 and a large part.
const SIZES: [usize; 2] = [60, 2000];

fn bench(c: &mut Criterion) {
    let settings = PlanSettings::default();
    let limit_rad = settings
        .field
        .zoning_limit_rad(settings.max_incidence_deg.to_radians());
    let step_mm = settings
        .layers
        .step_for(settings.beam.focus_half_length_mm())
        .expect("default layer settings are valid");
    let merge_radius_mm =
        settings.beam.focal_length_mm * settings.field.lens_ray_budget_deg.to_radians().tan();
    let mut group = c.benchmark_group("plan");
    group.sample_size(10);
    for n in SIZES {
        let path = synthetic_core_path(n, SEED);
        group.bench_with_input(BenchmarkId::new("plan", n), &path, |b, path| {
            b.iter(|| trim_plan::planner::plan(path, &settings).expect("plans"));
        });
        group.bench_with_input(BenchmarkId::new("zoning", n), &path, |b, path| {
            b.iter(|| {
                let pieces = pieces_of(path, limit_rad, limit_rad).expect("valid path");
                zone_pieces(&pieces, limit_rad, &settings.zoning, merge_radius_mm)
                    .expect("zoning succeeds")
            });
        });
        let pieces = pieces_of(&path, limit_rad, limit_rad).expect("valid path");
        let zoning = zone_pieces(&pieces, limit_rad, &settings.zoning, merge_radius_mm)
            .expect("zoning succeeds");
        // Each zone's members are gathered once, outside the timing: only the cuts are timed.
        let members: Vec<Vec<_>> = zoning
            .groups
            .iter()
            .map(|g| g.pieces.iter().map(|&i| pieces[i].clone()).collect())
            .collect();
        group.bench_with_input(BenchmarkId::new("layering", n), &members, |b, members| {
            b.iter(|| {
                zoning
                    .groups
                    .iter()
                    .zip(members)
                    .map(|(g, m)| {
                        trim_plan::layer::layer_pieces(m, &g.centre, &g.axis, step_mm)
                            .expect("the bench's layer step is in range")
                            .layers
                            .len()
                    })
                    .sum::<usize>()
            });
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
