//! The coarse stage's capture range: synthetic cores placed at exact fixture errors (size ×
//! eight directions, `tests/common/posed.rs`), registered from the fixture's nominal pose (the
//! identity); per start, whether it converged, the cross-edge error, the coarse pose found
//! against the truth, the coarse stage's starts and time, or the error.
//!
//! `cargo run --release -p trim-register --example capture -- [deg/mm ...] [--seed N]
//! [--points N]` (default sizes 0/0 10/10 18/18 20/20 35/40). `TRIM_SETTINGS`: a JSON
//! `[register]` table.

use std::time::Instant;

use trim_register::eval::path_errors;
use trim_register::regional::{RegisterSettings, register};

#[path = "../tests/common/posed.rs"]
mod posed;
use posed::{DIRECTIONS, fixture_error, posed_case};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut sizes = Vec::new();
    let (mut seed, mut points) = (7u64, 120_000usize);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--seed" => seed = args.next().ok_or("--seed N")?.parse()?,
            "--points" => points = args.next().ok_or("--points N")?.parse()?,
            size => {
                let (d, m) = size.split_once('/').ok_or("sizes as DEG/MM")?;
                sizes.push((d.parse::<f64>()?, m.parse::<f64>()?));
            }
        }
    }
    if sizes.is_empty() {
        sizes = vec![
            (0.0, 0.0),
            (10.0, 10.0),
            (18.0, 18.0),
            (20.0, 20.0),
            (35.0, 40.0),
        ];
    }
    println!(
        "| fixture °/mm | axis | shift dir | result | cross-edge P95/max µm | coarse pose err °/mm | offset found °/mm | starts | score | coarse s | total s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (deg, mm) in sizes {
        for (i, axis) in DIRECTIONS.iter().enumerate() {
            let dir = DIRECTIONS[(i + 3) % DIRECTIONS.len()];
            let error = fixture_error(deg, *axis, mm, dir);
            let case = posed_case(seed, points, &error);
            let base: RegisterSettings = match std::env::var("TRIM_SETTINGS") {
                Ok(json) => serde_json::from_str(&json)?,
                Err(_) => RegisterSettings::default(),
            };
            let settings = RegisterSettings {
                scanner_viewpoint_mm: Some(case.scanner_mm.coords.into()),
                ..base
            };
            let t0 = Instant::now();
            let result = register(
                &case.cad,
                &case.scan,
                &case.path,
                &nalgebra::Similarity3::identity(),
                &settings,
            );
            let total = t0.elapsed().as_secs_f64();
            let fmt = |v: &[f64; 3]| format!("{:.2},{:.2},{:.2}", v[0], v[1], v[2]);
            match result {
                Ok(reg) => {
                    let e = path_errors(&reg.path, &case.truth, |_| true)?;
                    let diff = case.scan_from_cad_true.inverse() * reg.scan_from_cad;
                    let coarse_s: f64 = reg
                        .report
                        .timings_s
                        .iter()
                        .filter(|(n, _)| n.starts_with("coarse") || n.contains("captured"))
                        .map(|(_, s)| *s)
                        .sum();
                    let g = &reg.report.global;
                    println!(
                        "| {deg}/{mm} | {} | {} | ok | {:.1}/{:.1} | {:.2}/{:.2} | {:.2}/{:.2} | {} | {:.3} | {coarse_s:.3} | {total:.3} |",
                        fmt(axis),
                        fmt(&dir),
                        e.cross_edge_p95_mm * 1e3,
                        e.cross_edge_max_mm * 1e3,
                        diff.isometry.rotation.angle().to_degrees(),
                        diff.isometry.translation.vector.norm(),
                        g.fixture_offset.rotation_deg,
                        g.fixture_offset.translation_mm,
                        g.coarse_starts,
                        g.capture_score,
                    );
                }
                Err(err) => println!(
                    "| {deg}/{mm} | {} | {} | refused: {err} | | | | | | | {total:.3} |",
                    fmt(axis),
                    fmt(&dir)
                ),
            }
        }
    }
    Ok(())
}
