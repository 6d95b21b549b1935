//! Detect before trimming and the skipped layer, at the CLI (issue 23): `[trim] only_detected`
//! plans only what the first scan's inspection finds, with passes from the measured height; and
//! a layer whose beam the simulated cell blocks on purpose (`--sim-block-beam`) leaves its
//! contours' burrs standing, which `--verify`'s inspection fails and its retrim fixes.
//!
//! The first two run the built-in demo part (seed 1, burrs on 30 % of its 52 contours) on the
//! built-in simulated cell, in a debug build; the third a job of `trimctl synth`'s files, clean
//! (nothing to trim: nothing planned, nothing moved) and burred. The last two run `--verify` on
//! such a job (a real part to the run): its rescan comes from `[verify] scan_command`, or a
//! file the run waits for until its timeout.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

use serde_json::Value;
use trim_cell::cell_model::ScanPose;
use trim_geom::formats::read_points;

#[path = "support/scans_at_poses.rs"]
mod scans_at_poses;
use scans_at_poses::{split_by_side, write_scans_at_poses};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// The product's tolerance on residual web and gouge, µm (inspection's default).
const TOLERANCE_UM: f64 = 30.0;
/// `[process] depth_per_pass_um`'s default, µm.
const DEPTH_PER_PASS_UM: f64 = 40.0;
/// `[process]`'s most passes.
const MAX_PASSES: u64 = 20;
/// `min_coverage`'s default.
const MIN_COVERAGE: f64 = 0.9;

fn read_json(file: &Path) -> Value {
    let text = std::fs::read_to_string(file)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", file.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", file.display()))
}

/// `trimctl run JOB ARGS --out OUT` on the simulated cell: exit code, stdout, stderr.
fn trimctl(args: &[&str], job: &Path, out: &Path) -> (Option<i32>, String, String) {
    let result = Command::new(TRIMCTL)
        .arg("run")
        .arg(job)
        .args(args)
        .args(["--sim-time-scale", "0.01", "--out"])
        .arg(out)
        .output()
        .expect("trimctl runs");
    (
        result.status.code(),
        String::from_utf8_lossy(&result.stdout).into_owned(),
        String::from_utf8_lossy(&result.stderr).into_owned(),
    )
}

/// Contour id → the passes of its polylines (every polyline of a contour alike), over the
/// plan's layers; hatch tracks (negative ids) left out.
fn planned_passes(plan: &Value) -> BTreeMap<i64, BTreeSet<u64>> {
    let mut out: BTreeMap<i64, BTreeSet<u64>> = BTreeMap::new();
    for z in plan["zones"].as_array().expect("zones") {
        for l in z["layers"].as_array().expect("layers") {
            for p in l["polylines"].as_array().expect("polylines") {
                let id = p["contour"].as_i64().expect("contour id");
                if id >= 0 {
                    out.entry(id)
                        .or_default()
                        .insert(p["passes"].as_u64().unwrap_or(1));
                }
            }
        }
    }
    out
}

/// (zone, layer) → contour ids (hatch tracks left out), in plan order.
fn layers(plan: &Value) -> Vec<((u64, u64), BTreeSet<i64>)> {
    let mut out = Vec::new();
    for z in plan["zones"].as_array().expect("zones") {
        for l in z["layers"].as_array().expect("layers") {
            let ids = l["polylines"]
                .as_array()
                .expect("polylines")
                .iter()
                .map(|p| p["contour"].as_i64().expect("contour id"))
                .filter(|id| *id >= 0)
                .collect();
            out.push((
                (
                    z["id"].as_u64().expect("zone id"),
                    l["index"].as_u64().expect("layer index"),
                ),
                ids,
            ));
        }
    }
    out
}

/// The inspection's contours by id.
fn inspection(dir: &Path) -> BTreeMap<i64, Value> {
    read_json(&dir.join("inspection.json"))["contours"]
        .as_array()
        .expect("contours")
        .iter()
        .map(|c| (c["id"].as_i64().expect("id"), c.clone()))
        .collect()
}

