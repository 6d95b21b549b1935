//! Accuracy sweep on synthetic cores: trimctl's regional registration across the range a core
//! can come in (seeded cases of `tests/common/cases.rs`: bend 0.1–0.5 mm, twist 0.2–1°, scale
//! ±0.5–2 %, noise 8–15 µm, fixture errors up to 20° and 20 mm), per contour group, against a
//! re-implementation of the paper's method.
//!
//! `cargo run --release -p trim-register --example accuracy -- [seeds] [scan_points] [first_seed]`
//!
//! Environment: `TRIM_NO_PAPER` skips the paper's method; `TRIM_CAD_POINTS` (200000);
//! `TRIM_SETTINGS` a JSON `[register]` table; `TRIM_DEBUG` prints timings, mean errors and the
//! flagged contours; `TRIM_CONTOURS=FILE` appends one CSV row per contour (seed, id, actual max
//! cross-edge error µm, predicted bound µm, field σ µm, patch residual µm, field rmse µm,
//! coverage, support distance mm, trustworthy, flags) for calibrating the bound.

use std::io::Write;
use std::time::Instant;

use trim_register::eval::path_errors;
use trim_register::regional::{RegisterSettings, register};
use trim_register::scaled_icp_baseline::{PaperSettings, paper_local_fits, paper_method};
use trim_synth::generate;

