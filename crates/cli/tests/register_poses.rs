//! `trimctl register --scan A --scan B --poses poses.csv`: a scanner fixed to the machine sees
//! one side of the part at each machine pose. The two scans, each carried into the work-piece
//! frame through the cell at its own pose, register as the whole scan does; one side alone
//! leaves the other side's contours without data. Two scans without poses, and a scan the poses
//! file does not name, are refused naming what is missing. `trimctl run` takes the same scans
//! as job.toml's `[part] scans` and `poses`.

#![expect(
    clippy::unwrap_used,
    reason = "test code: a failure should stop loudly"
)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use trim_cell::cell_model::ScanPose;
use trim_geom::formats::{read_path, read_points};
use trim_geom::{Point3, PointCloud};

#[path = "support/scans_at_poses.rs"]
mod scans_at_poses;
use scans_at_poses::{split_by_side, write_scans_at_poses};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// The merged scans' registered path lies within this of the whole scan's, point by point, µm:
/// the same points, in another order (which point of a voxel the field takes changes).
const SAME_PATH_UM: f64 = 2.0;
/// One side's scan alone leaves at least this many more contours untrusted.
const MORE_FLAGGED_ONE_SIDE: usize = 5;

fn register(scans: &[&Path], poses: Option<&Path>, out: &Path) -> Output {
    let case = out.parent().unwrap().join("case");
    let mut cmd = Command::new(TRIMCTL);
    cmd.arg("register")
        .arg("--cad")
        .arg(case.join("cad.stl"))
        .arg("--path")
        .arg(case.join("path.csv"))
        .arg("--out")
        .arg(out.with_extension("csv"))
        .arg("--report")
        .arg(out);
    for s in scans {
        cmd.arg("--scan").arg(s);
    }
    if let Some(p) = poses {
        cmd.arg("--poses").arg(p);
    }
    cmd.output().unwrap()
}

fn report(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap()
}

fn untrusted(report: &serde_json::Value) -> usize {
    report["contours"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| !c["trustworthy"].as_bool().unwrap())
        .count()
}

/// The test part (seed 5, three views fixed to the cell as the demo's: two from the top, one
/// from below) written to `dir/case` and registered on its whole scan; the report's path.
fn register_whole_case(dir: &Path) -> PathBuf {
    let case = dir.join("case");
    let status = Command::new(TRIMCTL)
        .args([
            "synth",
            "--seed",
            "5",
            "--views",
            "3",
            "--scan-points",
            "150000",
            "--out",
        ])
        .arg(&case)
        .status()
        .unwrap();
    assert!(status.success());
    let whole = dir.join("whole.json");
    let out = register(&[&case.join("scan.ply")], None, &whole);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    whole
}

/// The whole scan of `dir/case`, and its points split by the side of the part they lie on
/// (`split_by_side`).
fn sides_at(dir: &Path, poses: [ScanPose; 2]) -> (PointCloud, Vec<(ScanPose, Vec<Point3>)>) {
    let scan = read_points(&dir.join("case").join("scan.ply")).unwrap();
    let parts = split_by_side(&scan, poses);
    (scan, parts)
}

/// The registered paths in `a` and `b` hold the same contours and points, each within
/// [`SAME_PATH_UM`].
fn assert_same_path(a: &Path, b: &Path) {
    let (pa, pb) = (read_path(a).unwrap(), read_path(b).unwrap());
    assert_eq!(pa.contours().len(), pb.contours().len());
    let mut worst_um = 0.0_f64;
    for (ca, cb) in pa.contours().iter().zip(pb.contours()) {
        assert_eq!(ca.id(), cb.id());
        assert_eq!(ca.points().len(), cb.points().len());
        for (p, q) in ca.points().iter().zip(cb.points()) {
            worst_um = worst_um.max((p - q).norm() * 1e3);
        }
    }
    assert!(worst_um <= SAME_PATH_UM, "{worst_um:.2} µm apart");
}

#[test]
fn two_scans_at_two_machine_poses_register_as_the_whole_scan() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = register_whole_case(tmp.path());
    // Each side as the scanner saw it at its own machine pose through the nominal cell.
    let (_, parts) = sides_at(
        tmp.path(),
        [
            ScanPose {
                xyz_mm: [5.0, -3.0, 20.0],
                tilt_deg: 0.0,
                c_deg: 0.0,
            },
            ScanPose {
                xyz_mm: [-12.0, 8.0, 35.0],
                tilt_deg: -25.0,
                c_deg: 140.0,
            },
        ],
    );
    let (files, poses_file) = write_scans_at_poses(tmp.path(), "pose", &parts);
    let refs: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();

    // Merged: the whole scan's registration.
    let merged = tmp.path().join("merged.json");
    let out = register(&refs, Some(&poses_file), &merged);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (a, b) = (report(&whole), report(&merged));
    assert!(b["global"]["refused"].is_null(), "{}", b["global"]);
    assert_eq!(untrusted(&a), untrusted(&b));
    assert_same_path(&whole.with_extension("csv"), &merged.with_extension("csv"));

    // One side alone: the other side's contours lose their data, and are flagged (measured:
    // 10 of 52 untrusted against none with both sides).
    let top = tmp.path().join("top.json");
    let out = register(&refs[..1], Some(&poses_file), &top);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let top = report(&top);
    assert!(
        untrusted(&top) >= untrusted(&a) + MORE_FLAGGED_ONE_SIDE,
        "one side: {} untrusted, whole scan {}",
        untrusted(&top),
        untrusted(&a)
    );

    // Two scans need their poses; every scan needs its row.
    let out = register(&refs, None, &tmp.path().join("no_poses.json"));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2 scans without --poses"), "{err}");
    let csv = std::fs::read_to_string(&poses_file).unwrap();
    std::fs::write(
        &poses_file,
        csv.lines().take(2).collect::<Vec<_>>().join("\n"),
    )
    .unwrap();
    let out = register(&refs, Some(&poses_file), &tmp.path().join("one_pose.json"));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no pose for scan pose1.ply"), "{err}");
}