fn num(c: &Value, key: &str) -> f64 {
    c[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing: {c}"))
}

/// The ids whose first-scan inspection fails on excess: excess − U > tolerance (computed here
/// from inspection.json, independently of the run's own calls).
fn burrs_seen(first: &BTreeMap<i64, Value>) -> BTreeSet<i64> {
    first
        .iter()
        .filter(|(_, c)| num(c, "excess_height_um") - num(c, "uncertainty_um") > TOLERANCE_UM)
        .map(|(id, _)| *id)
        .collect()
}

#[test]
fn only_detected_trims_the_burred_contours_with_passes_from_their_height_and_skips_the_clean() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "[trim]\nonly_detected = true\n").expect("job file");
    let full_job = tmp.path().join("full.toml");
    std::fs::write(&full_job, "").expect("job file");

    // The full job (the default: every contour, one pass), planned only.
    let full = tmp.path().join("full");
    let (ok, stdout, stderr) = trimctl(&["--dry-run"], &full_job, &full);
    assert_eq!(ok, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    let full_contours = planned_passes(&read_json(&full.join("plan.json")));
    assert!(
        full_contours.values().all(|p| p == &BTreeSet::from([1])),
        "{full_contours:?}"
    );
    assert!(!full.join("detect").exists());

    // A job whose CAD is a point cloud cannot be inspected: refused before registration,
    // naming the key, nothing planned or moved.
    let inputs = full.join("inputs");
    let cloud_job = tmp.path().join("cloud.toml");
    std::fs::write(
        &cloud_job,
        format!(
            "[trim]\nonly_detected = true\n[part]\ncad = {:?}\npath = {:?}\nscan = {:?}\n",
            inputs.join("cad_points.ply"),
            inputs.join("path.csv"),
            inputs.join("scan.ply")
        ),
    )
    .expect("job file");
    let refused = tmp.path().join("refused");
    let (code, _, stderr) = trimctl(&[], &cloud_job, &refused);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("part.cad")
            && stderr.contains("holds no mesh")
            && stderr.contains("trim.only_detected"),
        "{stderr}"
    );
    assert!(!refused.join("registration.json").exists());
    assert!(!refused.join("plan.json").exists() && !refused.join("journal.jsonl").exists());

    let out = tmp.path().join("detected");
    let (ok, stdout, stderr) = trimctl(&[], &job, &out);
    assert_eq!(ok, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("detect: "), "{stdout}");
    let first = inspection(&out.join("detect"));
    assert_eq!(first.len(), full_contours.len(), "one call per contour");
    let plan = read_json(&out.join("plan.json"));
    let planned = planned_passes(&plan);
    let burrs = burrs_seen(&first);
    eprintln!(
        "full job: {} contours; only_detected: {} planned, {} failing on excess in the first scan",
        full_contours.len(),
        planned.len(),
        burrs.len()
    );
    assert!(!burrs.is_empty());
    assert!(
        planned.len() < full_contours.len(),
        "{} of {} planned",
        planned.len(),
        full_contours.len()
    );
    for (id, c) in &first {
        let (h, u, coverage) = (
            num(c, "excess_height_um"),
            num(c, "uncertainty_um"),
            num(c, "coverage"),
        );
        if burrs.contains(id) {
            // Every detected burr is planned, each polyline with ⌈h / 40 µm⌉ passes (≤ 20).
            let want = ((h / DEPTH_PER_PASS_UM - 1e-9).ceil() as u64).clamp(1, MAX_PASSES);
            assert_eq!(
                planned.get(id),
                Some(&BTreeSet::from([want])),
                "burr on contour {id} ({h:.0} µm)"
            );
        } else if coverage < MIN_COVERAGE {
            // Not covered enough to tell: trimmed too (and reported as such).
            assert!(
                planned.contains_key(id),
                "contour {id}: coverage {coverage}"
            );
        } else if h + u <= TOLERANCE_UM || h == 0.0 {
            // Clean (shown within the tolerance, or covered with no excess): not trimmed.
            assert!(!planned.contains_key(id), "clean contour {id} planned: {c}");
        }
    }
    // Every planned layer was marked (journaled done once), counting every pass.
    let mut done = BTreeMap::new();
    for line in std::fs::read_to_string(out.join("journal.jsonl"))
        .expect("journal")
        .lines()
    {
        let e: Value = serde_json::from_str(line).expect("journal line");
        if e["kind"] == "layer_done" {
            let key = (
                e["key"]["zone"].as_u64().expect("zone"),
                e["key"]["layer"].as_u64().expect("layer"),
            );
            assert!(
                done.insert(key, e["vectors"].as_u64().expect("vectors"))
                    .is_none(),
                "{key:?} done twice"
            );
        }
    }
    for z in plan["zones"].as_array().expect("zones") {
        for l in z["layers"].as_array().expect("layers") {
            let key = (
                z["id"].as_u64().expect("id"),
                l["index"].as_u64().expect("index"),
            );
            let vectors: u64 = l["polylines"]
                .as_array()
                .expect("polylines")
                .iter()
                .map(|p| {
                    let n = p["commands"]
                        .as_array()
                        .map_or_else(|| p["points"].as_array().expect("points").len(), Vec::len)
                        as u64;
                    (n - 1) * p["passes"].as_u64().unwrap_or(1)
                })
                .sum();
            assert_eq!(done.get(&key), Some(&vectors), "layer {key:?}");
        }
    }
    // The report and summary.json say what was detected, skipped and how many passes.
    let summary = read_json(&out.join("summary.json"));
    let calls = summary["detection"]["contours"]
        .as_array()
        .expect("detection.contours");
    assert_eq!(calls.len(), first.len());
    for c in calls {
        let id = c["id"].as_i64().expect("id");
        assert_eq!(
            c["trimmed"].as_bool().expect("trimmed"),
            planned.contains_key(&id),
            "{c}"
        );
        if let Some(p) = c["passes"].as_u64() {
            assert_eq!(planned[&id], BTreeSet::from([p]), "{c}");
        }
    }
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(
        report.contains("## Detection before trimming") && report.contains("Skipped as clean:"),
        "{report}"
    );
}

