//! `trimctl run` end to end: the demo part on the simulated cell leaves a complete run folder;
//! a run killed midway resumes without marking any layer twice; a layer cut at a point nobody
//! can tell is redone or skipped by the operator's choice; bad job files are refused with one
//! line naming the key.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");
/// The product's trimming tolerance (µm): the spot must land within ±30 µm of the true trimming
/// line. The demo's largest spot error (registration, plan and the twin's nominal cell) is
/// measured at 9.6 µm (P95 4.8 µm; 10–17 µm in the runs issue 24 quotes): the bound is the
/// tolerance itself, a margin of about 2–3× on what is measured, not a looser figure.
const SPOT_TOLERANCE_UM: f64 = 30.0;

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
        "registration.svg",
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
    // The run report gives every contour's predicted error bound, as registration.json does.
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    // The demo hatches one region: the zone table (printed and in the report) and the SVG name
    // its tracks, not their internal negative ids.
    let svg = std::fs::read_to_string(out.join("plan.svg")).unwrap();
    for (what, text) in [
        ("stdout", &*stdout),
        ("report.md", &*report),
        ("plan.svg", &*svg),
    ] {
        let lines: Vec<&str> = text
            .lines()
            .filter(|l| l.contains("hatch[0] track"))
            .collect();
        assert!(!lines.is_empty(), "{what}:\n{text}");
        assert!(lines.iter().all(|l| !l.contains("[-")), "{what}:\n{text}");
    }
    let quality: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("registration.json")).unwrap())
            .unwrap();
    let contours = quality["contours"].as_array().unwrap();
    assert!(!contours.is_empty());
    // The registration's picture draws every contour, all trusted on the demo.
    let picture = std::fs::read_to_string(out.join("registration.svg")).unwrap();
    assert_eq!(
        picture.matches(r#"class="contour trusted""#).count(),
        contours.len()
    );
    assert!(picture.contains("the part as a whole: accepted"));
    assert!(report.contains("predicted max error µm"), "{report}");
    for c in contours {
        let bound = c["predicted_max_error_um"].as_f64().unwrap();
        assert!(bound.is_finite() && bound > 0.0, "{c}");
        let row = format!("| {} | {bound:.1} |", c["id"]);
        assert!(report.contains(&row), "{row} missing from report.md");
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
    demo_hatch_is_planned_and_marked(&out, &stdout);
}

/// The demo's hatched region: its tracks are equally spaced, planned beside the contours (split
/// into pieces where the incidence limit requires) and marked; the twin's spot error counts the
/// trimming line only.
fn demo_hatch_is_planned_and_marked(out: &Path, stdout: &str) {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("hatch[0]"))
        .unwrap_or_else(|| panic!("no hatch line in:\n{stdout}"));
    assert!(line.contains("coverage 100.00 %"), "{line}");
    for file in ["hatch_0.csv", "hatch_0.svg", "inputs/hatch_boundary.csv"] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
    let tracks = std::fs::read_to_string(out.join("hatch_0.csv")).expect("hatch_0.csv");
    let n_tracks = tracks
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next())
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    // 3 mm across at a 0.05 mm pitch, plus the outline; the part lies turned by its fixture
    // error, so tracks along the machine's X cross the 16 mm long region a little diagonally.
    assert!((60..=80).contains(&n_tracks), "{n_tracks} tracks");
    let text = std::fs::read_to_string(out.join("plan.json")).expect("plan.json");
    let plan: serde_json::Value = serde_json::from_str(&text).expect("plan.json is JSON");
    let mut hatch_ids = std::collections::BTreeSet::new();
    let mut hatch_polylines = 0;
    for z in plan["zones"].as_array().expect("zones") {
        for l in z["layers"].as_array().expect("layers") {
            for p in l["polylines"].as_array().expect("polylines") {
                let id = p["contour"].as_i64().expect("contour id");
                if id < 0 {
                    hatch_ids.insert(id);
                    hatch_polylines += 1;
                }
            }
        }
    }
    assert_eq!(hatch_ids.len(), n_tracks, "every track is planned");
    assert!(
        hatch_polylines > n_tracks,
        "tracks across the cambered face are split by the incidence limit"
    );
    assert_eq!(plan["validation"]["passed"], true);
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("summary.json is JSON");
    let spots = &summary["spot_error"];
    assert!(
        spots["excluded_spots"].as_u64().expect("excluded_spots") > 0,
        "{spots}"
    );
    let max_um = spots["overall"]["max_um"].as_f64().expect("max_um");
    eprintln!(
        "demo spot error: max {max_um:.1} µm, P95 {:.1} µm (tolerance ±{SPOT_TOLERANCE_UM} µm)",
        spots["overall"]["p95_um"].as_f64().unwrap_or(f64::NAN)
    );
    assert!(max_um <= SPOT_TOLERANCE_UM, "{spots}");
}

