//! `trimctl plan` and `run` on a part with zones outside the axis limits: the plan and its SVG
//! are written with those zones marked, the command exits with the bad-input code, and `run`
//! refuses the plan even with `--allow-invalid`.

use std::process::Command;

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// The demo part on a cell whose A axis travels ±5°: the zones tilted further are unreachable.
const NARROW_A: &str = "[machine]\na_limits_deg = [-5.0, 5.0]\n";

fn unreachable_ids(plan_json: &std::path::Path) -> Vec<u64> {
    let text = std::fs::read_to_string(plan_json).expect("the plan is written");
    let plan: serde_json::Value = serde_json::from_str(&text).expect("the plan is JSON");
    let zones = plan["zones"].as_array().expect("zones");
    let marked: Vec<u64> = zones
        .iter()
        .filter(|z| z["unreachable"].is_string())
        .map(|z| z["id"].as_u64().expect("zone id"))
        .collect();
    let listed: Vec<u64> = plan["validation"]["unreachable_zones"]
        .as_array()
        .expect("validation lists the unreachable zones")
        .iter()
        .map(|v| v.as_u64().expect("zone id"))
        .collect();
    assert_eq!(marked, listed);
    assert_eq!(plan["validation"]["passed"], false);
    assert!(
        marked.len() < zones.len(),
        "the ±5° cell reaches some zones"
    );
    marked
}

#[test]
fn unreachable_zones_are_written_marked_and_run_refuses_them() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, NARROW_A).expect("job.toml");

    // run: plans, writes the plan and its SVG into the run folder, refuses to start.
    let run_dir = tmp.path().join("run");
    let out = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .arg("--out")
        .arg(&run_dir)
        .arg("--allow-invalid")
        .output()
        .expect("trimctl runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("cannot be reached within the axis limits"),
        "{stderr}"
    );
    let from_run = unreachable_ids(&run_dir.join("plan.json"));
    assert!(!from_run.is_empty());
    let svg = std::fs::read_to_string(run_dir.join("plan.svg")).expect("plan.svg");
    assert_eq!(svg.matches(">UNREACHABLE<").count(), from_run.len());
    assert!(
        !run_dir.join("journal.jsonl").exists(),
        "nothing may start on a plan with unreachable zones"
    );

    // plan: the same zones, written and listed, exit 1.
    let plan_json = tmp.path().join("job.json");
    let plan_svg = tmp.path().join("job.svg");
    let out = Command::new(TRIMCTL)
        .arg("plan")
        .arg("--path")
        .arg(run_dir.join("registered.csv"))
        .arg("--config")
        .arg(&job)
        .arg("--out")
        .arg(&plan_json)
        .arg("--svg")
        .arg(&plan_svg)
        .output()
        .expect("trimctl runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert_eq!(unreachable_ids(&plan_json), from_run);
    assert!(stderr.contains("unreachable zones"), "{stderr}");
    assert!(
        stdout.contains("UNREACHABLE within the axis limits"),
        "{stdout}"
    );
    let svg = std::fs::read_to_string(&plan_svg).expect("the SVG is written");
    assert_eq!(svg.matches(">UNREACHABLE<").count(), from_run.len());
}