#[test]
fn a_layer_whose_beam_is_blocked_fails_its_burred_contours_and_the_retrim_fixes_them() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "[trim]\nonly_detected = true\n").expect("job file");

    // The plan, to choose the layer: the first holding the whole of a contour (no polyline of
    // it in another layer) with a burr of at least 100 µm seen on the first scan, which cannot
    // pass untrimmed.
    let dry = tmp.path().join("dry");
    let (ok, stdout, stderr) = trimctl(&["--dry-run"], &job, &dry);
    assert_eq!(ok, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    let first = inspection(&dry.join("detect"));
    let burrs = burrs_seen(&first);
    let tall: BTreeSet<i64> = burrs
        .iter()
        .copied()
        .filter(|id| num(&first[id], "excess_height_um") >= 100.0)
        .collect();
    let plan_layers = layers(&read_json(&dry.join("plan.json")));
    let only_in = |i: usize| -> BTreeSet<i64> {
        let others: BTreeSet<i64> = plan_layers
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .flat_map(|(_, (_, ids))| ids.iter().copied())
            .collect();
        plan_layers[i].1.difference(&others).copied().collect()
    };
    let (i, ((zone, layer), in_layer)) = plan_layers
        .iter()
        .enumerate()
        .find(|(i, _)| !only_in(*i).is_disjoint(&tall))
        .expect("a layer holding the whole of a contour with a tall burr");
    let (zone, layer, in_layer, whole) = (*zone, *layer, in_layer.clone(), only_in(i));
    let key = format!("{zone}:{layer}");

    let out = tmp.path().join("run");
    let (ok, stdout, stderr) = trimctl(&["--verify", "--sim-block-beam", &key], &job, &out);
    assert_eq!(ok, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("FAULT INJECTED"), "{stdout}");
    // The same plan (same seed, same registration), and the fault recorded.
    assert_eq!(layers(&read_json(&out.join("plan.json"))), plan_layers);
    let summary = read_json(&out.join("summary.json"));
    let fault = &summary["injected_fault"];
    // Every mark vector of the layer, every pass, and no other: what the journal says the
    // layer marked.
    let journaled = std::fs::read_to_string(out.join("journal.jsonl"))
        .expect("journal")
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).expect("journal line"))
        .find(|e| {
            e["kind"] == "layer_done" && e["key"]["zone"] == zone && e["key"]["layer"] == layer
        })
        .expect("the blocked layer journaled as done");
    assert!(journaled["vectors"].as_u64().expect("vectors") > 0);
    assert_eq!(fault["marks_blocked"], journaled["vectors"], "{fault}");
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(report.contains("## Injected fault"), "{report}");

    // The burred contours the blocked layer holds whole: none of their edge was trimmed.
    let skipped_burrs: BTreeSet<i64> = whole.intersection(&burrs).copied().collect();
    let rounds = read_json(&out.join("verify.json"));
    let rounds = rounds.as_array().expect("rounds");
    let failing = |r: &Value| -> BTreeSet<i64> {
        r["failing"]
            .as_array()
            .expect("failing")
            .iter()
            .map(|v| v.as_i64().expect("id"))
            .collect()
    };
    let f1 = failing(&rounds[0]);
    let clean: BTreeSet<i64> = first
        .iter()
        .filter(|(_, c)| {
            num(c, "excess_height_um") + num(c, "uncertainty_um") <= TOLERANCE_UM
                && num(c, "coverage") >= MIN_COVERAGE
        })
        .map(|(id, _)| *id)
        .collect();
    eprintln!(
        "blocked {key} (contours {in_layer:?}, burrs {skipped_burrs:?}); inspection 1 fails {f1:?} \
         ({} outside the layer); true residual after round 1 {:.1} µm; rounds {}",
        f1.difference(&in_layer).count(),
        num(&rounds[0], "true_residual_max_um"),
        rounds.len()
    );
    // 1. Every burr of the blocked layer still stands and fails the first rescan's inspection;
    //    the twin's truth agrees that a web taller than the tolerance stands.
    assert!(!skipped_burrs.is_empty());
    assert!(
        skipped_burrs.is_subset(&f1),
        "{skipped_burrs:?} not all in {f1:?}"
    );
    assert!(
        num(&rounds[0], "true_residual_max_um") > 100.0,
        "{:?}",
        rounds[0]
    );
    // 2. Nothing the first scan showed clean fails (it was not trimmed, so nothing changed
    //    there); a failure outside the blocked layer is a contour the first scan saw excess on
    //    or could not see whole (a web thicker than its height's passes cut, or hidden).
    assert!(
        f1.is_disjoint(&clean),
        "clean contours fail: {:?}",
        f1.intersection(&clean)
    );
    // 3. The retrim covers every failing contour.
    assert_eq!(rounds[0]["retrimmed"], true);
    let retrimmed = planned_passes(&read_json(&out.join("retrim_1/plan.json")));
    assert!(
        f1.iter().all(|id| retrimmed.contains_key(id)),
        "{f1:?} vs {:?}",
        retrimmed.keys()
    );
    // 4. The last inspection fails nothing and passes the blocked layer's burrs; the twin's
    //    truth: no web taller than the tolerance and no deeper gouge anywhere.
    let last = rounds.last().expect("a round");
    assert_eq!(last["fail"], 0, "{last}");
    let final_inspection = inspection(&out.join(format!(
        "verify_{}",
        last["inspection"].as_u64().expect("inspection")
    )));
    for id in &skipped_burrs {
        let c = &final_inspection[id];
        assert_eq!(c["verdict"], "pass", "contour {id}: {c}");
        assert!(
            num(c, "excess_height_um") + num(c, "uncertainty_um") <= TOLERANCE_UM,
            "{c}"
        );
    }
    assert!(num(last, "true_residual_max_um") <= TOLERANCE_UM, "{last}");
    assert!(num(last, "true_gouge_max_um") <= TOLERANCE_UM, "{last}");
}

