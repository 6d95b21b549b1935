//! job.toml's `[part.scan_from_cad]`, the fixture's nominal pose of the part: `trimctl run` and
//! `trimctl register --config` start registration there (`register --initial` overrides it), so
//! a part fixtured far beyond the capture range registers with the key and is refused, naming
//! the key, without it; a bad pose is refused naming the key or the file.

use std::path::Path;
use std::process::Command;

use trim_geom::formats::{PlyEncoding, read_path, read_points, write_ply};
use trim_geom::{Point3, Similarity3};
use trim_register::eval::path_errors;

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// The fixture's pose in the test: extrinsic X-Y-Z angles (35° in all) and a 32 mm shift, far
/// beyond the default capture range of 20° and 20 mm.
const ROTATION_DEG: [f64; 3] = [25.0, -20.0, 15.0];
const TRANSLATION_MM: [f64; 3] = [30.0, -10.0, 5.0];

/// The registered path against the truth: the targets (tests of trim-register), mm.
const CROSS_EDGE_P95_MM: f64 = 0.020;
const CROSS_EDGE_MAX_MM: f64 = 0.050;

fn fixture() -> Similarity3 {
    let [rx, ry, rz] = ROTATION_DEG.map(f64::to_radians);
    Similarity3::from_parts(
        nalgebra::Translation3::new(TRANSLATION_MM[0], TRANSLATION_MM[1], TRANSLATION_MM[2]),
        nalgebra::UnitQuaternion::from_euler_angles(rx, ry, rz),
        1.0,
    )
}

/// A synthetic core without fixture error, then the whole scene (scan, truth, scanner) placed by
/// [`fixture`]: the part sits exactly where `[part.scan_from_cad]` will say. Returns the job
/// text without the key.
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a setup failure must fail the test"
)]
fn posed_case(dir: &Path) -> String {
    let case = dir.join("case");
    let status = Command::new(TRIMCTL)
        .args(["synth", "--seed", "5", "--pose-deg", "0", "--pose-mm", "0"])
        .args(["--out"])
        .arg(&case)
        .status()
        .expect("trimctl synth runs");
    assert!(status.success());
    let e = fixture();
    let scan = read_points(&case.join("scan.ply"))
        .unwrap()
        .transformed(&e)
        .unwrap();
    write_ply(
        &dir.join("scan_posed.ply"),
        &scan,
        PlyEncoding::BinaryLittleEndian,
    )
    .unwrap();
    let truth = read_path(&case.join("truth.csv"))
        .unwrap()
        .transformed(&e)
        .unwrap();
    trim_geom::formats::write_path(&dir.join("truth_posed.csv"), &truth).unwrap();
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(case.join("case.json")).unwrap()).unwrap();
    let s: Vec<f64> = info["scanner_in_scan_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let scanner = e * Point3::new(s[0], s[1], s[2]);
    format!(
        "[part]\ncad = \"case/cad_points.ply\"\npath = \"case/path.csv\"\nscan = \"scan_posed.ply\"\n\n[register]\nscanner_viewpoint_mm = [{}, {}, {}]\n",
        scanner.x, scanner.y, scanner.z
    )
}

fn with_pose(job: &str, rotation: &str, translation: &str) -> String {
    job.replace(
        "\n[register]",
        &format!(
            "\n[part.scan_from_cad]\nrotation_deg = {rotation}\ntranslation_mm = {translation}\n\n[register]"
        ),
    )
}

fn run(job: &Path, out: &Path) -> std::process::Output {
    Command::new(TRIMCTL)
        .arg("run")
        .arg(job)
        // The test is about where registration starts; a contour the cautious bound flags
        // (issue 21) is left out of the plan rather than stopping the run.
        .args(["--dry-run", "--skip-untrusted", "--out"])
        .arg(out)
        .output()
        .expect("trimctl run runs")
}