#[test]
fn killed_run_resumes_without_marking_a_layer_twice() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // Slow enough (real-time devices) that the kill lands midway.
    let mut child = spawn_real_time_run(&[], &out);
    wait_until(
        &mut child,
        || layers_done(&out).len() >= 2,
        RUN_TIMEOUT,
        "it could be killed midway",
    );
    // While it runs the folder is its alone; killed, it holds nothing.
    a_second_writer_is_refused(&child, &out, &out);
    kill(child);
    let before = layers_done(&out);
    let planned = planned_layers(&out);
    assert!(
        before.len() < planned.len(),
        "the kill came after the last layer"
    );

    // The in-process simulators died with the run: when the kill landed mid-layer, nobody can
    // tell how far that layer got, and `redo` marks it again (between layers it is not used).
    resume_marks_each_layer_once(&out, &planned);

    // Resumed again, the finished run is left as it is: nothing connected, no layer marked,
    // the report unchanged (it gained a "Resume" section of 0 layers before).
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).unwrap();
    let again = Command::new(TRIMCTL)
        .args(["run", "--cnc", "127.0.0.1:1", "--resume"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(
        again.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&again.stderr)
    );
    assert!(
        stdout.contains("is finished") && stdout.contains("nothing to resume"),
        "{stdout}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("report.md")).unwrap(),
        report
    );
    assert_eq!(
        std::fs::read_to_string(out.join("journal.jsonl")).unwrap(),
        journal
    );
}

/// A `--verify` run killed (SIGKILL) inside its first retrim, resumed from the retrim's folder:
/// the resume names the run it continues, finishes the retrim from its journal and goes on
/// with the loop to the end, as an uninterrupted run does.
#[test]
fn a_retrim_killed_midway_resumes_from_its_own_folder_without_marking_a_layer_twice() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let retrim = out.join("retrim_1");
    // Real-time devices, so the kill lands inside the first retrim.
    let mut child = spawn_real_time_run(&["--verify"], &out);
    wait_until(
        &mut child,
        || retrim.join("journal.jsonl").exists() && !layers_done(&retrim).is_empty(),
        3 * RUN_TIMEOUT,
        "its retrim could be killed midway",
    );
    // The retrim is written under the run's lock: resuming it while the run lives is refused,
    // naming the run.
    a_second_writer_is_refused(&child, &out, &retrim);
    kill(child);
    let planned = planned_layers(&retrim);
    assert!(
        layers_done(&retrim).len() < planned.len(),
        "the kill came after the retrim's last layer"
    );
    // Inspection 1 is recorded (its retrim was planned before it was), nothing after it.
    assert_eq!(verify_rounds(&out).len(), 1);
    let stderr = resume_marks_each_layer_once(&retrim, &planned);
    assert!(
        stderr.contains("is retrim 1 of the --verify run"),
        "{stderr}"
    );
    verify_loop_ended_once(&out);
    // The retrim's resume is its own folder's: report, summary and record.
    let report = std::fs::read_to_string(retrim.join("report.md")).expect("retrim_1/report.md");
    assert!(report.contains("## Resume 1"), "{report}");
    assert!(retrim.join("run.resume-1.mcap").is_file());
}

/// A `--verify` run killed (SIGKILL) inside its job, resumed with `--resume RUN`: the job is
/// finished from its journal, then the loop runs from inspection 1 to the end, as an
/// uninterrupted run does.
#[test]
fn a_verify_run_killed_in_its_job_resumes_to_the_end_of_its_loop() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let child = spawn_real_time_run(&["--verify"], &out);
    kill_when(
        child,
        || layers_done(&out).len() >= 2,
        RUN_TIMEOUT,
        "its job could be killed midway",
    );
    let planned = planned_layers(&out);
    assert!(
        layers_done(&out).len() < planned.len(),
        "the kill came after the job's last layer"
    );
    assert!(!out.join("verify.json").exists() && !out.join("verify_1").exists());
    let state: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("verify_state.json")).expect("verify_state.json"),
    )
    .expect("verify_state.json is JSON");
    assert_eq!(state["rounds"], 2, "{state}");
    assert_eq!(state["demo"]["seed"], 1, "{state}");
    resume_marks_each_layer_once(&out, &planned);
    verify_loop_ended_once(&out);
    assert!(out.join("run.resume-1.mcap").is_file());
    assert!(out.join("retrim_1").join("run.mcap").is_file());

    // A corrupt state, or landed cuts gone, is refused naming the file, before anything moves.
    for (name, spoil, says) in [
        (
            "corrupt-state",
            "verify_state.json",
            "verify_state.json: not the state of a --verify run",
        ),
        (
            "no-cuts",
            "retrim_1/twin_cuts.jsonl",
            "retrim_1/twin_cuts.jsonl is missing",
        ),
    ] {
        let copy = tmp.path().join(name);
        copy_dir(&out, &copy);
        if spoil.ends_with(".jsonl") {
            std::fs::remove_file(copy.join(spoil)).unwrap();
        } else {
            std::fs::write(copy.join(spoil), "{\"version\": 1, \"rou").unwrap();
        }
        let journal = std::fs::read_to_string(copy.join("journal.jsonl")).unwrap();
        let result = Command::new(TRIMCTL)
            .args(["run", "--sim-time-scale", "0.01", "--resume"])
            .arg(&copy)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(1), "{name}: {stderr}");
        assert!(stderr.contains(says), "{name}: {says:?} missing: {stderr}");
        assert_eq!(
            std::fs::read_to_string(copy.join("journal.jsonl")).unwrap(),
            journal
        );
    }
}

