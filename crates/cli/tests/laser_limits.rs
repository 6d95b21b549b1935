//! Laser operating limits (issue 14, part 4): `trimctl beam`, `plan` and `run` refuse a
//! `[beam]` operating point outside the limits of `cell.laser_profile` (exit 1, one line naming
//! the limit, the value, the profile and the job.toml keys), and the paper's figures and the demo
//! pass on the default profile.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

/// The paper's operating point on a 40 µJ source: 214.36 µJ is refused.
const PAPER_ON_MONACO: &str = "[cell]\nlaser_profile = \"monaco\"\n";

/// 70 W on the default 60 W source (70 W at 1 MHz is 70 µJ, within its 250 µJ).
const OVER_POWER: &str = "[beam]\npower_w = 70.0\nrepetition_rate_hz = 1000000.0\n";

/// 3 MHz on the default 200–2000 kHz source (20 W at 3 MHz is 6.7 µJ).
const OVER_RATE: &str = "[beam]\npower_w = 20.0\nrepetition_rate_hz = 3000000.0\n";

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write a test file");
    p
}

fn trimctl(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(TRIMCTL)
        .args(args)
        .output()
        .expect("trimctl runs")
}

/// Exit 1 and one error line holding every part of `named`.
fn refused(out: &Output, named: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("trimctl: error:"))
        .unwrap_or_else(|| panic!("no error line in {stderr}"));
    for part in named {
        assert!(line.contains(part), "{part:?} missing from {line:?}");
    }
}

/// What each out-of-limit job must name.
fn cases() -> [(&'static str, &'static str, Vec<&'static str>); 3] {
    [
        (
            "paper_on_monaco.toml",
            PAPER_ON_MONACO,
            vec![
                "cell.laser_profile = \"monaco\"",
                "laser profile \"monaco\"",
                "pulse energy 214.36 µJ",
                "beam.power_w / beam.repetition_rate_hz",
                "limits.pulse_energy_uj_max = 40 µJ",
                "crates/io/profiles/monaco.toml",
            ],
        ),
        (
            "over_power.toml",
            OVER_POWER,
            vec![
                "laser profile \"high-energy\"",
                "average power 70 W (beam.power_w) is above limits.average_power_w_max = 60 W",
            ],
        ),
        (
            "over_rate.toml",
            OVER_RATE,
            vec![
                "laser profile \"high-energy\"",
                "repetition rate 3000 kHz (beam.repetition_rate_hz) is above \
                 limits.rep_rate_khz_max = 2000 kHz",
            ],
        ),
    ]
}

#[test]
fn beam_prints_the_papers_figures_on_the_default_profile_and_refuses_points_outside_a_profile() {
    let out = trimctl(&["beam".as_ref()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let figures: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let get = |k: &str| figures[k].as_f64().unwrap_or(f64::NAN);
    // Paper §2.1: E = 214.36 µJ, w0 ≈ 20.4 µm, F0 = 32.7248 J/cm² (to the rounding of D).
    assert!((get("pulse_energy_uj") - 214.36).abs() < 1e-6, "{figures}");
    assert!((get("waist_radius_um") - 20.4).abs() < 0.05, "{figures}");
    assert!(
        (get("peak_fluence_j_per_cm2") - 32.7248).abs() < 0.016,
        "{figures}"
    );
    assert!(
        stderr.contains("laser profile \"high-energy\": 214.36 µJ of 250 µJ, 53.59 W of 60 W, 250 kHz in 200-2000 kHz"),
        "{stderr}"
    );

    let tmp = tempfile::tempdir().expect("temp dir");
    // Within monaco's limits: 10 W at 250 kHz = 40 µJ, exactly its limit.
    let ok = write(
        tmp.path(),
        "monaco_40uj.toml",
        "[cell]\nlaser_profile = \"monaco\"\n[beam]\npower_w = 10.0\n",
    );
    let out = trimctl(&["beam".as_ref(), "--config".as_ref(), ok.as_os_str()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (name, text, named) in cases() {
        let job = write(tmp.path(), name, text);
        let out = trimctl(&["beam".as_ref(), "--config".as_ref(), job.as_os_str()]);
        refused(&out, &named);
        assert!(
            out.stdout.is_empty(),
            "{name}: no figures for a refused point"
        );
    }
}

#[test]
fn plan_refuses_points_outside_the_profile_before_planning_and_plans_the_papers_point() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let csv = tmp.path().join("core.csv");
    let out = trimctl(&[
        "synth".as_ref(),
        "--out".as_ref(),
        tmp.path().join("case").as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::copy(tmp.path().join("case").join("path.csv"), &csv).expect("the case has a path");
    let plan = |config: Option<&Path>, out_json: &Path| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "plan".as_ref(),
            "--path".as_ref(),
            csv.as_os_str(),
            "--out".as_ref(),
            out_json.as_os_str(),
        ];
        if let Some(c) = config {
            args.extend(["--config".as_ref(), c.as_os_str()]);
        }
        trimctl(&args)
    };
    for (name, text, named) in cases() {
        let job = write(tmp.path(), name, text);
        let out_json = tmp.path().join(format!("{name}.json"));
        refused(&plan(Some(&job), &out_json), &named);
        assert!(!out_json.exists(), "{name}: a refused plan writes nothing");
    }
    // The defaults: the paper's operating point on the high-energy profile.
    let out_json = tmp.path().join("paper.json");
    let out = plan(None, &out_json);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let job: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out_json).expect("the plan is written"))
            .expect("the plan is JSON");
    assert_eq!(job["settings"]["beam"]["power_w"], 53.59);
    assert_eq!(job["settings"]["beam"]["repetition_rate_hz"], 250000.0);
}

#[test]
fn run_refuses_points_outside_the_profile_before_anything_starts_and_the_demo_passes() {
    let tmp = tempfile::tempdir().expect("temp dir");
    for (name, text, named) in cases() {
        let job = write(tmp.path(), name, text);
        let run_dir = tmp.path().join(format!("run_{name}"));
        let out = trimctl(&[
            "run".as_ref(),
            job.as_os_str(),
            "--out".as_ref(),
            run_dir.as_os_str(),
        ]);
        refused(&out, &named);
        assert!(
            !run_dir.exists(),
            "{name}: a refused job must not create a run folder"
        );
    }
    // The demo's default laser is within its profile: a dry run registers, plans and writes
    // the run folder, whose effective job names the profile and the paper's operating point.
    let run_dir = tmp.path().join("demo");
    let out = trimctl(&[
        "run".as_ref(),
        "--dry-run".as_ref(),
        "--out".as_ref(),
        run_dir.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let effective = std::fs::read_to_string(run_dir.join("job.toml")).expect("job.toml");
    let effective: toml::Table = effective.parse().expect("job.toml is TOML");
    assert_eq!(
        effective["cell"]["laser_profile"].as_str(),
        Some("high-energy")
    );
    assert_eq!(effective["beam"]["power_w"].as_float(), Some(53.59));
    assert_eq!(
        effective["beam"]["repetition_rate_hz"].as_float(),
        Some(250000.0)
    );
}