/// A synthetic core (`trimctl synth`, seed 2, four views, no dropouts) with `burrs` of its
/// contours burred, in `dir/core`, as a job of its own files with `[trim] only_detected`.
fn synth_job(dir: &Path, burrs: &str) -> std::path::PathBuf {
    synth_job_with(dir, burrs, "[trim]\nonly_detected = true\n")
}

/// [`synth_job`] with `tables` (job.toml text) in place of `[trim] only_detected`.
fn synth_job_with(dir: &Path, burrs: &str, tables: &str) -> std::path::PathBuf {
    let core = dir.join("core");
    synth_core(&core, burrs, "0");
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "{tables}\n[part]\ncad = {:?}\npath = {:?}\nscan = {:?}\n",
            core.join("cad.stl"),
            core.join("path.csv"),
            core.join("scan.ply")
        ),
    )
    .expect("job file");
    job
}

/// `trimctl synth` of the test core (seed 2, four views) into `core`, with `burrs` of its
/// contours burred and `dropouts` dropout patches in its scan.
fn synth_core(core: &Path, burrs: &str, dropouts: &str) {
    let result = Command::new(TRIMCTL)
        .args([
            "synth",
            "--seed",
            "2",
            "--views",
            "4",
            "--dropouts",
            dropouts,
            "--burrs",
            burrs,
            "--out",
        ])
        .arg(core)
        .output()
        .expect("trimctl synth runs");
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
}

