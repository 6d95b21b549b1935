//! `trimctl run --verify` on a part of the job's own files (issue 23): the rescan comes from
//! the cell's scanner, here a `[verify] scan_command` that delivers a scan of the part as it
//! stands after trimming (the same synthetic core, `trimctl synth` seed 2, scanned without its
//! burrs), or a file the run waits for, with a timeout.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// `trimctl synth --seed 2` (four views, no dropouts) with `burrs` of its contours burred, into
/// `dir`.
fn synth(dir: &Path, burrs: &str) {
    let result = Command::new(TRIMCTL)
        .args([
            "synth",
            "--seed",
            "2",
            "--views",
            "4",
            "--dropouts",
            "0",
            "--burrs",
            burrs,
        ])
        .arg("--out")
        .arg(dir)
        .output()
        .expect("trimctl synth runs");
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
}

/// A job of the burred core's files plus `verify` (the `[verify]` table's body).
fn job(tmp: &Path, verify: &str) -> PathBuf {
    let core = tmp.join("burred");
    let job = tmp.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "[part]\ncad = {:?}\npath = {:?}\nscan = {:?}\n\n[verify]\n{verify}",
            core.join("cad.stl"),
            core.join("path.csv"),
            core.join("scan.ply")
        ),
    )
    .expect("job file");
    job
}

/// `trimctl run JOB --verify --rounds 1` on the simulated cell: exit code, stdout, stderr.
fn run(job: &Path, out: &Path) -> (Option<i32>, String, String) {
    let result = Command::new(TRIMCTL)
        .arg("run")
        .arg(job)
        .args([
            "--verify",
            "--rounds",
            "1",
            "--sim-time-scale",
            "0.01",
            "--out",
        ])
        .arg(out)
        .output()
        .expect("trimctl run runs");
    (
        result.status.code(),
        String::from_utf8_lossy(&result.stdout).into_owned(),
        String::from_utf8_lossy(&result.stderr).into_owned(),
    )
}

#[test]
fn a_real_parts_rescan_comes_from_the_scan_command_and_is_inspected_without_a_truth() {
    let tmp = tempfile::tempdir().expect("tempdir");
    synth(&tmp.path().join("burred"), "0.3");
    synth(&tmp.path().join("clean"), "0");
    let clean_scan = tmp.path().join("clean").join("scan.ply");
    let job = job(
        tmp.path(),
        &format!("scan_command = [\"cp\", {clean_scan:?}, \"{{scan}}\"]\nscan_timeout_s = 60\n"),
    );
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run(&job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    // The command ran with {scan} filled in, and wrote the round's file in the run folder.
    assert!(
        stdout.contains("verify 1: rescanning the part: cp"),
        "{stdout}"
    );
    assert!(out.join("rescan_1.ply").exists());
    let rounds: Vec<Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("verify.json")).unwrap()).unwrap();
    assert_eq!(rounds.len(), 1, "{rounds:?}");
    let first = &rounds[0];
    // The part as delivered carries no burr: nothing fails, and there is no truth to report.
    assert_eq!(first["fail"], 0, "{first}");
    assert!(first["pass"].as_u64().unwrap() >= 40, "{first}");
    for key in ["true_residual_max_um", "true_gouge_p95_um"] {
        assert!(first[key].is_null(), "{key}: {first}");
    }
    let inspection: Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("verify_1").join("inspection.json")).unwrap(),
    )
    .unwrap();
    assert!(inspection["contours"].as_array().unwrap().len() >= 40);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Verify and retrim"), "{report}");
}

#[test]
fn a_rescan_that_never_comes_stops_the_run_at_the_timeout_naming_the_file() {
    let tmp = tempfile::tempdir().expect("tempdir");
    synth(&tmp.path().join("burred"), "0.3");
    let job = job(tmp.path(), "scan_timeout_s = 1\n");
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run(&job, &out);
    assert_eq!(code, Some(1), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stdout.contains("verify 1: waiting for the rescan of the part at"),
        "{stdout}"
    );
    assert!(
        stderr.contains("timed out after 1.0 s waiting for") && stderr.contains("rescan_1.ply"),
        "{stderr}"
    );
    // The job itself ran and was journaled before the wait.
    assert!(out.join("journal.jsonl").exists());
}