/// The end of a `--verify` run on the demo, after a kill and a resume, is the uninterrupted
/// run's: after one retrim every contour passes inspection; verify.json lists inspections 1, 2
/// once each and summary.json's `verify` is the same; report.md holds the loop's section once,
/// a row per round; every planned layer of the job and of each retrim finished exactly once.
fn verify_loop_ended_once(out: &Path) {
    let rounds = verify_rounds(out);
    let inspections: Vec<u64> = rounds
        .iter()
        .map(|r| r["inspection"].as_u64().expect("an inspection number"))
        .collect();
    assert_eq!(inspections, [1, 2], "{rounds:?}");
    assert_eq!(rounds[0]["retrimmed"], true, "{:?}", rounds[0]);
    let last = rounds.last().expect("a round");
    let contours = inspected(&out.join("verify_2"));
    assert_eq!(contours.len(), 52);
    assert_eq!(last["pass"], 52, "{last:?}");
    assert_eq!(
        (last["fail"].as_u64(), last["undecided"].as_u64()),
        (Some(0), Some(0))
    );
    assert!(contours.values().all(|c| c["verdict"] == "pass"));
    assert!(
        last["true_residual_max_um"]
            .as_f64()
            .expect("the twin's truth")
            <= SPOT_TOLERANCE_UM,
        "{last:?}"
    );
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("summary.json is JSON");
    assert_eq!(summary["verify"], serde_json::Value::Array(rounds.clone()));
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert_eq!(
        report.matches("## Verify and retrim").count(),
        1,
        "{report}"
    );
    let section = &report[report
        .find("## Verify and retrim")
        .expect("the loop's section")..];
    for k in [1, 2] {
        assert_eq!(
            section
                .lines()
                .filter(|l| l.starts_with(&format!("| {k} |")))
                .count(),
            1,
            "{section}"
        );
    }
    assert!(!out.join("retrim_2").exists() && !out.join("verify_3").exists());
    for dir in [out.to_path_buf(), out.join("retrim_1")] {
        let done = layers_done(&dir);
        let planned = planned_layers(&dir);
        assert_eq!(done.len(), planned.len(), "{}: {done:?}", dir.display());
        for key in &planned {
            assert_eq!(done.get(key), Some(&1), "{}: layer {key:?}", dir.display());
        }
    }
}

/// `trimctl run ARGS --out OUT` on the demo with real-time simulated devices, started in the
/// background with its output discarded.
fn spawn_real_time_run(args: &[&str], out: &Path) -> std::process::Child {
    Command::new(TRIMCTL)
        .arg("run")
        .args(args)
        .args(["--sim-time-scale", "1.0", "--out"])
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("trimctl run starts")
}

/// Waits until `ready()` holds, then kills `child` with SIGKILL (no clean shutdown, as a crash
/// or a power cut); fails when the run ends first (`what` says before what) or `limit` passes.
fn kill_when(
    mut child: std::process::Child,
    ready: impl Fn() -> bool,
    limit: Duration,
    what: &str,
) {
    wait_until(&mut child, ready, limit, what);
    kill(child);
}

/// Kills `child` with SIGKILL and reaps it.
fn kill(mut child: std::process::Child) {
    child.kill().expect("the run is killed");
    child.wait().expect("the killed run is reaped");
}

