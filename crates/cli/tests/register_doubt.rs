//! A part in doubt (`registration.json`'s `global.in_doubt`): `trimctl register` writes its
//! outputs, exits 0, names the reason in its summary, and flags `part_in_doubt` every contour
//! whose bound exceeds `quality.doubt_bound_fraction` of the tolerance, the others trusted; an
//! out-of-range fraction is refused naming the key. Its picture (`--svg`) draws every contour,
//! the flagged ones as such, under the part's verdict.

use std::path::Path;
use std::process::{Command, Output};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

fn register(case: &Path, config: Option<&Path>, report: &Path) -> Output {
    register_with(case, config, report, &[])
}

fn register_with(case: &Path, config: Option<&Path>, report: &Path, extra: &[&str]) -> Output {
    let mut cmd = Command::new(TRIMCTL);
    cmd.arg("register")
        .arg("--cad")
        .arg(case.join("cad.stl"))
        .arg("--scan")
        .arg(case.join("scan.ply"))
        .arg("--path")
        .arg(case.join("path.csv"))
        .arg("--out")
        .arg(report.with_extension("csv"))
        .arg("--report")
        .arg(report);
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    cmd.args(extra);
    cmd.output().expect("trimctl register runs")
}

#[test]
fn a_part_in_doubt_keeps_the_contours_whose_bound_is_within_half_the_tolerance() {
    let tmp = tempfile::tempdir().unwrap();
    let case = tmp.path().join("case");
    let status = Command::new(TRIMCTL)
        .args(["synth", "--seed", "5", "--scan-points", "150000", "--out"])
        .arg(&case)
        .status()
        .unwrap();
    assert!(status.success());

    // With the defaults this part is neither refused nor in doubt.
    let plain = tmp.path().join("plain.json");
    let out = register(&case, None, &plain);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&plain).unwrap()).unwrap();
    assert!(report["global"]["in_doubt"].is_null());
    assert!(report["global"]["refused"].is_null());

    // A stricter part-level gate: more than a twentieth flagged puts it in doubt.
    let job = tmp.path().join("job.toml");
    std::fs::write(&job, "[register.quality]\nmax_untrusted_fraction = 0.05\n").unwrap();
    let doubted = tmp.path().join("doubted.json");
    let picture = tmp.path().join("doubted.svg");
    let out = register_with(
        &case,
        Some(&job),
        &doubted,
        &["--svg", picture.to_str().unwrap()],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("part in doubt: "), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&doubted).unwrap()).unwrap();
    let reason = report["global"]["in_doubt"].as_str().expect("in doubt");
    assert!(
        reason.contains("quality.max_untrusted_fraction (5 %)"),
        "{reason}"
    );
    assert!(reason.contains("exceeds 15 µm"), "{reason}");
    assert!(report["global"]["refused"].is_null());
    let contours = report["contours"].as_array().unwrap();
    let (mut doubted_n, mut trusted_n) = (0, 0);
    for c in contours {
        // The part's rules count a contour by its bound at 1.5σ (`doubt_bound_um`), never
        // above the reported one (at 2.1σ).
        let bound = c["doubt_bound_um"].as_f64().unwrap();
        assert!(
            bound > 0.0 && bound <= c["predicted_max_error_um"].as_f64().unwrap() + 1e-9,
            "{c}"
        );
        let flags: Vec<&str> = c["flags"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_str().unwrap())
            .collect();
        let trusted = c["trustworthy"].as_bool().unwrap();
        assert_eq!(flags.contains(&"part_in_doubt"), bound > 15.0, "{c}");
        if trusted {
            assert!(bound <= 15.0 && flags.is_empty(), "{c}");
            trusted_n += 1;
        }
        doubted_n += usize::from(flags.contains(&"part_in_doubt"));
    }
    // Both kinds occur on this part: the rule is exercised, not vacuous.
    assert!(doubted_n > 0 && trusted_n > 0, "{doubted_n} / {trusted_n}");
    assert_eq!(
        report["global"]["untrustworthy"].as_u64().unwrap() as usize,
        contours.len() - trusted_n
    );
    // The picture: every contour once, the flagged ones marked and listed, the verdict above.
    let svg = std::fs::read_to_string(&picture).unwrap();
    assert_eq!(svg.matches(r#"class="contour "#).count(), contours.len());
    assert_eq!(
        svg.matches(r#"class="contour flagged""#).count(),
        contours.len() - trusted_n
    );
    assert!(svg.contains(&format!(
        "{trusted_n} of {} contours trusted (tolerance 30 µm)",
        contours.len()
    )));
    assert!(svg.contains("part in doubt: "), "the verdict line");
    for c in contours
        .iter()
        .filter(|c| !c["trustworthy"].as_bool().unwrap())
    {
        let id = c["id"].as_i64().unwrap();
        assert!(svg.contains(&format!(r#"class="contour flagged" data-id="{id}""#)));
    }

    // Out of range: refused naming the key, nothing registered.
    std::fs::write(&job, "[register.quality]\ndoubt_bound_fraction = 1.5\n").unwrap();
    let bad = tmp.path().join("bad.json");
    let out = register(&case, Some(&job), &bad);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("quality.doubt_bound_fraction"), "{stderr}");
    assert!(!bad.exists());

    // A datum fit has no per-contour bounds to draw: the two are refused together.
    let out = register_with(
        &case,
        None,
        &bad,
        &["--svg", "x.svg", "--datums", "datums.txt"],
    );
    // A usage error (trimctl's exit 1, clap's message).
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--svg") && stderr.contains("--datums"),
        "{stderr}"
    );
}