#[path = "../tests/common/cases.rs"]
mod cases;
use cases::{GROUPS, case_params};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).map_or(Ok(8), |s| s.parse())?;
    let scan_points: usize = args.get(2).map_or(Ok(200_000), |s| s.parse())?;
    let first: u64 = args.get(3).map_or(Ok(1), |s| s.parse())?;
    let cad_points: usize = std::env::var("TRIM_CAD_POINTS").map_or(Ok(200_000), |v| v.parse())?;
    let debug = std::env::var_os("TRIM_DEBUG").is_some();
    let mut contours_csv = match std::env::var("TRIM_CONTOURS") {
        Ok(file) => Some(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(file)?,
        ),
        Err(_) => None,
    };
    println!(
        "| seed | bend mm | twist ° | scale ± | shrink gradient | noise µm | fixture °/mm | method | cross-edge P95 µm | cross-edge max µm | pointwise P95 µm | slots P95/max | holes P95/max | edges P95/max | flagged | bound misses | time s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    let (mut contours, mut misses) = (0usize, 0usize);
    for seed in first..first + seeds {
        let params = case_params(seed, scan_points, cad_points);
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
        let mut groups = Vec::new();
        for (_, range) in &GROUPS {
            let g = path_errors(&reg.path, &case.truth, |id| range.contains(&id))?;
            groups.push(format!(
                "{:.1}/{:.1}",
                g.cross_edge_p95_mm * 1e3,
                g.cross_edge_max_mm * 1e3
            ));
        }
        // Each contour's actual largest cross-edge error against its predicted bound.
        let mut case_misses = 0;
        for q in &reg.report.contours {
            let actual_um =
                path_errors(&reg.path, &case.truth, |id| id == q.id)?.cross_edge_max_mm * 1e3;
            let predicted_um = q.predicted_max_error_um;
            contours += 1;
            if actual_um > predicted_um {
                case_misses += 1;
            }
            if let Some(f) = contours_csv.as_mut() {
                writeln!(
                    f,
                    "{seed},{},{actual_um:.2},{predicted_um:.2},{:.3},{:.3},{:.3},{:.3},{:.3},{},\"{:?}\"",
                    q.id,
                    q.field_sigma_mm * 1e3,
                    q.residual_rms_mm.unwrap_or(f64::NAN) * 1e3,
                    reg.report.global.field_rmse_mm.unwrap_or(f64::NAN) * 1e3,
                    q.coverage,
                    q.support_distance_mm,
                    q.trustworthy,
                    q.flags
                )?;
            }
            if debug && (actual_um > predicted_um || !q.trustworthy) {
                eprintln!(
                    "  contour {}: actual {actual_um:.1} µm, predicted {predicted_um:.1} µm, flags {:?}",
                    q.id, q.flags
                );
            }
        }
        misses += case_misses;
        if debug {
            eprintln!("timings {:?}", reg.report.timings_s);
            let rinv = case.scan_from_cad_true.inverse();
            for (name, range) in &GROUPS {
                // Mean error in the part frame, and the error split into height (along the
                // feature vector), across (in the face, across the contour) and along the
                // contour, RMS and max, µm.
                let mut sum = nalgebra::Vector3::zeros();
                let mut n = 0.0;
                let (mut ss, mut mx) = ([0.0f64; 3], [0.0f64; 3]);
                for c in reg
                    .path
                    .contours()
                    .iter()
                    .filter(|c| range.contains(&c.id()))
                {
                    let t = case.truth.get(c.id()).ok_or("contour missing from truth")?;
                    let tp = t.points();
                    for (k, (p, q)) in c.points().iter().zip(tp).enumerate() {
                        sum += rinv.isometry.rotation * (p - q);
                        n += 1.0;
                        let a = tp[k.saturating_sub(1)];
                        let b = tp[(k + 1).min(tp.len() - 1)];
                        let along = (b - a).normalize();
                        let up = t.features()[k];
                        let across = up.cross(&along).normalize();
                        let d = p - q;
                        for (i, v) in [d.dot(&up), d.dot(&across), d.dot(&along)]
                            .into_iter()
                            .enumerate()
                        {
                            ss[i] += v * v;
                            mx[i] = mx[i].max(v.abs());
                        }
                    }
                }
                eprintln!(
                    "  {name}: mean error (part frame) {:.1?} µm; rms height/across/along {:.1?} max {:.1?}",
                    (sum / n * 1e3).as_slice(),
                    ss.map(|v| (v / n).sqrt() * 1e3),
                    mx.map(|v| v * 1e3)
                );
            }
        }
        worst.0 = worst.0.max(e.cross_edge_p95_mm);
        worst.1 = worst.1.max(e.cross_edge_max_mm);
        worst.2 = worst.2.max(e.pointwise_p95_mm);
        let head = format!(
            "| {seed} | {:.2} | {:.2} | {:.1} % | {:+.2} % | {:.1} | {:.1}/{:.1}",
            params.sag_mm,
            params.twist_deg,
            params.scale_range * 100.0,
            params.shrink_gradient * 100.0,
            params.noise_mm * 1e3,
            params.pose_deg,
            params.pose_mm
        );
        println!(
            "{head} | trimctl | {:.1} | {:.1} | {:.1} | {} | {} | {case_misses} | {t_ours:.2} |",
            e.cross_edge_p95_mm * 1e3,
            e.cross_edge_max_mm * 1e3,
            e.pointwise_p95_mm * 1e3,
            groups.join(" | "),
            reg.report.global.untrustworthy,
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
                    "{head} | paper | {:.1} | {:.1} | {:.1} | | | | – | – | {t_paper:.2} |",
                    e.cross_edge_p95_mm * 1e3,
                    e.cross_edge_max_mm * 1e3,
                    e.pointwise_p95_mm * 1e3
                );
            }
            Err(err) => println!("{head} | paper | failed: {err} | | | | | | – | – | |"),
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
            "{head} | paper local, trimctl coarse | {:.1} | {:.1} | {:.1} | | | | – | – | {t_local:.2} |",
            e.cross_edge_p95_mm * 1e3,
            e.cross_edge_max_mm * 1e3,
            e.pointwise_p95_mm * 1e3
        );
    }
    println!(
        "\nworst trimctl case: cross-edge P95 {:.1} µm, max {:.1} µm, pointwise P95 {:.1} µm; \
         contours over their predicted bound: {misses} of {contours} ({:.1} %)",
        worst.0 * 1e3,
        worst.1 * 1e3,
        worst.2 * 1e3,
        100.0 * misses as f64 / contours.max(1) as f64
    );
    Ok(())
}
