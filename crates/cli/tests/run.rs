//! `trimctl run` end to end: the demo part on the simulated cell leaves a complete run folder;
//! a run killed midway resumes without marking any layer twice; bad job files are refused with
//! one line naming the key.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// How long the demo may take in a debug build on a loaded 2-core machine before the test
/// gives up (not a performance check: a hang guard).
const RUN_TIMEOUT: Duration = Duration::from_secs(600);

fn journal_entries(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("journal.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// (zone, layer) → how many times the journal says the layer was finished.
fn layers_done(dir: &Path) -> BTreeMap<(u64, u64), usize> {
    let mut done = BTreeMap::new();
    for e in journal_entries(dir) {
        if e["kind"] == "layer_done" {
            let key = (
                e["key"]["zone"].as_u64().expect("journal key has a zone"),
                e["key"]["layer"].as_u64().expect("journal key has a layer"),
            );
            *done.entry(key).or_insert(0) += 1;
        }
    }
    done
}

fn planned_layers(dir: &Path) -> Vec<(u64, u64)> {
    let text = std::fs::read_to_string(dir.join("plan.json")).expect("plan.json is readable");
    let plan: serde_json::Value = serde_json::from_str(&text).expect("plan.json is JSON");
    let mut keys = Vec::new();
    for z in plan["zones"].as_array().expect("zones") {
        for l in z["layers"].as_array().expect("layers") {
            keys.push((
                z["id"].as_u64().expect("zone id"),
                l["index"].as_u64().expect("layer index"),
            ));
        }
    }
    keys
}

#[test]
fn demo_runs_to_the_end_and_leaves_a_complete_run_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let result = Command::new(TRIMCTL)
        .args(["run", "--sim-time-scale", "0.01", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        result.status.success(),
        "stdout:\n{stdout}\nstderr:\n{stderr}"
    );
    for expected in [
        "registration:",
        "zone  cluster  centre",
        "time estimate:",
        "executed:",
        "done:",
    ] {
        assert!(
            stdout.contains(expected),
            "{expected:?} missing from:\n{stdout}"
        );
    }
    for file in [
        "job.toml",
        "registered.csv",
        "registration.json",
        "plan.json",
        "plan.svg",
        "journal.jsonl",
        "run.mcap",
        "report.md",
        "summary.json",
        "inputs/path.csv",
        "inputs/scan.ply",
    ] {
        let p = out.join(file);
        assert!(
            p.is_file() && p.metadata().unwrap().len() > 0,
            "{file} missing or empty"
        );
    }
    let done = layers_done(&out);
    let planned = planned_layers(&out);
    assert!(!planned.is_empty());
    for key in &planned {
        assert_eq!(
            done.get(key),
            Some(&1),
            "layer {key:?} finished {:?} times",
            done.get(key)
        );
    }
    let mcap = std::fs::read(out.join("run.mcap")).unwrap();
    assert_eq!(
        &mcap[..8],
        b"\x89MCAP0\r\n",
        "run.mcap starts with the MCAP magic"
    );
}

#[test]
fn killed_run_resumes_without_marking_a_layer_twice() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // Slow enough (real-time devices) that the kill lands midway.
    let mut child = Command::new(TRIMCTL)
        .args(["run", "--sim-time-scale", "1.0", "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if layers_done(&out).len() >= 2 {
            break;
        }
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the run ended ({status}) before it could be killed midway");
        }
        assert!(start.elapsed() < RUN_TIMEOUT, "no layer finished in time");
        std::thread::sleep(Duration::from_millis(50));
    }
    child.kill().unwrap(); // SIGKILL: no clean shutdown, as a crash or a power cut.
    child.wait().unwrap();
    let before = layers_done(&out);
    let planned = planned_layers(&out);
    assert!(
        before.len() < planned.len(),
        "the kill came after the last layer"
    );

    let result = Command::new(TRIMCTL)
        .args(["run", "--sim-time-scale", "0.01", "--resume"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "resume failed:\n{}\n{}",
        String::from_utf8_lossy(&result.stdout),
        String::from_utf8_lossy(&result.stderr)
    );
    let after = layers_done(&out);
    for key in &planned {
        assert_eq!(
            after.get(key),
            Some(&1),
            "layer {key:?} finished {:?} times",
            after.get(key)
        );
    }
}

#[test]
fn bad_job_files_get_one_line_naming_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let cases = [
        ("[beam]\npowr_w = 10\n", "powr_w"),
        (
            "[galvo]\nmark_speed_mm_per_s = -1\n",
            "galvo.mark_speed_mm_per_s",
        ),
        ("max_incidence_deg = 90\n", "max_incidence_deg"),
        ("[zoning]\nk = 0\n", "zoning.k"),
        ("[register]\nmode = \"sideways\"\n", "mode"),
        ("[cell]\ncnc = \"not an address\"\n", "cell.cnc"),
        ("[part]\ncad = \"missing.stl\"\n", "part"),
        ("[beam\n", "line 1"),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let job = tmp.path().join(format!("job{i}.toml"));
        std::fs::write(&job, text).unwrap();
        let result = Command::new(TRIMCTL)
            .arg("run")
            .arg(&job)
            .arg("--out")
            .arg(tmp.path().join(format!("run{i}")))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(1), "{text:?}: {stderr}");
        let lines: Vec<&str> = stderr
            .lines()
            .filter(|l| l.starts_with("trimctl: error"))
            .collect();
        assert_eq!(lines.len(), 1, "{text:?}: {stderr}");
        assert!(
            lines[0].contains(key),
            "{text:?}: {:?} does not name {key}",
            lines[0]
        );
        assert!(
            !tmp.path().join(format!("run{i}")).exists(),
            "{text:?}: a refused job must not create a run folder"
        );
    }
}