#[test]
fn a_part_with_nothing_detected_is_not_moved_and_the_report_says_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let clean_dir = tmp.path().join("clean");
    std::fs::create_dir_all(&clean_dir).expect("dir");
    let job = synth_job(&clean_dir, "0");
    let out = clean_dir.join("run");
    let (code, stdout, stderr) = trimctl(&[], &job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("nothing to trim:"), "{stdout}");
    // Nothing planned, nothing executed: no plan, no journal, no record.
    for file in ["plan.json", "journal.jsonl", "run.mcap"] {
        assert!(!out.join(file).exists(), "{file} written");
    }
    let summary = read_json(&out.join("summary.json"));
    assert!(summary["nothing_to_trim"].is_string(), "{summary}");
    let calls = summary["detection"]["contours"]
        .as_array()
        .expect("detection.contours");
    assert_eq!(calls.len(), 52);
    assert!(calls.iter().all(|c| c["trimmed"] == false), "{calls:?}");
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(report.contains("**Nothing to trim**"), "{report}");

    // The same core with burrs: the same job plans and trims them.
    let burred_dir = tmp.path().join("burred");
    std::fs::create_dir_all(&burred_dir).expect("dir");
    let job = synth_job(&burred_dir, "0.3");
    let out = burred_dir.join("run");
    let (code, stdout, stderr) = trimctl(&[], &job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(!stdout.contains("nothing to trim"), "{stdout}");
    let first = inspection(&out.join("detect"));
    let burrs = burrs_seen(&first);
    let planned = planned_passes(&read_json(&out.join("plan.json")));
    eprintln!(
        "clean core: nothing to trim; burred core: {} burrs seen, {} contours planned",
        burrs.len(),
        planned.len()
    );
    assert!(!burrs.is_empty());
    assert!(burrs.iter().all(|id| planned.contains_key(id)), "{burrs:?}");
    assert!(out.join("journal.jsonl").is_file());
}

#[test]
fn sim_block_beam_is_refused_on_a_real_galvo_for_a_layer_the_plan_lacks_and_when_malformed() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "").expect("job file");
    // Not ZONE:LAYER: a usage error.
    let (code, _, stderr) = trimctl(&["--sim-block-beam", "3-0"], &job, &tmp.path().join("a"));
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("expected ZONE:LAYER"), "{stderr}");
    // A layer the plan does not have: refused after planning, before anything moves.
    let out = tmp.path().join("b");
    let (code, _, stderr) = trimctl(&["--sim-block-beam", "999:0"], &job, &out);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("--sim-block-beam 999:0: the plan has no such layer"),
        "{stderr}"
    );
    assert!(out.join("plan.json").is_file() && !out.join("journal.jsonl").exists());
    // A real galvo (an address, nothing listening): no twin, refused before connecting.
    let out = tmp.path().join("c");
    let (code, _, stderr) = trimctl(
        &["--sim-block-beam", "0:0", "--galvo", "127.0.0.1:9"],
        &job,
        &out,
    );
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("--sim-block-beam: needs the digital twin"),
        "{stderr}"
    );
    assert!(!out.join("journal.jsonl").exists());
}

