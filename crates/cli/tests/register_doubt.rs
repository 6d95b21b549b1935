//! A part in doubt (`registration.json`'s `global.in_doubt`): `trimctl register` writes its
//! outputs, exits 0, names the reason in its summary, and flags `part_in_doubt` every contour
//! whose bound exceeds `quality.doubt_bound_fraction` of the tolerance and every strip that
//! shares an end with a strip so flagged (named in the reason), the others trusted; an
//! out-of-range fraction is refused naming the key. Its picture (`--svg`) draws every contour,
//! the flagged ones as such, under the part's verdict.

#![expect(
    clippy::unwrap_used,
    reason = "test code: a failure should stop loudly"
)]

use std::path::Path;
use std::process::{Command, Output};

use trim_geom::formats::read_path;
use trim_register::regional::strips_sharing_ends;

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

/// Checks a part in doubt's flags against its bounds at 1.5σ over `limit_um` and the strips
/// sharing an end with an untrusted one (named in the reason); returns how many are flagged
/// `part_in_doubt`, how many trusted, and the ids of the strips flagged for a neighbour.
fn doubt_flags(
    report: &serde_json::Value,
    case: &Path,
    limit_um: f64,
) -> (usize, usize, Vec<String>) {
    let reason = report["global"]["in_doubt"].as_str().expect("in doubt");
    let contours = report["contours"].as_array().unwrap();
    let flags_of = |c: &serde_json::Value| -> Vec<String> {
        c["flags"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_str().unwrap().to_owned())
            .collect()
    };
    // Untrusted before the strips beside them are: any other flag, or the bound over the limit.
    let untrusted_first: Vec<bool> = contours
        .iter()
        .map(|c| {
            flags_of(c).iter().any(|f| f != "part_in_doubt")
                || c["doubt_bound_um"].as_f64().unwrap() > limit_um
        })
        .collect();
    let path = read_path(&case.join("path.csv")).unwrap();
    let points: Vec<&[trim_geom::Point3]> = path.contours().iter().map(|c| c.points()).collect();
    let joins = strips_sharing_ends(&points);
    let beside: Vec<String> = (0..contours.len())
        .filter(|&i| !untrusted_first[i] && joins[i].iter().any(|&j| untrusted_first[j]))
        .map(|i| contours[i]["id"].to_string())
        .collect();
    if !beside.is_empty() {
        let named = format!(
            "strip{} {} beside an untrusted strip",
            if beside.len() > 1 { "s" } else { "" },
            beside.join(", ")
        );
        assert!(reason.contains(&named), "{named}: {reason}");
    } else {
        assert!(!reason.contains("beside an untrusted strip"), "{reason}");
    }
    let (mut doubted_n, mut trusted_n) = (0, 0);
    for (i, c) in contours.iter().enumerate() {
        // The part's rules count a contour by its bound at 1.5σ (`doubt_bound_um`), never
        // above the reported one (at 2.1σ).
        let bound = c["doubt_bound_um"].as_f64().unwrap();
        assert!(
            bound > 0.0 && bound <= c["predicted_max_error_um"].as_f64().unwrap() + 1e-9,
            "{c}"
        );
        let flags = flags_of(c);
        let in_doubt = flags.iter().any(|f| f == "part_in_doubt");
        let trusted = c["trustworthy"].as_bool().unwrap();
        let by_join = beside.contains(&c["id"].to_string());
        assert_eq!(in_doubt, bound > limit_um || by_join, "{c}");
        assert_eq!(by_join, !untrusted_first[i] && !trusted, "{c}");
        if trusted {
            assert!(bound <= limit_um && flags.is_empty(), "{c}");
            trusted_n += 1;
        }
        doubted_n += usize::from(in_doubt);
    }
    (doubted_n, trusted_n, beside)
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
    // The P95 risk: each contour's, summed over the trusted ones, printed as the report has it.
    let trusted_risks: Vec<f64> = report["contours"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["trustworthy"].as_bool().unwrap())
        .map(|c| c["p95_risk"].as_f64().expect("a P95 risk"))
        .collect();
    assert!(trusted_risks.iter().all(|r| (0.0..=1.0).contains(r)));
    let expected = report["global"]["expected_over_p95"].as_f64().unwrap();
    assert!((expected - trusted_risks.iter().sum::<f64>()).abs() < 1e-9);
    assert_eq!(report["global"]["p95_limit_um"].as_f64(), Some(12.0));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains(&format!(
            "cross-edge P95 limit 12 µm: {expected:.2} of the {} trusted contours expected beyond it",
            trusted_risks.len()
        )),
        "{stdout}"
    );

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
    let (doubted_n, trusted_n, beside) = doubt_flags(&report, &case, 15.0);
    // On this part the strips sharing ends are flagged by their own bounds: none beside.
    assert!(beside.is_empty(), "{beside:?}");
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

    // At 0.7 of the tolerance (21 µm) the end strips of this part keep their own bounds, and
    // the strips sharing an end with them are flagged for it (two on this seed).
    std::fs::write(
        &job,
        "[register.quality]\nmax_untrusted_fraction = 0.05\ndoubt_bound_fraction = 0.7\n",
    )
    .unwrap();
    let wider = tmp.path().join("wider.json");
    let out = register(&case, Some(&job), &wider);
    assert!(out.status.success());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&wider).unwrap()).unwrap();
    let (_, _, beside) = doubt_flags(&report, &case, 21.0);
    assert!(!beside.is_empty(), "the rule is exercised");

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
