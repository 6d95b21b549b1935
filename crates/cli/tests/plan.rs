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

    // plan (the same contours and the demo's hatch tracks): the same zones, written and listed,
    // exit 1.
    let plan_json = tmp.path().join("job.json");
    let plan_svg = tmp.path().join("job.svg");
    let out = Command::new(TRIMCTL)
        .arg("plan")
        .arg("--path")
        .arg(run_dir.join("registered.csv"))
        .arg("--hatch")
        .arg(run_dir.join("hatch_0.csv"))
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

/// Writes the synthetic core's path and three straight hatch tracks above its middle.
fn path_and_tracks(
    dir: &std::path::Path,
    negative_id: bool,
) -> (std::path::PathBuf, std::path::PathBuf) {
    let mut path = trim_synth::testing::synthetic_core_path(20, 5);
    if negative_id {
        let mut contours = path.contours().to_vec();
        let c = &contours[0];
        contours[0] =
            trim_geom::Contour::with_features(-7, c.points().to_vec(), c.features().to_vec())
                .expect("contour");
        path = trim_geom::Path::new(contours).expect("path");
    }
    let z = path.contours()[0].points()[0].z;
    let tracks = (0..3)
        .map(|t| {
            let y = 0.5 * f64::from(t);
            trim_geom::Contour::new(
                t.into(),
                (0..=20)
                    .map(|i| trim_geom::Point3::new(-5.0 + 0.5 * f64::from(i), y, z))
                    .collect(),
                trim_geom::Vector3::z(),
            )
            .expect("track")
        })
        .collect();
    let path_csv = dir.join("path.csv");
    let tracks_csv = dir.join("tracks.csv");
    trim_geom::formats::write_path(&path_csv, &path).expect("path CSV");
    trim_geom::formats::write_path(&tracks_csv, &trim_geom::Path::new(tracks).expect("tracks"))
        .expect("tracks CSV");
    (path_csv, tracks_csv)
}

/// `trimctl plan --path PATH --hatch TRACKS --out JOB`.
fn plan_with_hatch(
    path: &std::path::Path,
    tracks: &std::path::Path,
    job: &std::path::Path,
) -> std::process::Output {
    Command::new(TRIMCTL)
        .arg("plan")
        .arg("--path")
        .arg(path)
        .arg("--hatch")
        .arg(tracks)
        .arg("--out")
        .arg(job)
        .output()
        .expect("trimctl runs")
}

#[test]
fn plan_takes_hatch_tracks_beside_the_contours() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let (path, tracks) = path_and_tracks(tmp.path(), false);
    let job = tmp.path().join("job.json");
    let out = plan_with_hatch(&path, &tracks, &job);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&job).expect("job")).expect("JSON");
    let mut ids: Vec<i64> = plan["zones"]
        .as_array()
        .expect("zones")
        .iter()
        .flat_map(|z| z["contours"].as_array().expect("contours").clone())
        .map(|v| v.as_i64().expect("id"))
        .filter(|id| *id < 0)
        .collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(
        ids,
        vec![-3, -2, -1],
        "track t of the first file is −(1 + t)"
    );

    // A path that already uses negative ids would collide: refused, naming the file.
    let (path, tracks) = path_and_tracks(tmp.path(), true);
    let out = plan_with_hatch(&path, &tracks, &job);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("path.csv") && stderr.contains("-7"),
        "{stderr}"
    );
}