#[test]
fn only_detected_hatches_the_blocked_openings_in_the_job_itself_and_the_rescan_sees_them_cleared() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "[trim]\nonly_detected = true\n").expect("job file");
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = trimctl(
        &["--demo-blockages", "0.15", "--verify", "--rounds", "1"],
        &job,
        &out,
    );
    assert!(
        code == Some(0) || code == Some(1),
        "stdout:\n{stdout}\nstderr:\n{stderr}"
    );
    // The first scan's inspection found the films and the job itself hatched them.
    let summary = read_json(&out.join("summary.json"));
    let hatched: BTreeSet<i64> = summary["detection"]["blocked_hatched"]
        .as_array()
        .expect("detection.blocked_hatched")
        .iter()
        .map(|o| o["contour"].as_i64().expect("contour"))
        .collect();
    // Each hatched film's passes cut through its thickness: measured where the scan saw both
    // its sides (plus twice its uncertainty), else `[trim] film_thickness_um` (200 µm); the
    // record and report.md say which.
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    for o in summary["detection"]["blocked_hatched"]
        .as_array()
        .expect("detection.blocked_hatched")
    {
        let (t_um, passes) = (num(o, "film_thickness_um"), num(o, "passes"));
        match o["thickness_from"].as_str() {
            Some("measured") => {
                let u_um = num(o, "film_thickness_uncertainty_um");
                assert!((50.0 - 15.0..=200.0 + 15.0).contains(&t_um), "{o}");
                assert!(
                    (passes - ((t_um + 2.0 * u_um) / 40.0).ceil()).abs() < 0.5,
                    "{o}"
                );
            }
            Some("config") => {
                assert_eq!((t_um, passes), (200.0, 5.0), "{o}");
                assert!(o["film_thickness_uncertainty_um"].is_null(), "{o}");
            }
            _ => panic!("thickness_from missing: {o}"),
        }
        eprintln!(
            "contour {}: film {t_um:.1} µm ({}), {passes} passes",
            o["contour"], o["thickness_from"]
        );
    }
    assert!(
        report.contains("| film thickness (µm) | thickness from |"),
        "{report}"
    );
    let first = inspection(&out.join("detect"));
    let blocked: BTreeSet<i64> = first
        .iter()
        .filter(|(_, c)| c["blocked_fraction"].as_f64().is_some_and(|b| b > 0.1))
        .map(|(id, _)| *id)
        .collect();
    assert!(!blocked.is_empty(), "no blocked opening seen: {stdout}");
    assert!(
        blocked.is_subset(&hatched),
        "blocked {blocked:?}, hatched {hatched:?}"
    );
    // After the job (before any retrim) the rescan reads every hatched opening cleared.
    let after = inspection(&out.join("verify_1"));
    for id in &hatched {
        let c = &after[id];
        assert!(
            num(c, "blocked_fraction") <= 0.1,
            "contour {id} still covered after the job's hatching: {c}"
        );
    }
    let rounds = read_json(&out.join("verify.json"));
    let film = rounds[0]["true_film_covered_max"]
        .as_f64()
        .expect("film cover");
    assert!(
        film <= 0.05,
        "the twin's films still cover {film} of an opening"
    );
}

/// `trimctl run JOB --verify --rounds 1` on the simulated cell: exit code, stdout, stderr.
fn run_verify_once(job: &Path, out: &Path) -> (Option<i32>, String, String) {
    trimctl(&["--verify", "--rounds", "1"], job, out)
}

