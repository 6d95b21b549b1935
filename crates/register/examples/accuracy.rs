//! Accuracy sweep on synthetic cores: trimctl's regional registration against a
//! re-implementation of the paper's method, several seeds and deformation levels.
//!
//! `cargo run --release -p trim-register --example accuracy -- [seeds] [scan_points]`

use std::time::Instant;

use trim_register::eval::path_errors;
use trim_register::paper::{PaperSettings, paper_local_fits, paper_method};
use trim_register::regional::{RegisterSettings, register};
use trim_synth::{SynthParams, generate};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).map_or(Ok(3), |s| s.parse())?;
    let scan_points: usize = args.get(2).map_or(Ok(200_000), |s| s.parse())?;
    println!(
        "| level | seed | method | cross-edge P95 µm | cross-edge max µm | pointwise P95 µm | flagged | time s |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (level, sag, twist, scale, pose_deg, pose_mm) in [
        ("mild", 0.2, 0.4, 0.005, 2.0, 1.0),
        ("large", 0.5, 1.0, 0.02, 5.0, 3.0),
    ] {
        for seed in 1..=seeds {
            let params = SynthParams {
                seed,
                sag_mm: sag,
                twist_deg: twist,
                scale_range: scale,
                pose_deg,
                pose_mm,
                scan_points,
                cad_points: std::env::var("TRIM_CAD_POINTS").map_or(Ok(200_000), |v| v.parse())?,
                ..SynthParams::default()
            };
            let case = generate(&params)?;
            let base: RegisterSettings = match std::env::var("TRIM_SETTINGS") {
                Ok(json) => serde_json::from_str(&json)?,
                Err(_) => RegisterSettings::default(),
            };
            let settings = RegisterSettings {
                scanner_viewpoint_mm: Some(case.scanner_in_scan.coords.into()),
                ..base
            };
            let t0 = Instant::now();
            let reg = register(
                &case.cad_points,
                &case.scan,
                &case.path,
                &case.scan_from_cad_nominal,
                &settings,
            )?;
            let t_ours = t0.elapsed().as_secs_f64();
            let e = path_errors(&reg.path, &case.truth, |_| true)?;
            if std::env::var_os("TRIM_DEBUG").is_some() {
                eprintln!("timings {:?}", reg.report.timings_s);
                for (name, range) in [("slots", 1..=4), ("holes", 5..=46), ("edges", 47..=52)] {
                    let e = path_errors(&reg.path, &case.truth, |id| range.contains(&id))?;
                    eprintln!(
                        "  {name}: cross P95 {:.1} max {:.1} pointwise P95 {:.1}",
                        e.cross_edge_p95_mm * 1e3,
                        e.cross_edge_max_mm * 1e3,
                        e.pointwise_p95_mm * 1e3
                    );
                }
                let rinv = case.scan_from_cad_true.inverse();
                for (name, range) in [("slots", 1..=4), ("holes", 5..=46), ("edges", 47..=52)] {
                    let mut sum = nalgebra::Vector3::zeros();
                    let mut n = 0.0;
                    for c in reg
                        .path
                        .contours()
                        .iter()
                        .filter(|c| range.contains(&c.id()))
                    {
                        let t = case.truth.get(c.id()).ok_or("contour missing from truth")?;
                        for (p, q) in c.points().iter().zip(t.points()) {
                            sum += rinv.isometry.rotation * (p - q);
                            n += 1.0;
                        }
                    }
                    eprintln!(
                        "  {name}: mean error (part frame) {:.1?} µm",
                        (sum / n * 1e3).as_slice()
                    );
                }
                for c in reg.report.contours.iter().filter(|c| !c.trustworthy) {
                    eprintln!("  flagged {c:?}");
                }
            }
            println!(
                "| {level} | {seed} | trimctl | {:.1} | {:.1} | {:.1} | {} | {t_ours:.2} |",
                e.cross_edge_p95_mm * 1e3,
                e.cross_edge_max_mm * 1e3,
                e.pointwise_p95_mm * 1e3,
                reg.report.global.untrustworthy
            );
            if std::env::var_os("TRIM_NO_PAPER").is_some() {
                continue;
            }
            let t0 = Instant::now();
            match paper_method(
                &case.cad_points,
                &case.scan,
                &case.path,
                &case.scan_from_cad_nominal,
                &PaperSettings::default(),
            ) {
                Ok(p) => {
                    let t_paper = t0.elapsed().as_secs_f64();
                    let e = path_errors(&p, &case.truth, |_| true)?;
                    println!(
                        "| {level} | {seed} | paper | {:.1} | {:.1} | {:.1} | – | {t_paper:.2} |",
                        e.cross_edge_p95_mm * 1e3,
                        e.cross_edge_max_mm * 1e3,
                        e.pointwise_p95_mm * 1e3
                    );
                }
                Err(err) => println!("| {level} | {seed} | paper | failed: {err} | | | | |"),
            }
            // The paper's local stage started from trimctl's coarse similarity.
            let t0 = Instant::now();
            let local = paper_local_fits(
                &case.cad_points,
                &case.scan,
                &case.path,
                &reg.scan_from_cad,
                &PaperSettings::default(),
            )?;
            let t_local = t0.elapsed().as_secs_f64();
            let e = path_errors(&local, &case.truth, |_| true)?;
            println!(
                "| {level} | {seed} | paper local, trimctl coarse | {:.1} | {:.1} | {:.1} | – | {t_local:.2} |",
                e.cross_edge_p95_mm * 1e3,
                e.cross_edge_max_mm * 1e3,
                e.pointwise_p95_mm * 1e3
            );
        }
    }
    Ok(())
}