/// Waits until `ready()` holds while `child` runs; fails when the run ends first (`what` says
/// before what) or `limit` passes.
fn wait_until(
    child: &mut std::process::Child,
    ready: impl Fn() -> bool,
    limit: Duration,
    what: &str,
) {
    let start = Instant::now();
    while !ready() {
        if let Some(status) = child.try_wait().expect("the run's status") {
            panic!("the run ended ({status}) before {what}");
        }
        assert!(start.elapsed() < limit, "nothing to kill in time: {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// How long a refusal of a locked run folder may take (debug build, loaded machine): it must
/// not wait for the lock, which the running demo holds for minutes.
const REFUSAL_TIMEOUT: Duration = Duration::from_secs(20);

/// While the run `holder` writes `folder`, a second trimctl on it is refused at once (exit 1)
/// naming the folder and the holder's process id: `--resume TARGET` (the folder, or one of its
/// retrims, which resumes the folder) and a fresh `run --out FOLDER`.
fn a_second_writer_is_refused(holder: &std::process::Child, folder: &Path, target: &Path) {
    for (what, target) in [("--resume", target), ("--out", folder)] {
        let start = Instant::now();
        let result = Command::new(TRIMCTL)
            .args(["run", "--sim-time-scale", "0.01", what])
            .arg(target)
            .output()
            .expect("trimctl runs");
        let took = start.elapsed();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(1), "{what}: {stderr}");
        assert!(
            stderr.contains(&format!(
                "{} is in use by another trimctl (PID {}",
                folder.display(),
                holder.id()
            )),
            "{what}: the folder and the holder's PID not named: {stderr}"
        );
        assert!(took < REFUSAL_TIMEOUT, "{what}: refused after {took:?}");
    }
}

/// `trimctl run --resume DIR --cut-layer redo` on fast devices succeeds, and then every layer in
/// `planned` has finished exactly once in DIR's journal; its stderr.
fn resume_marks_each_layer_once(dir: &Path, planned: &[(u64, u64)]) -> String {
    let result = Command::new(TRIMCTL)
        .args([
            "run",
            "--sim-time-scale",
            "0.01",
            "--cut-layer",
            "redo",
            "--resume",
        ])
        .arg(dir)
        .output()
        .expect("trimctl run --resume runs");
    assert!(
        result.status.success(),
        "resume of {} failed:\n{}\n{}",
        dir.display(),
        String::from_utf8_lossy(&result.stdout),
        String::from_utf8_lossy(&result.stderr)
    );
    let after = layers_done(dir);
    for key in planned {
        assert_eq!(
            after.get(key),
            Some(&1),
            "layer {key:?} of {} finished {:?} times",
            dir.display(),
            after.get(key)
        );
    }
    String::from_utf8_lossy(&result.stderr).into_owned()
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
        (
            "[part]\ncad = \"c.stl\"\npath = \"p.csv\"\nscan = \"s.ply\"\nscans = [\"a.ply\"]\nposes = \"poses.csv\"\n",
            "part.scan and part.scans",
        ),
        (
            "[part]\ncad = \"c.stl\"\npath = \"p.csv\"\nscans = [\"a.ply\", \"b.ply\"]\n",
            "part.scans: needs part.poses",
        ),
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

/// `trimctl sim all` as a child process: its addresses, read from its stdout.
struct SimServer {
    child: std::process::Child,
    galvo: String,
    cnc: String,
    laser: String,
}

impl SimServer {
    /// Starts the simulators on free ports, 100× faster than real time, with `faults`.
    fn start(faults: &[&str]) -> SimServer {
        use std::io::BufRead as _;
        let mut cmd = Command::new(TRIMCTL);
        cmd.args([
            "sim",
            "all",
            "--galvo-port",
            "0",
            "--cnc-port",
            "0",
            "--galvo-time-scale",
            "0.01",
            "--cnc-time-scale",
            "0.01",
        ]);
        for f in faults {
            cmd.args(["--fault", f]);
        }
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("trimctl sim starts");
        let mut lines = std::io::BufReader::new(child.stdout.take().expect("piped stdout")).lines();
        let (mut galvo, mut cnc, mut laser) = (None, None, None);
        while galvo.is_none() || cnc.is_none() || laser.is_none() {
            let line = lines
                .next()
                .expect("trimctl sim printed its addresses")
                .expect("stdout is readable");
            let v: serde_json::Value =
                serde_json::from_str(&line).expect("an address line is JSON");
            let get = |k: &str| v[k].as_str().map(str::to_owned);
            galvo = galvo.or_else(|| get("galvo"));
            cnc = cnc.or_else(|| get("cnc"));
            laser = laser.or_else(|| get("laser"));
        }
        SimServer {
            child,
            galvo: galvo.unwrap_or_default(),
            cnc: cnc.unwrap_or_default(),
            laser: laser.unwrap_or_default(),
        }
    }

    /// `trimctl run` arguments that point at these simulators (its CNC starts in E-stop and
    /// unhomed: both steps allowed).
    fn cell_args(&self) -> Vec<String> {
        [
            "--galvo",
            &self.galvo,
            "--cnc",
            &self.cnc,
            "--laser",
            &self.laser,
            "--enable-machine",
            "--home",
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect()
    }

    /// Stops it as an operator's power switch would: no clean shutdown, all state lost.
    fn power_off(mut self) {
        self.child.kill().expect("kill trimctl sim");
        self.child.wait().expect("reap trimctl sim");
    }
}

impl Drop for SimServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn journal_kinds(dir: &Path) -> Vec<String> {
    journal_entries(dir)
        .iter()
        .map(|e| e["kind"].as_str().unwrap_or("?").to_owned())
        .collect()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("create the copy");
    for entry in std::fs::read_dir(from).expect("read the run folder") {
        let entry = entry.expect("a directory entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("a file type").is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).expect("copy a file");
        }
    }
}

#[test]
fn a_layer_cut_at_an_unknown_point_resumes_by_the_operators_choice() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");

    // The galvo stops answering at the 5th EXECUTE (layer index 4): the run stops, exit 2.
    let sim = SimServer::start(&["galvo=stall@EXECUTE#5"]);
    let result = Command::new(TRIMCTL)
        .args(["run", "--out"])
        .arg(&out)
        .args(sim.cell_args())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
    assert_eq!(result.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("trimctl run --resume"), "{stderr}");
    let planned = planned_layers(&out);
    let cut = planned[4];
    let begins: Vec<serde_json::Value> = journal_entries(&out)
        .into_iter()
        .filter(|e| e["kind"] == "layer_begin")
        .collect();
    let last_begin = begins.last().expect("a layer began").clone();
    assert_eq!(
        (
            last_begin["key"]["zone"].as_u64(),
            last_begin["key"]["layer"].as_u64()
        ),
        (Some(cut.0), Some(cut.1))
    );
    let vectors = last_begin["vectors"].as_u64().unwrap();
    let cut_name = format!("zone {} layer {}", cut.0, cut.1);

    // The operator power-cycles the galvo controller: it forgets its lists.
    sim.power_off();
    let sim = SimServer::start(&[]);

    // Resume cannot tell how far the layer got: refused (exit 1), nothing switched on, the
    // choices named.
    let result = Command::new(TRIMCTL)
        .args(["run", "--resume"])
        .arg(&out)
        .args(sim.cell_args())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    for expected in [
        format!("cannot tell how far {cut_name} got"),
        format!("up to {vectors} of its {vectors} vectors may be marked twice"),
        "--cut-layer redo".to_owned(),
        "--cut-layer skip".to_owned(),
    ] {
        assert!(
            stderr.contains(&expected),
            "{expected:?} missing:\n{stderr}"
        );
    }
    assert!(!journal_kinds(&out).contains(&"cut_layer_choice".to_owned()));
    let skip_dir = tmp.path().join("run-skip");
    copy_dir(&out, &skip_dir);

    // redo: the layer is marked again from its first vector; the journal and the report say so.
    let result = Command::new(TRIMCTL)
        .args(["run", "--resume"])
        .arg(&out)
        .args(["--cut-layer", "redo"])
        .args(sim.cell_args())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout).into_owned();
    assert!(
        result.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let choices: Vec<serde_json::Value> = journal_entries(&out)
        .into_iter()
        .filter(|e| e["kind"] == "cut_layer_choice")
        .collect();
    assert_eq!(choices.len(), 1, "{choices:?}");
    assert_eq!(choices[0]["choice"], "redo");
    assert_eq!(choices[0]["vectors_maybe_twice"].as_u64(), Some(vectors));
    let done = layers_done(&out);
    for key in &planned {
        assert_eq!(done.get(key), Some(&1), "redo: layer {key:?}");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let line = format!(
        "cut layer {cut_name}: progress unknown; redone from vector 0 of {vectors}: up to {vectors} vectors may be marked twice"
    );
    assert!(
        stdout.contains(&line),
        "{line:?} missing from stdout:\n{stdout}"
    );
    assert!(report.contains("## Resume 1"), "{report}");
    assert!(
        report.contains(&line),
        "{line:?} missing from report:\n{report}"
    );

    // skip: the layer is left out, never marked; every other layer is marked once; the
    // journal and the report list it.
    let result = Command::new(TRIMCTL)
        .args(["run", "--resume"])
        .arg(&skip_dir)
        .args(["--cut-layer", "skip"])
        .args(sim.cell_args())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout).into_owned();
    assert!(
        result.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let choices: Vec<serde_json::Value> = journal_entries(&skip_dir)
        .into_iter()
        .filter(|e| e["kind"] == "cut_layer_choice")
        .collect();
    assert_eq!(choices.len(), 1, "{choices:?}");
    assert_eq!(choices[0]["choice"], "skip");
    assert_eq!(choices[0]["vectors_maybe_twice"].as_u64(), Some(0));
    let done = layers_done(&skip_dir);
    for key in &planned {
        let want = if *key == cut { None } else { Some(&1) };
        assert_eq!(done.get(key), want, "skip: layer {key:?}");
    }
    let report = std::fs::read_to_string(skip_dir.join("report.md")).unwrap();
    let line = format!("layers left out (--cut-layer skip), not marked: {cut_name}");
    assert!(
        stdout.contains(&line),
        "{line:?} missing from stdout:\n{stdout}"
    );
    assert!(
        report.contains(&line),
        "{line:?} missing from report:\n{report}"
    );

    // A later resume keeps the layer left out without asking again.
    let result = Command::new(TRIMCTL)
        .args(["run", "--resume"])
        .arg(&skip_dir)
        .args(sim.cell_args())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout).into_owned();
    assert!(result.status.success(), "{stdout}");
    assert!(stdout.contains(&line), "{line:?} missing:\n{stdout}");
    assert_eq!(layers_done(&skip_dir), done);
    drop(sim);
}

/// The error line, `report.md` and `summary.json` say what the way down acknowledged: with a
/// laser that stops answering mid-list, its emission-off is NOT acknowledged, the run exits 4
/// (the laser's state unknown) and the operator is told to switch it off at its key; with a
/// galvo that hangs, the laser's emission-off is acknowledged (exit 2) and the galvo's steps
/// are named as not acknowledged. "The laser is off" is said only when it was acknowledged.
#[test]
fn a_stopped_run_says_which_steps_of_the_way_down_were_acknowledged() {
    let tmp = tempfile::tempdir().unwrap();
    // The laser's 2nd fault query is the check right after the first EXECUTE (preparation
    // checks once); the galvo's 2nd EXECUTE is layer index 1.
    for (fault, code, says, report_says, not_acked) in [
        (
            "laser=stall@faults#2",
            4,
            "laser emission-off NOT acknowledged",
            "laser emission-off NOT acknowledged",
            "emission_off",
        ),
        (
            "galvo=stall@EXECUTE#2",
            2,
            "the laser's emission is off (acknowledged)",
            "laser emission-off acknowledged (1 attempt(s)",
            "galvo_stop",
        ),
    ] {
        let out = tmp.path().join(fault.replace(['=', '@', '#'], "-"));
        let sim = SimServer::start(&[fault]);
        let result = Command::new(TRIMCTL)
            .args(["run", "--out"])
            .arg(&out)
            .args(sim.cell_args())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
        assert_eq!(result.status.code(), Some(code), "{fault}: {stderr}");
        let error = stderr
            .lines()
            .find(|l| l.starts_with("trimctl: error"))
            .unwrap_or_else(|| panic!("{fault}: no error line: {stderr}"));
        assert!(error.contains(says), "{fault}: {error}");
        assert!(!error.contains("the laser is off"), "{fault}: {error}");
        if code == 4 {
            assert!(
                error.contains("switch the laser off at its key"),
                "{fault}: {error}"
            );
        }
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(report.contains("## Way down"), "{fault}: {report}");
        assert!(report.contains(report_says), "{fault}: {report}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        let shutdown = &summary["shutdown"];
        assert_eq!(
            shutdown["laser_off_ok"].as_bool(),
            Some(code == 2),
            "{fault}: {shutdown}"
        );
        let failed: Vec<&str> = shutdown["failures"]
            .as_array()
            .unwrap_or_else(|| panic!("{fault}: {shutdown}"))
            .iter()
            .filter_map(|f| f["step"].as_str())
            .collect();
        assert!(failed.contains(&not_acked), "{fault}: {failed:?}");
        assert!(
            !shutdown["emission_off"].as_array().unwrap().is_empty(),
            "{fault}: {shutdown}"
        );
        // The MCAP record holds it on /shutdown.
        let record = std::fs::read(out.join("run.mcap")).unwrap();
        assert!(
            record
                .windows(b"/shutdown".len())
                .any(|w| w == b"/shutdown")
                && record
                    .windows(b"laser_off_ok".len())
                    .any(|w| w == b"laser_off_ok"),
            "{fault}: no /shutdown message in the record"
        );
        drop(sim);
    }
}

/// SIGTERM, SIGHUP and SIGQUIT stop a run mid-layer the way Ctrl-C does: the way down (laser
/// off first, acknowledged), exit 3, the cut layer journaled; `--resume` finishes the job with
/// every layer finished once.
#[test]
fn each_stop_signal_takes_the_way_down_and_the_run_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    for sig in ["TERM", "HUP", "QUIT"] {
        let out = tmp.path().join(sig);
        // stderr to a file: a pipe nobody reads until the end could fill and block the run.
        let stderr_path = tmp.path().join(format!("{sig}.stderr"));
        let child = Command::new(TRIMCTL)
            .args(["run", "--sim-time-scale", "1.0", "--out"])
            .arg(&out)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr_path).unwrap())
            .spawn()
            .unwrap();
        // Mid-layer: a layer finished, and the last entry is a later layer's begin.
        let start = Instant::now();
        let mut child = child;
        loop {
            let entries = journal_entries(&out);
            let mid_layer = !layers_done(&out).is_empty()
                && entries.last().is_some_and(|e| e["kind"] == "layer_begin");
            if mid_layer {
                break;
            }
            if let Some(status) = child.try_wait().unwrap() {
                panic!("SIG{sig}: the run ended ({status}) before the signal");
            }
            assert!(
                start.elapsed() < RUN_TIMEOUT,
                "SIG{sig}: no layer began in time"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        let killed = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(killed.success());
        let status = child.wait().unwrap();
        let stderr = std::fs::read_to_string(&stderr_path).unwrap();
        assert_eq!(status.code(), Some(3), "SIG{sig}: {stderr}");
        assert!(stderr.contains(&format!("SIG{sig}")), "SIG{sig}: {stderr}");
        assert!(
            stderr.contains("the laser is off (emission-off acknowledged"),
            "SIG{sig}: {stderr}"
        );
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(summary["shutdown"]["laser_off_ok"].as_bool(), Some(true));
        // The journal is consistent: the begun layer is journaled as cut, nothing after it.
        let kinds = journal_kinds(&out);
        assert_eq!(
            kinds[kinds.len() - 2..],
            ["layer_begin".to_owned(), "layer_cut".to_owned()],
            "SIG{sig}: {kinds:?}"
        );
        let before = layers_done(&out);
        assert!(before.values().all(|&n| n == 1));

        let result = Command::new(TRIMCTL)
            .args(["run", "--sim-time-scale", "0.01", "--resume"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "SIG{sig}: resume failed:\n{}",
            String::from_utf8_lossy(&result.stderr)
        );
        let after = layers_done(&out);
        for key in planned_layers(&out) {
            assert_eq!(after.get(&key), Some(&1), "SIG{sig}: layer {key:?}");
        }
    }
}

/// Against a CNC that stands in E-stop and unhomed (`trimctl sim`'s, as a machine after
/// power-up), `trimctl run` refuses without --enable-machine and --home (exit 1, naming the
/// state, nothing switched on); the built-in demo needs neither (its in-process simulator
/// stands ready).
#[test]
fn run_refuses_a_machine_in_estop_without_enable_machine() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let sim = SimServer::start(&[]);
    let args: Vec<String> = sim
        .cell_args()
        .into_iter()
        .filter(|a| a != "--enable-machine" && a != "--home")
        .collect();
    let result = Command::new(TRIMCTL)
        .args(["run", "--out"])
        .arg(&out)
        .args(&args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    for want in [
        "the machine is in E-stop",
        "--enable-machine",
        "nothing was switched on",
    ] {
        assert!(stderr.contains(want), "{want:?} missing: {stderr}");
    }
    assert!(
        !journal_kinds(&out).iter().any(|k| k == "layer_begin"),
        "a layer began"
    );
    drop(sim);
}

/// `trimctl sim` stops cleanly (exit 0, its report printed) on SIGTERM, SIGHUP and SIGQUIT as
/// on Ctrl-C, instead of dying with its devices mid-answer.
#[test]
fn sim_stops_cleanly_on_each_stop_signal() {
    use std::io::BufRead as _;
    for sig in ["INT", "TERM", "HUP", "QUIT"] {
        let tmp = tempfile::tempdir().unwrap();
        let stderr_path = tmp.path().join("stderr");
        let mut child = Command::new(TRIMCTL)
            .args(["sim", "all", "--galvo-port", "0", "--cnc-port", "0"])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr_path).unwrap())
            .spawn()
            .unwrap();
        // Running once it printed its three addresses.
        let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
        for _ in 0..3 {
            lines.next().expect("an address line").unwrap();
        }
        std::thread::sleep(Duration::from_millis(200));
        let killed = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(killed.success());
        let status = child.wait().unwrap();
        let stderr = std::fs::read_to_string(&stderr_path).unwrap();
        assert_eq!(status.code(), Some(0), "SIG{sig}: {stderr}");
        assert!(
            stderr.contains(&format!("SIG{sig}")) && stderr.contains("stopping"),
            "SIG{sig}: {stderr}"
        );
    }
}

/// `run --verify` on the demo (which then carries burrs): the job trims every contour once,
/// the twin rescans the part, inspection fails the contours whose webs the single pass did not
/// cut through, and the retrims (passes from the measured excess) leave no web and no gouge
/// over the tolerance; every round is in verify.json, report.md and its own folders.
/// `trimctl run --verify` on the built-in cell with `args` (before `--out out`, at a time
/// scale of 0.01): its stdout, once it succeeded, and its rounds (verify.json).
fn run_verify(args: &[&str], out: &Path) -> (String, Vec<serde_json::Value>) {
    let result = Command::new(TRIMCTL)
        .args(["run", "--verify", "--sim-time-scale", "0.01"])
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .expect("trimctl runs");
    let stdout = String::from_utf8_lossy(&result.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        result.status.success(),
        "stdout:\n{stdout}\nstderr:\n{stderr}"
    );
    (stdout, verify_rounds(out))
}

/// The rounds of a `--verify` run (`out/verify.json`).
fn verify_rounds(out: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(out.join("verify.json")).expect("verify.json");
    serde_json::from_str(&text).expect("verify.json is JSON")
}

#[test]
fn verify_inspects_the_rescanned_demo_and_retrims_what_failed() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let (stdout, rounds) = run_verify(&[], &out);
    assert!(rounds.len() >= 2, "{rounds:?}");
    // After the one pass of the job, webs thicker than a pass stand and inspection fails them.
    assert!(rounds[0]["fail"].as_u64().unwrap() > 0, "{:?}", rounds[0]);
    assert!(rounds[0]["true_residual_max_um"].as_f64().unwrap() > 100.0);
    let last = rounds.last().unwrap();
    assert_eq!(last["fail"], 0, "{last:?}");
    assert!(
        last["true_residual_max_um"].as_f64().unwrap() <= SPOT_TOLERANCE_UM,
        "{last:?}"
    );
    assert!(
        last["true_gouge_max_um"].as_f64().unwrap() <= SPOT_TOLERANCE_UM,
        "{last:?}"
    );
    for key in ["true_residual_p95_um", "true_gouge_p95_um"] {
        assert!(
            last[key].as_f64().unwrap() <= SPOT_TOLERANCE_UM,
            "{key}: {last:?}"
        );
    }
    // summary.json carries the same rounds.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["verify"], serde_json::Value::Array(rounds.clone()));
    for (k, r) in rounds.iter().enumerate() {
        let dir = out.join(format!("verify_{}", k + 1));
        for file in [
            "inspection.json",
            "inspection.csv",
            "deviation.png",
            "report.html",
        ] {
            assert!(
                dir.join(file).is_file(),
                "{} missing",
                dir.join(file).display()
            );
        }
        if r["retrimmed"] == true {
            let retrim = out.join(format!("retrim_{}", k + 1));
            assert!(retrim.join("plan.json").is_file() && retrim.join("journal.jsonl").is_file());
        }
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Verify and retrim"), "{report}");
    assert!(
        stdout.contains("verify 1:") && stdout.contains("verified:"),
        "{stdout}"
    );
    // A job naming its own part files whose CAD is a point cloud is refused before anything
    // moves: inspection measures distances to the CAD's surface (a real part's rescan itself is
    // tested in tests/detect.rs).
    let inputs = out.join("inputs");
    let job = tmp.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            "[part]\ncad = {:?}\npath = {:?}\nscan = {:?}\n",
            inputs.join("cad_points.ply"),
            inputs.join("path.csv"),
            inputs.join("scan.ply")
        ),
    )
    .unwrap();
    let real = tmp.path().join("real");
    let refused = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .args(["--verify", "--out"])
        .arg(&real)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("holds no mesh") && stderr.contains("--verify"),
        "{stderr}"
    );
    assert!(!real.join("journal.jsonl").exists());
}

