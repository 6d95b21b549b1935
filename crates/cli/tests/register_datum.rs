//! `trimctl register --datums`: the six-point datum fit as the alternative positioning mode
//! recovers the pose of an undeformed synthetic part.

use std::process::Command;

use trim_geom::formats::{read_path, read_points};
use trim_geom::{Point3, Vector3};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// Runs `trimctl register --datums` on the synthetic case in `case`.
fn register_with_datums(
    case: &std::path::Path,
    datums: &std::path::Path,
    out: &std::path::Path,
    report: Option<&std::path::Path>,
) -> std::process::Output {
    let mut cmd = Command::new(TRIMCTL);
    cmd.arg("register")
        .arg("--cad")
        .arg(case.join("cad.stl"))
        .arg("--scan")
        .arg(case.join("scan.ply"))
        .arg("--path")
        .arg(case.join("path.csv"))
        .arg("--datums")
        .arg(datums)
        .arg("--out")
        .arg(out);
    if let Some(r) = report {
        cmd.arg("--report").arg(r);
    }
    cmd.output().expect("trimctl register runs")
}

/// Pointwise error the datum fit must stay under on an undeformed part with 10 µm scan noise
/// (the thesis notes it is less accurate than a surface fit).
const MAX_P95_ERROR_MM: f64 = 0.05;

#[test]
fn datum_fit_positions_an_undeformed_part() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let case = tmp.path().join("case");
    let status = Command::new(TRIMCTL)
        .args([
            "synth",
            "--seed",
            "5",
            "--sag",
            "0",
            "--twist",
            "0",
            "--scale-range",
            "0",
            "--out",
        ])
        .arg(&case)
        .status()
        .expect("trimctl synth runs");
    assert!(status.success());

    // Six datums spread over the top face: the CAD points nearest to six spots of the bounds,
    // on faces that look up (toward the default scanner direction).
    let cad = read_points(&case.join("cad_points.ply")).expect("CAD points");
    let normals = cad.normals().expect("CAD points carry normals");
    let b = cad.bounds().expect("bounds");
    let e = b.extent();
    let mut datums = String::new();
    for (fx, fy) in [
        (0.2, 0.1),
        (0.8, 0.1),
        (0.2, 0.5),
        (0.8, 0.5),
        (0.3, 0.9),
        (0.7, 0.9),
    ] {
        let spot = Point3::new(b.min.x + fx * e.x, b.min.y + fy * e.y, b.max.z);
        let (i, _) = cad
            .points()
            .iter()
            .enumerate()
            .filter(|(i, _)| normals[*i].dot(&Vector3::z()) > 0.9)
            .map(|(i, p)| (i, (p - spot).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("a CAD point faces up");
        let p = cad.points()[i];
        datums.push_str(&format!("{} {} {}\n", p.x, p.y, p.z));
    }
    std::fs::write(tmp.path().join("datums.txt"), datums).expect("write datums");

    let out = tmp.path().join("registered.csv");
    let report = tmp.path().join("report.json");
    let result = register_with_datums(&case, &tmp.path().join("datums.txt"), &out, Some(&report));
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(stdout.contains("datum fit: 6 datums"), "{stdout}");

    let registered = read_path(&out).expect("registered path");
    let truth = read_path(&case.join("truth.csv")).expect("truth");
    let mut errors: Vec<f64> = registered
        .points()
        .zip(truth.points())
        .map(|(a, b)| (a - b).norm())
        .collect();
    errors.sort_by(f64::total_cmp);
    let p95 = errors[errors.len() * 95 / 100];
    assert!(p95 < MAX_P95_ERROR_MM, "pointwise P95 {p95} mm");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("JSON");
    assert_eq!(r["mode"], "datum");
    assert_eq!(r["residuals_mm"].as_array().map(Vec::len), Some(6));

    // Too few datums is refused with the file named.
    std::fs::write(tmp.path().join("two.txt"), "0 0 0\n1 0 0\n").expect("write");
    let result = register_with_datums(
        &case,
        &tmp.path().join("two.txt"),
        &tmp.path().join("x.csv"),
        None,
    );
    assert_eq!(result.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("two.txt") && stderr.contains("at least 3"),
        "{stderr}"
    );
}