/// `trimctl run` on a job naming its own files, its part scanned as `[part] scans` at the
/// machine poses of `[part] poses`: the run registers on the merged cloud, as `register` does
/// on the whole scan, through the built-in simulated cell to the end. A scan without a row is
/// refused naming it, before anything moves.
#[test]
fn run_registers_a_part_scanned_at_two_machine_poses_from_the_merged_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = register_whole_case(tmp.path());
    // The two sides, each as the scanner saw it at its pose, in a folder of their own.
    let (scan, parts) = sides_at(
        tmp.path(),
        [
            ScanPose {
                xyz_mm: [-4.0, 6.0, 25.0],
                tilt_deg: 10.0,
                c_deg: -30.0,
            },
            ScanPose {
                xyz_mm: [9.0, -2.0, 40.0],
                tilt_deg: -35.0,
                c_deg: 215.0,
            },
        ],
    );
    let scans = tmp.path().join("scans");
    std::fs::create_dir_all(&scans).unwrap();
    let (files, poses_file) = write_scans_at_poses(&scans, "side", &parts);
    assert!(files.iter().all(|f| f.starts_with(&scans)));
    assert_eq!(poses_file, scans.join("poses.csv"));
    // Relative to the job file, as every [part] file.
    let job = tmp.path().join("job.toml");
    let part = "[part]\ncad = \"case/cad.stl\"\npath = \"case/path.csv\"\n";
    std::fs::write(
        &job,
        format!("{part}scans = [\"scans/side0.ply\", \"scans/side1.ply\"]\nposes = \"scans/poses.csv\"\n"),
    )
    .unwrap();
    let run_dir = tmp.path().join("run");
    let out = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .args(["--sim-time-scale", "0.01", "--out"])
        .arg(&run_dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "stdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("scans ")
            && stdout.contains("side0.ply")
            && stdout.contains("side1.ply")
            && stdout.contains("poses.csv")
            && stdout.contains(&format!("({} points)", scan.len())),
        "{stdout}"
    );
    assert!(stdout.contains("done:"), "{stdout}");

    // The run's registration is the whole scan's.
    let (a, b) = (report(&whole), report(&run_dir.join("registration.json")));
    assert!(b["global"]["refused"].is_null(), "{}", b["global"]);
    assert_eq!(untrusted(&a), untrusted(&b));
    assert_same_path(
        &whole.with_extension("csv"),
        &run_dir.join("registered.csv"),
    );

    // The record's /calibration says where each scan was taken (the MCAP is uncompressed).
    let record = std::fs::read(run_dir.join("run.mcap")).unwrap();
    let holds = |text: &str| record.windows(text.len()).any(|w| w == text.as_bytes());
    assert!(
        holds("\"scan_poses\"") && holds("side1.ply") && holds("\"c_deg\":215.0"),
        "no scan poses in /calibration"
    );

    // The run folder's job names the scans and poses absolutely, so it resumes from anywhere.
    let effective = std::fs::read_to_string(run_dir.join("job.toml")).unwrap();
    let effective: toml::Table = toml::from_str(&effective).unwrap();
    let named = effective["part"]["scans"].as_array().unwrap();
    assert_eq!(named.len(), 2);
    for (n, f) in named.iter().zip(&files) {
        assert!(Path::new(n.as_str().unwrap()).is_absolute(), "{n}");
        assert_eq!(
            std::fs::canonicalize(n.as_str().unwrap()).unwrap(),
            std::fs::canonicalize(f).unwrap()
        );
    }
    assert!(Path::new(effective["part"]["poses"].as_str().unwrap()).is_absolute());

    // A scan the poses file has no row for is refused naming it, before anything moves.
    std::fs::copy(&files[1], scans.join("side2.ply")).unwrap();
    std::fs::write(
        &job,
        format!("{part}scans = [\"scans/side0.ply\", \"scans/side2.ply\"]\nposes = \"scans/poses.csv\"\n"),
    )
    .unwrap();
    let refused_dir = tmp.path().join("refused");
    let out = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .args(["--sim-time-scale", "0.01", "--out"])
        .arg(&refused_dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("part.scans") && err.contains("no pose for scan side2.ply"),
        "{err}"
    );
    assert!(!refused_dir.join("journal.jsonl").exists());
}