#[test]
fn a_real_parts_rescan_comes_from_the_scan_command_and_is_inspected_without_a_truth() {
    // `--verify` on a part of the job's own files: the cell's scanner is a `[verify]
    // scan_command` that delivers a scan of the part as it stands after trimming (the same
    // core scanned without its burrs).
    let tmp = tempfile::tempdir().expect("tempdir");
    let clean = tmp.path().join("clean");
    synth_job_with(&clean, "0", "");
    let clean_scan = clean.join("core").join("scan.ply");
    let burred = tmp.path().join("burred");
    let job = synth_job_with(
        &burred,
        "0.3",
        &format!(
            "[verify]\nscan_command = [\"cp\", {clean_scan:?}, \"{{scan}}\"]\nscan_timeout_s = 60\n"
        ),
    );
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run_verify_once(&job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    // The command ran with {scan} filled in, and wrote the round's file in the run folder.
    assert!(
        stdout.contains("verify 1: rescanning the part: cp"),
        "{stdout}"
    );
    assert!(out.join("rescan_1.ply").exists());
    let rounds = read_json(&out.join("verify.json"));
    let rounds = rounds.as_array().expect("rounds");
    assert_eq!(rounds.len(), 1, "{rounds:?}");
    let first = &rounds[0];
    // The part as delivered carries no burr: nothing fails, and there is no truth to report.
    assert_eq!(first["fail"], 0, "{first}");
    assert!(first["pass"].as_u64().unwrap() >= 40, "{first}");
    for key in [
        "true_residual_max_um",
        "true_gouge_p95_um",
        "true_film_covered_max",
    ] {
        assert!(first[key].is_null(), "{key}: {first}");
    }
    assert!(inspection(&out.join("verify_1")).len() >= 40);
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(report.contains("## Verify and retrim"), "{report}");
}

/// A real cell's scanner that loses part of the part on one scan (dropouts) is asked once more
/// for the contours it left uncovered: the `[verify] scan_command` runs again with `{look}` 2,
/// writing `rescan_<k>_again.ply`, and those contours are judged on that scan. Here the first
/// look is a clean core's scan with dropout patches, the second the same core without them.
#[test]
fn a_real_parts_uncovered_contours_get_a_second_look_from_the_scan_command() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let clean = tmp.path().join("clean");
    synth_job_with(&clean, "0", "");
    let holed = tmp.path().join("holed");
    synth_core(&holed, "0", "30");
    let (first, second) = (holed.join("scan.ply"), clean.join("core").join("scan.ply"));
    let script = format!(
        "if [ \"$1\" = 1 ]; then cp {} \"$2\"; else cp {} \"$2\"; fi",
        first.display(),
        second.display()
    );
    let burred = tmp.path().join("burred");
    let job = synth_job_with(
        &burred,
        "0.3",
        &format!(
            "[verify]\nscan_command = [\"sh\", \"-c\", {script:?}, \"scan\", \"{{look}}\", \"{{scan}}\"]\nscan_timeout_s = 60\n"
        ),
    );
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run_verify_once(&job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("verify 1: the rescan covered contours"))
        .unwrap_or_else(|| panic!("no second look:\n{stdout}"));
    eprintln!("{line}");
    assert!(
        stdout
            .contains("verify 1: rescanning the part again for the contours it left uncovered: sh"),
        "{stdout}"
    );
    assert!(out.join("rescan_1.ply").exists() && out.join("rescan_1_again.ply").exists());
    // The contours the first look left uncovered are judged on the second: covered, and the
    // part (delivered without burrs) passes with nothing left undecided for coverage.
    let uncovered: Vec<i64> = line
        .split('[')
        .nth(1)
        .and_then(|rest| rest.split(']').next())
        .expect("a list")
        .split(", ")
        .map(|id| id.parse().expect("an id"))
        .collect();
    assert!(!uncovered.is_empty());
    let inspected = inspection(&out.join("verify_1"));
    for id in &uncovered {
        let c = &inspected[id];
        assert!(num(c, "coverage") >= 0.9, "contour {id}: {c}");
    }
    let rounds = read_json(&out.join("verify.json"));
    assert_eq!(rounds[0]["fail"], 0, "{}", rounds[0]);
}

/// A part scanned as `[part] scans` at two machine poses (each side of the part from its own
/// pose) is rescanned at both: the `[verify] scan_command` runs once per pose, `{pose}` naming
/// the part's scan whose pose it is, and the inspection judges the two rescans merged through
/// the cell as the registration took the scans. One side's rescan alone would leave the other
/// side's contours uncovered. A rescan the command does not write stops the run naming the pose.
#[test]
fn a_part_scanned_at_two_poses_is_rescanned_at_both_and_judged_on_the_merged_rescans() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let poses = [
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
    ];
    // The burred part as the job's scans; the same core without burrs, at the same poses, as
    // what the scanner delivers after trimming.
    let sides = |core: &Path, dir: &Path| {
        let scan = read_points(&core.join("scan.ply")).expect("scan.ply");
        std::fs::create_dir_all(dir).expect("dir");
        write_scans_at_poses(dir, "side", &split_by_side(&scan, poses))
    };
    let clean = tmp.path().join("clean");
    synth_core(&clean, "0", "0");
    let (delivered, _) = sides(&clean, &tmp.path().join("delivered"));
    let core = tmp.path().join("core");
    synth_core(&core, "0.3", "0");
    let (_, poses_file) = sides(&core, &tmp.path().join("scans"));
    let job = tmp.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            "[verify]\nscan_command = [\"cp\", \"{}/{{pose}}.ply\", \"{{scan}}\"]\nscan_timeout_s = 60\n\
             [part]\ncad = \"core/cad.stl\"\npath = \"core/path.csv\"\n\
             scans = [\"scans/side0.ply\", \"scans/side1.ply\"]\nposes = {poses_file:?}\n",
            tmp.path().join("delivered").display()
        ),
    )
    .expect("job file");
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run_verify_once(&job, &out);
    assert_eq!(code, Some(0), "stdout:\n{stdout}\nstderr:\n{stderr}");
    for (k, file) in delivered.iter().enumerate() {
        assert!(
            stdout.contains(&format!(
                "verify 1: rescanning the part at pose side{k}: cp {}",
                file.display()
            )),
            "{stdout}"
        );
        assert!(out.join(format!("rescan_1_side{k}.ply")).exists());
    }
    // Both sides seen: every contour covered, nothing fails (the part as delivered carries no
    // burr), and no second look was needed.
    let inspected = inspection(&out.join("verify_1"));
    assert!(inspected.len() >= 40, "{} contours", inspected.len());
    for (id, c) in &inspected {
        assert!(num(c, "coverage") >= MIN_COVERAGE, "contour {id}: {c}");
    }
    assert!(
        !stdout.contains("rescanning the part at pose side0 again"),
        "{stdout}"
    );
    let rounds = read_json(&out.join("verify.json"));
    assert_eq!(rounds[0]["fail"], 0, "{}", rounds[0]);

    // A command that delivers no rescan at the second pose stops the run naming that pose.
    std::fs::remove_file(&delivered[1]).expect("remove");
    let out = tmp.path().join("run_lost");
    let (code, stdout, stderr) = run_verify_once(&job, &out);
    assert_eq!(code, Some(1), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(
        stderr.contains("verify 1") && stderr.contains("pose side1"),
        "{stderr}"
    );
}

