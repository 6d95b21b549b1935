//! `trimctl frame` and `trimctl run --frame` on the planned demo job against the built-in
//! simulated cell: framing never opens the gate (no emission, no open gate, no marked vector),
//! the pointer is on while tracing and off after, and the traced outline covers every command
//! point of the layer; `run --frame` asks before each zone and answers come from stdin.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A planned demo run folder (registered and planned, nothing executed).
fn planned_demo(dir: &Path) {
    let out = Command::new(TRIMCTL)
        .args(["run", "--dry-run", "--out"])
        .arg(dir)
        .output()
        .expect("trimctl runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every command point of a layer of plan.json, in bits.
fn layer_points_bits(plan: &serde_json::Value, zone: u64, layer: u64) -> Vec<[i64; 2]> {
    let bits_per_mm = plan["settings"]["galvo"]["bits_per_mm"]
        .as_f64()
        .expect("bits_per_mm");
    let z = plan["zones"]
        .as_array()
        .expect("zones")
        .iter()
        .find(|z| z["id"].as_u64() == Some(zone))
        .expect("zone");
    let l = z["layers"]
        .as_array()
        .expect("layers")
        .iter()
        .find(|l| l["index"].as_u64() == Some(layer))
        .expect("layer");
    let mut out = Vec::new();
    for p in l["polylines"].as_array().expect("polylines") {
        let pts = if p["commands"].as_array().is_some_and(|c| !c.is_empty()) {
            &p["commands"]
        } else {
            &p["points"]
        };
        for xy in pts.as_array().expect("points") {
            let b = |k: usize| (xy[k].as_f64().expect("mm") * bits_per_mm).round() as i64;
            out.push([b(0), b(1)]);
        }
    }
    out
}

/// Inside or on the convex polygon (either orientation), exactly.
fn inside(v: &[[i64; 2]], p: [i64; 2]) -> bool {
    let n = v.len();
    let cross = |a: [i64; 2], b: [i64; 2]| {
        i128::from(b[0] - a[0]) * i128::from(p[1] - a[1])
            - i128::from(b[1] - a[1]) * i128::from(p[0] - a[0])
    };
    let s: Vec<i128> = (0..n)
        .map(|i| cross(v[i], v[(i + 1) % n]).signum())
        .collect();
    s.iter().all(|x| *x >= 0) || s.iter().all(|x| *x <= 0)
}

#[test]
fn framing_every_zone_traces_its_outline_with_the_pointer_and_never_opens_the_gate() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    planned_demo(&run);
    let report = tmp.path().join("frame.json");
    let out = Command::new(TRIMCTL)
        .arg("frame")
        .arg(&run)
        .args(["--passes", "2", "--sim-time-scale", "0.01", "--report"])
        .arg(&report)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("gate opened 0 times"), "{stdout}");
    assert!(stdout.contains("off at the end: yes"), "{stdout}");

    let plan = json(&run.join("plan.json"));
    let r = json(&report);
    let zones = plan["zones"].as_array().unwrap();
    let framed = r["framed"].as_array().unwrap();
    assert_eq!(framed.len(), zones.len(), "every zone framed");
    let sim = &r["sim"];
    assert_eq!(sim["gate_opened"], 0);
    assert_eq!(sim["emission_on"], 0);
    assert_eq!(sim["marked_vectors"], 0);
    assert_eq!(sim["traced_without_pointer"], 0);
    assert_eq!(sim["pointer_on_at_end"], false);
    assert_eq!(sim["violations"].as_array().unwrap().len(), 0);
    assert_eq!(sim["pointer_on"].as_u64().unwrap() as usize, zones.len());
    let traces = sim["traces"].as_array().unwrap();
    for t in traces {
        assert_eq!(
            (&t["pointer"], &t["gate_open"], &t["emission"]),
            (
                &serde_json::json!(true),
                &serde_json::json!(false),
                &serde_json::json!(false)
            ),
            "{t}"
        );
    }
    for (f, z) in framed.iter().zip(zones) {
        let zone = z["id"].as_u64().unwrap();
        let layer = z["layers"][0]["index"].as_u64().unwrap();
        assert_eq!(
            (f["key"]["zone"].as_u64(), f["key"]["layer"].as_u64()),
            (Some(zone), Some(layer))
        );
        assert_eq!(f["passes_done"], 2);
        // The polygon the simulator traced (pass 0 of this layer's frame list).
        let tag = 0xF000_0000_u64 | (zone << 16) | layer;
        let polygon: Vec<[i64; 2]> = traces
            .iter()
            .filter(|t| t["tag"].as_u64() == Some(tag) && t["pass"] == 0)
            .map(|t| {
                [
                    t["from_bits"][0].as_i64().unwrap(),
                    t["from_bits"][1].as_i64().unwrap(),
                ]
            })
            .collect();
        assert!(!polygon.is_empty(), "zone {zone}: nothing traced");
        for p in layer_points_bits(&plan, zone, layer) {
            assert!(
                inside(&polygon, p),
                "zone {zone}: {p:?} outside {polygon:?}"
            );
        }
    }

    // No terminal and no bound: refused, nothing moves.
    let out = Command::new(TRIMCTL)
        .arg("frame")
        .arg(&run)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--passes N or --seconds S"));
    let out = Command::new(TRIMCTL)
        .arg("frame")
        .arg(&run)
        .args(["--zone", "9999", "--passes", "1"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no zone 9999"));
    // A trace time beyond a day is refused before anything moves (1e300 s panicked in the
    // timer), and so is one that is not a number > 0.
    for seconds in ["1e300", "86401", "nan", "0"] {
        let out = Command::new(TRIMCTL)
            .arg("frame")
            .arg(&run)
            .args(["--seconds", seconds])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "--seconds {seconds}: {stderr}");
        assert!(
            stderr.contains("--seconds: must be a number > 0 and at most 86400"),
            "{stderr}"
        );
    }
    // A job file cut short is refused with the parser's message once.
    let cut = tmp.path().join("cut.json");
    let text = std::fs::read_to_string(run.join("plan.json")).unwrap();
    std::fs::write(&cut, &text[..text.len() / 2]).unwrap();
    let out = Command::new(TRIMCTL)
        .arg("frame")
        .arg(&cut)
        .args(["--passes", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("not a valid job: EOF while parsing"),
        "{stderr}"
    );
    assert_eq!(stderr.matches("EOF while parsing").count(), 1, "{stderr}");
}

#[test]
fn run_frame_asks_before_each_zone_and_quit_stops_the_run_resumably() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let mut child = Command::new(TRIMCTL)
        .args(["run", "--frame", "--sim-time-scale", "0.01", "--out"])
        .arg(&run)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Zone 1: reframe, then mark; zone 2: quit.
    child.stdin.take().unwrap().write_all(b"r\n\nq\n").unwrap();
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stdout}\n{stderr}");
    assert_eq!(
        stderr.matches("[Enter] mark, r reframe, q quit").count(),
        3,
        "{stderr}"
    );
    assert_eq!(stdout.matches("framed zone").count(), 3, "{stdout}");
    assert!(stderr.contains("--resume"), "{stderr}");
    assert!(!stderr.contains("violation"), "{stderr}");

    let plan = json(&run.join("plan.json"));
    let zones = plan["zones"].as_array().unwrap();
    let first = zones[0]["id"].as_u64().unwrap();
    let done: Vec<(u64, u64)> = std::fs::read_to_string(run.join("journal.jsonl"))
        .unwrap()
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|e| e["kind"] == "layer_done")
        .map(|e| {
            (
                e["key"]["zone"].as_u64().unwrap(),
                e["key"]["layer"].as_u64().unwrap(),
            )
        })
        .collect();
    let first_layers = zones[0]["layers"].as_array().unwrap().len();
    assert_eq!(done.len(), first_layers, "{done:?}");
    assert!(done.iter().all(|(z, _)| *z == first), "{done:?}");
}