/// The share of the demo's holes and slots given a film in the blockage tests.
const DEMO_BLOCKAGES: &str = "0.15";

/// An inspection's contours by id (`dir/inspection.json`).
fn inspected(dir: &Path) -> BTreeMap<i64, serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("inspection.json")).expect("inspection.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("inspection.json is JSON");
    v["contours"]
        .as_array()
        .expect("inspection.json: contours")
        .iter()
        .map(|c| (c["id"].as_i64().expect("a contour id"), c.clone()))
        .collect()
}

/// The contours whose opening an inspection reads more than 10 % covered (the share that fails
/// them, `max_blocked_fraction`).
fn blocked_in(contours: &BTreeMap<i64, serde_json::Value>) -> Vec<i64> {
    contours
        .iter()
        .filter(|(_, c)| c["blocked_fraction"].as_f64().is_some_and(|b| b > 0.1))
        .map(|(id, _)| *id)
        .collect()
}

/// `run --verify --demo-blockages 0.15`: films 50–200 µm thick over part of 15 % of the demo's
/// openings. The job (every contour trimmed once) leaves them; inspection 1 fails each on its
/// blocked opening; the retrim hatches each blocked opening (`[trim] hatch_blocked`, on by
/// default) with the passes through its film's thickness (measured where the scan sees both
/// its sides, else 200 µm; the retrim's line says which), the twin clears the films where the
/// landed kerfs sweep them, and the last inspection passes every one of those contours with its opening
/// read at most 10 % covered (the fail line; the reading of a clean hole is 0–4 %), and the
/// twin's truth has at most 0.5 % of any opening still covered. With `hatch_blocked = false`
/// the films stay: the part fails, exit 1.
#[test]
fn blocked_openings_are_hatched_in_the_retrim_and_the_rescan_sees_them_cleared() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let (stdout, rounds) = run_verify(&["--demo-blockages", DEMO_BLOCKAGES], &out);
    let first = inspected(&out.join("verify_1"));
    let blocked = blocked_in(&first);
    eprintln!(
        "blocked after the job: {:?}",
        blocked
            .iter()
            .map(|id| (id, first[id]["blocked_fraction"].as_f64().unwrap()))
            .collect::<Vec<_>>()
    );
    assert!(blocked.len() >= 3, "{blocked:?}");
    for id in &blocked {
        assert_eq!(first[id]["verdict"], "fail", "contour {id}");
    }
    assert!(rounds[0]["true_film_covered_max"].as_f64().unwrap() > 0.2);
    let hatched: Vec<i64> = rounds[0]["hatched"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_i64().unwrap())
        .collect();
    assert_eq!(hatched, blocked, "{:?}", rounds[0]);
    assert!(
        out.join("retrim_1")
            .join(format!("blocked_{}.csv", blocked[0]))
            .is_file()
    );
    // The retrim says, per opening, where its film's thickness came from: measured (both
    // sides seen) or the job's `[trim] film_thickness_um`.
    let line = stdout
        .lines()
        .find(|l| l.starts_with("retrim 1: blocked openings hatched:"))
        .unwrap_or_else(|| panic!("no retrim hatch line:\n{stdout}"));
    eprintln!("{line}");
    for id in &blocked {
        let from = line
            .split(&format!("contour {id} ("))
            .nth(1)
            .and_then(|rest| rest.split(')').next())
            .unwrap_or_else(|| panic!("contour {id} not in {line}"));
        assert!(
            from.contains("µm measured,") || from.contains("film 200 µm from the job,"),
            "contour {id}: {from}"
        );
    }
    let last = rounds.last().unwrap();
    let k = rounds.len();
    let end = inspected(&out.join(format!("verify_{k}")));
    for id in &blocked {
        let b = end[id]["blocked_fraction"].as_f64().unwrap();
        eprintln!(
            "contour {id}: blocked {:.3} → {b:.3}, verdict {}",
            first[id]["blocked_fraction"].as_f64().unwrap(),
            end[id]["verdict"]
        );
        assert!(b <= 0.1, "contour {id}: {b}");
        assert_eq!(end[id]["verdict"], "pass", "contour {id}: {:?}", end[id]);
    }
    assert_eq!(last["fail"], 0, "{last:?}");
    let film = last["true_film_covered_max"].as_f64().unwrap();
    eprintln!(
        "after {} retrim(s): twin's film cover max {:.2} %, residual web {:.1} µm, gouge {:.1} µm",
        k - 1,
        100.0 * film,
        last["true_residual_max_um"],
        last["true_gouge_max_um"]
    );
    assert!(film <= 0.005, "{last:?}");
    assert!(last["true_gouge_max_um"].as_f64().unwrap() <= SPOT_TOLERANCE_UM);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("blocked openings hatched"), "{report}");

    // Hatching off: the films stand, the retrim trims the rims again to no avail, and the part
    // still fails (exit 1) on the blocked openings.
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "[trim]\nhatch_blocked = false\n").unwrap();
    let off = tmp.path().join("off");
    let result = Command::new(TRIMCTL)
        .arg("run")
        .arg(&job)
        .args([
            "--verify",
            "--rounds",
            "1",
            "--demo-blockages",
            DEMO_BLOCKAGES,
            "--sim-time-scale",
            "0.01",
            "--out",
        ])
        .arg(&off)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("still fails inspection"), "{stderr}");
    let rounds = verify_rounds(&off);
    let last = rounds.last().unwrap();
    assert!(
        last["true_film_covered_max"].as_f64().unwrap() > 0.2,
        "{last:?}"
    );
    assert!(
        rounds
            .iter()
            .all(|r| r["hatched"].as_array().unwrap().is_empty())
    );
    let end = inspected(&off.join(format!("verify_{}", rounds.len())));
    let still = blocked_in(&end);
    eprintln!("hatching off: still blocked {still:?}");
    assert!(!still.is_empty());
    for id in &still {
        assert_eq!(end[id]["verdict"], "fail", "contour {id}");
    }
}