#[test]
fn a_rescan_that_never_comes_stops_the_run_at_the_timeout_naming_the_file() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let job = synth_job_with(tmp.path(), "0.3", "[verify]\nscan_timeout_s = 1\n");
    let out = tmp.path().join("run");
    let (code, stdout, stderr) = run_verify_once(&job, &out);
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

/// A stop signal while the run waits for its rescan (a `[verify] scan_command` that takes its
/// time, as a scanner does) stops the run there: the command is stopped, no retrim starts, and
/// the run exits 3 at once. The job's execution is over by then: a handler tied to its runtime
/// outlived it (tokio keeps a signal's handler for the rest of the process), so the signal was
/// swallowed, the scan went on, and a retrim would have fired the laser.
#[test]
fn a_stop_signal_during_the_rescan_stops_the_run_before_any_retrim() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let scanning = tmp.path().join("scanning");
    let script = "touch \"$1\"; sleep 120";
    let job = synth_job_with(
        tmp.path(),
        "0.3",
        &format!(
            "[verify]\nscan_command = [\"sh\", \"-c\", {script:?}, \"scan\", {scanning:?}]\nscan_timeout_s = 300\n"
        ),
    );
    let out = tmp.path().join("run");
    let stderr_file = tmp.path().join("stderr");
    let mut child = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .args([
            "--verify",
            "--rounds",
            "1",
            "--sim-time-scale",
            "0.01",
            "--out",
        ])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&stderr_file).expect("stderr file"))
        .spawn()
        .expect("trimctl runs");
    let start = std::time::Instant::now();
    while !scanning.exists() {
        if let Some(status) = child.try_wait().expect("try_wait") {
            panic!(
                "the run ended ({status}) before its rescan:\n{}",
                std::fs::read_to_string(&stderr_file).unwrap_or_default()
            );
        }
        assert!(
            start.elapsed() < std::time::Duration::from_secs(600),
            "the rescan never started"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let signalled = std::time::Instant::now();
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(killed.success());
    let status = loop {
        if let Some(status) = child.try_wait().expect("try_wait") {
            break status;
        }
        if signalled.elapsed() > std::time::Duration::from_secs(60) {
            let _ = child.kill();
            panic!("the run went on for a minute after SIGINT during its rescan");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    let stderr = std::fs::read_to_string(&stderr_file).expect("stderr");
    assert_eq!(status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("SIGINT (Ctrl-C)") && stderr.contains("scan_command"),
        "{stderr}"
    );
    // The job ran and finished; no retrim began.
    assert!(out.join("journal.jsonl").exists());
    assert!(
        !out.join("retrim_1").join("journal.jsonl").exists(),
        "a retrim ran after the stop"
    );
}