#[test]
fn run_and_register_start_from_the_fixture_pose_and_refuse_a_part_beyond_the_range() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let job = posed_case(dir);
    let job_with = dir.join("with.toml");
    std::fs::write(
        &job_with,
        with_pose(
            &job,
            &format!("{ROTATION_DEG:?}"),
            &format!("{TRANSLATION_MM:?}"),
        ),
    )
    .unwrap();
    let job_without = dir.join("without.toml");
    std::fs::write(&job_without, &job).unwrap();
    let truth = read_path(&dir.join("truth_posed.csv")).unwrap();

    // With the key, `run` registers the part where the fixture holds it.
    let out = dir.join("run_with");
    let r = run(&job_with, &out);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("registration.json")).unwrap())
            .unwrap();
    let global = &report["global"];
    let h = fixture().to_homogeneous();
    for i in 0..4 {
        for j in 0..4 {
            let got = global["initial_scan_from_cad"][i][j].as_f64().unwrap();
            assert!(
                (got - h[(i, j)]).abs() < 1e-12,
                "({i},{j}): {got} vs {}",
                h[(i, j)]
            );
        }
    }
    let offset_deg = global["fixture_offset"]["rotation_deg"].as_f64().unwrap();
    let offset_mm = global["fixture_offset"]["translation_mm"].as_f64().unwrap();
    assert!(offset_deg < 0.3 && offset_mm < 0.5, "{global}");
    let registered = read_path(&out.join("registered.csv")).unwrap();
    let e = path_errors(&registered, &truth, |_| true).unwrap();
    assert!(
        e.cross_edge_p95_mm <= CROSS_EDGE_P95_MM && e.cross_edge_max_mm <= CROSS_EDGE_MAX_MM,
        "{e:?}"
    );

    // Without it, the part is 35° and 32 mm from the identity: refused, naming the key.
    let r = run(&job_without, &dir.join("run_without"));
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("beyond the capture range") && stderr.contains("[part.scan_from_cad]"),
        "{stderr}"
    );

    // `register --config` takes the key too; `--initial` overrides it.
    let register = |extra: &[&std::ffi::OsStr]| {
        Command::new(TRIMCTL)
            .arg("register")
            .arg("--cad")
            .arg(dir.join("case/cad_points.ply"))
            .arg("--scan")
            .arg(dir.join("scan_posed.ply"))
            .arg("--path")
            .arg(dir.join("case/path.csv"))
            .arg("--out")
            .arg(dir.join("registered.csv"))
            .args(extra)
            .output()
            .expect("trimctl register runs")
    };
    let r = register(&["--config".as_ref(), job_with.as_os_str()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let e = path_errors(
        &read_path(&dir.join("registered.csv")).unwrap(),
        &truth,
        |_| true,
    )
    .unwrap();
    assert!(e.cross_edge_p95_mm <= CROSS_EDGE_P95_MM, "{e:?}");
    let identity = dir.join("identity.txt");
    std::fs::write(&identity, "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let r = register(&[
        "--config".as_ref(),
        job_with.as_os_str(),
        "--initial".as_ref(),
        identity.as_os_str(),
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("beyond the capture range"));
}

#[test]
fn a_bad_pose_is_refused_naming_the_key_or_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    for (rotation, translation, key) in [
        (
            "[nan, 0.0, 0.0]",
            "[0.0, 0.0, 0.0]",
            "part.scan_from_cad.rotation_deg",
        ),
        (
            "[0.0, 0.0, 0.0]",
            "[0.0, inf, 0.0]",
            "part.scan_from_cad.translation_mm",
        ),
        (
            "[0.0, 0.0]",
            "[0.0, 0.0, 0.0]",
            "part.scan_from_cad.rotation_deg",
        ),
    ] {
        let job = dir.join("bad.toml");
        std::fs::write(
            &job,
            format!(
                "[part.scan_from_cad]\nrotation_deg = {rotation}\ntranslation_mm = {translation}\n"
            ),
        )
        .unwrap();
        let r = run(&job, &dir.join("run"));
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{stderr}");
        let lines: Vec<&str> = stderr
            .lines()
            .filter(|l| l.starts_with("trimctl: error"))
            .collect();
        assert!(
            lines.len() == 1 && lines[0].contains(key),
            "{rotation} {translation}: {stderr}"
        );
    }
    // --initial: a matrix that is not a rotation (a shear), and a NaN.
    for (matrix, says) in [
        (
            "1 0.5 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
            "not a scaled rotation",
        ),
        (
            "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
            "not a finite number",
        ),
    ] {
        let file = dir.join("initial.txt");
        std::fs::write(&file, matrix).unwrap();
        let r = Command::new(TRIMCTL)
            .args([
                "register", "--cad", "c.stl", "--scan", "s.ply", "--path", "p.csv",
            ])
            .args(["--out", "o.csv", "--initial"])
            .arg(&file)
            .current_dir(dir)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains("--initial") && stderr.contains("initial.txt") && stderr.contains(says),
            "{stderr}"
        );
    }
}