/// `trimctl frame` on a hand-edited plan whose pose leaves `[machine]`'s travel refuses before
/// anything moves (exit 1), naming the layer, the axis and the limit.
#[test]
fn frame_refuses_a_hand_edited_pose_outside_the_machine_limits() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    planned_demo(&dir);
    let plan_path = dir.join("plan.json");
    let mut plan = json(&plan_path);
    let zone = plan["zones"][0]["id"].as_u64().expect("zone id");
    let layer = plan["zones"][0]["layers"][0]["index"]
        .as_u64()
        .expect("layer index");
    plan["zones"][0]["layers"][0]["pose"]["x"] = serde_json::json!(500.0);
    std::fs::write(&plan_path, serde_json::to_string(&plan).unwrap()).unwrap();
    let report = tmp.path().join("frame.json");
    let out = Command::new(TRIMCTL)
        .arg("frame")
        .arg(&dir)
        .args(["--zone", &zone.to_string(), "--passes", "1", "--report"])
        .arg(&report)
        .output()
        .expect("trimctl runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    for want in [
        format!("zone {zone} layer {layer}"),
        "X = 500.000 mm outside".to_owned(),
        "refusing to move there".to_owned(),
    ] {
        assert!(stderr.contains(&want), "{want:?} missing: {stderr}");
    }
    assert!(!report.exists(), "framed anyway");
}

/// `trimctl frame` takes its way down (pointer off, exit 3) on SIGTERM, SIGHUP and SIGQUIT as
/// on Ctrl-C.
#[test]
fn frame_stops_on_each_stop_signal() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    planned_demo(&dir);
    for sig in ["TERM", "HUP", "QUIT"] {
        let stderr_path = tmp.path().join(format!("{sig}.stderr"));
        let mut child = Command::new(TRIMCTL)
            .arg("frame")
            .arg(&dir)
            .args(["--seconds", "60", "--sim-time-scale", "1.0"])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr_path).unwrap())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_secs(3));
        assert!(child.try_wait().unwrap().is_none(), "SIG{sig}: ended early");
        let killed = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(killed.success());
        let status = child.wait().unwrap();
        let stderr = std::fs::read_to_string(&stderr_path).unwrap();
        assert_eq!(status.code(), Some(3), "SIG{sig}: {stderr}");
        assert!(
            stderr.contains(&format!("SIG{sig}")) && stderr.contains("the pointer is off"),
            "SIG{sig}: {stderr}"
        );
    }
}
