//! Regional registration on synthetic ceramic cores: accuracy against ground truth, capture
//! range, reported failures and determinism.

use trim_geom::{Path, PointCloud, Similarity3, Vector3};
use trim_register::RegisterError;
use trim_register::eval::path_errors;
use trim_register::regional::{Flag, RegisterSettings, Registration, register};
use trim_register::scaled_icp_baseline::{PaperSettings, paper_method};
use trim_synth::{SynthCase, SynthParams, generate};

#[path = "common/untrimmed.rs"]
mod untrimmed;
use untrimmed::{register_untrimmed, register_untrimmed_with, untrimmed_case};

/// The issue's targets, mm.
const CROSS_EDGE_P95_MM: f64 = 0.020;
const CROSS_EDGE_MAX_MM: f64 = 0.050;
const POINTWISE_P95_MM: f64 = 0.030;
/// The coarse stage's isotropic scale against the best similarity of the true deformation
/// (see the test for the measured values).
const SCALE_TOL: f64 = 0.0015;

/// Small enough for the test profile, dense enough for the targets.
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a generator failure must fail the test"
)]
fn case(seed: u64, large: bool) -> SynthCase {
    let (sag_mm, twist_deg, scale_range, pose_deg, pose_mm) = if large {
        (0.5, 1.0, 0.02, 5.0, 3.0)
    } else {
        (0.2, 0.4, 0.005, 2.0, 1.0)
    };
    generate(&SynthParams {
        seed,
        sag_mm,
        twist_deg,
        scale_range,
        pose_deg,
        pose_mm,
        scan_points: 120_000,
        cad_points: 200_000,
        // A scanner fixed to the machine, looking from three directions (issue 21).
        scanner_views: 3,
        ..SynthParams::default()
    })
    .unwrap()
}

fn settings(case: &SynthCase) -> RegisterSettings {
    RegisterSettings {
        scanner_viewpoint_mm: Some(case.scanner_in_scan.coords.into()),
        ..RegisterSettings::default()
    }
}

#[test]
fn meets_the_accuracy_targets_on_mild_and_large_deformation() {
    for (seed, large) in [(11, false), (12, true)] {
        let c = case(seed, large);
        let reg = register(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &settings(&c),
        )
        .unwrap();
        let e = path_errors(&reg.path, &c.truth, |_| true).unwrap();
        assert!(
            e.cross_edge_p95_mm <= CROSS_EDGE_P95_MM
                && e.cross_edge_max_mm <= CROSS_EDGE_MAX_MM
                && e.pointwise_p95_mm <= POINTWISE_P95_MM,
            "seed {seed} large {large}: {e:?}"
        );
        // The coarse stage absorbed the fixture error and the scale. Reference: the best single
        // similarity for the true deformation, an independent closed form (Umeyama on every CAD
        // point and its deformed position). The coarse fit is not that least-squares fit
        // (point-to-plane, scan side only, Huber), and sag and twist pull on it: measured
        // |fitted − reference| = 0.00038 (mild) and 0.00099 (large). SCALE_TOL is 1.5× the
        // larger. The synthetic axis scales span ±0.005 (mild) and ±0.02 (large), so the old
        // 0.03 passed any scale, 1 included; the second check fails a fit that did not absorb
        // the scale at all (|1 − reference| = 0.0010 mild, 0.0045 large).
        let cad = c.cad_points.points();
        let deformed: Vec<_> = cad.iter().map(|p| c.deformation.apply(p)).collect();
        let reference = trim_register::umeyama::umeyama(cad, &deformed, true)
            .unwrap()
            .target_from_source
            .scaling();
        let scale = reg.scan_from_cad.scaling();
        // The second check only where it can tell: a case whose best similarity's scale lies
        // within SCALE_TOL of 1 cannot show whether the fit absorbed it.
        assert!(
            (scale - reference).abs() < SCALE_TOL
                && ((1.0 - reference).abs() < SCALE_TOL
                    || (scale - reference).abs() < (1.0 - reference).abs()),
            "seed {seed} large {large}: scale {scale}, reference {reference}"
        );
    }
}

#[test]
fn beats_the_papers_method_by_the_issues_factors() {
    // Mild: at least 2× better; large: the paper's method is ≥ 20× worse than our P95.
    for (seed, large, factor) in [(21, false, 2.0), (22, true, 20.0)] {
        let c = case(seed, large);
        let ours = register(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &settings(&c),
        )
        .unwrap();
        let ours = path_errors(&ours.path, &c.truth, |_| true).unwrap();
        let paper = paper_method(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &PaperSettings::default(),
        )
        .unwrap();
        let paper = path_errors(&paper, &c.truth, |_| true).unwrap();
        assert!(
            paper.cross_edge_p95_mm >= factor * ours.cross_edge_p95_mm,
            "seed {seed}: paper {paper:?} vs ours {ours:?}"
        );
    }
}

#[test]
fn refuses_a_scan_that_does_not_overlap_the_cad_or_is_at_one_place() {
    let c = case(31, false);
    let far = c
        .scan
        .transformed(&Similarity3::new(
            Vector3::new(0.0, 0.0, 200.0),
            Vector3::zeros(),
            1.0,
        ))
        .unwrap();
    let err = register(
        &c.cad_points,
        &far,
        &c.path,
        &c.scan_from_cad_nominal,
        &settings(&c),
    )
    .unwrap_err();
    // The centroid start finds the part 200 mm from the fixture's pose: refused as beyond the
    // capture range, with the distance.
    assert!(
        matches!(err, RegisterError::OutsideCaptureRange { translation_mm, .. } if (translation_mm - 200.0).abs() < trim_register::regional::CAPTURE_MARGIN_MM),
        "{err}"
    );
    let err = register(
        &c.cad_points,
        &PointCloud::default(),
        &c.path,
        &c.scan_from_cad_nominal,
        &settings(&c),
    )
    .unwrap_err();
    assert!(matches!(err, RegisterError::EmptyCloud { .. }), "{err}");
    // One point, and copies of it: refused by what it is, not as "0 correspondences".
    for n in [1, 100] {
        let at = PointCloud::new(vec![c.scan.points()[7]; n]).unwrap();
        let err = register(
            &c.cad_points,
            &at,
            &c.path,
            &c.scan_from_cad_nominal,
            &settings(&c),
        )
        .unwrap_err();
        assert!(
            matches!(err, RegisterError::AtOnePlace { which: "scan", points, .. } if points == n),
            "{err}"
        );
        assert!(err.to_string().contains("all at one place"), "{err}");
    }
}

#[test]
fn flags_a_contour_without_scan_points_and_keeps_the_rest() {
    let c = case(41, false);
    // Remove every scan point within 3 mm of contour 20's true position.
    let hole = c.truth.get(20).unwrap();
    let keep: Vec<usize> = (0..c.scan.len())
        .filter(|&i| {
            hole.points()
                .iter()
                .all(|p| (c.scan.points()[i] - p).norm() > 3.0)
        })
        .collect();
    let scan = c.scan.select(&keep).unwrap();
    let reg = register(
        &c.cad_points,
        &scan,
        &c.path,
        &c.scan_from_cad_nominal,
        &settings(&c),
    )
    .unwrap();
    let q = reg.report.contours.iter().find(|q| q.id == 20).unwrap();
    assert!(!q.trustworthy, "{q:?}");
    assert!(
        q.flags.contains(&Flag::LowCoverage) || q.flags.contains(&Flag::NoScanPoints),
        "{q:?}"
    );
    // Coverage flags only on the emptied contour and its neighbours; beyond them only the
    // predicted bound may flag, within the false-alarm budget (issue 21: 5 % of the contours).
    let coverage_flagged = reg
        .report
        .contours
        .iter()
        .filter(|q| q.flags.contains(&Flag::LowCoverage) || q.flags.contains(&Flag::NoScanPoints))
        .count();
    let bound_only = reg
        .report
        .contours
        .iter()
        .filter(|q| !q.trustworthy && q.flags == [Flag::PredictedError])
        .count();
    let flagged = reg
        .report
        .contours
        .iter()
        .filter(|q| !q.trustworthy)
        .count();
    assert!(
        coverage_flagged <= 3
            && (bound_only as f64) <= 0.05 * reg.report.contours.len() as f64
            && flagged == coverage_flagged + bound_only,
        "{flagged} contours flagged: {:?}",
        reg.report
            .contours
            .iter()
            .filter(|q| !q.trustworthy)
            .collect::<Vec<_>>()
    );
    // The contour still moves with the field from its neighbours (pinned by them).
    let trusted = |id: i64| {
        reg.report
            .contours
            .iter()
            .any(|q| q.id == id && q.trustworthy)
    };
    let e = path_errors(&reg.path, &c.truth, trusted).unwrap();
    assert!(e.cross_edge_p95_mm <= CROSS_EDGE_P95_MM, "{e:?}");
}

#[test]
fn is_deterministic_to_the_bit_on_any_thread_count() {
    let c = generate(&SynthParams {
        seed: 51,
        scan_points: 40_000,
        cad_points: 80_000,
        ..SynthParams::default()
    })
    .unwrap();
    let s = settings(&c);
    let run = || {
        register(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &s,
        )
        .unwrap()
    };
    let a = run();
    let b = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(run);
    let bits = |p: &Path| {
        p.points()
            .flat_map(|q| q.coords.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            .collect::<Vec<u64>>()
    };
    assert_eq!(bits(&a.path), bits(&b.path));
    assert_eq!(
        a.scan_from_cad.to_homogeneous(),
        b.scan_from_cad.to_homogeneous()
    );
}

#[test]
fn settings_refuse_out_of_range_keys_by_name() {
    let mut s = RegisterSettings::default();
    s.field.spacing_mm = -1.0;
    let e = s.validate().unwrap_err().to_string();
    assert!(e.contains("field.spacing_mm"), "{e}");
    let e = toml::from_str::<RegisterSettings>("[field]\nspacing = 3.0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("spacing"), "{e}");
    let parsed: RegisterSettings =
        toml::from_str("mode = \"global\"\n[field]\nsmoothness = 0.5\n").unwrap();
    assert_eq!(parsed.field.smoothness, 0.5);
    assert_eq!(
        parsed.field.spacing_mm,
        RegisterSettings::default().field.spacing_mm
    );
}

/// A registration whose cancel flag is set (Ctrl-C in Python) stops with `Cancelled` instead of
/// running on; the loops check the flag every iteration (tests/python/test_cancel.py measures
/// that the work stops).
#[test]
fn a_cancelled_registration_stops_with_cancelled() {
    let c = case(31, false);
    let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let e = trim_geom::cancel::run_cancellable(flag, || {
        register(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &RegisterSettings::default(),
        )
    })
    .expect_err("a cancelled registration");
    assert!(
        matches!(e, RegisterError::Geom(trim_geom::GeomError::Cancelled)),
        "{e}"
    );
}

/// Burrs and films in the scan do not pull the field (issue 21: "registration must not be
/// pulled by them"). The untrimmed core of the inspection's detection test: one view fixed to
/// the machine, 500k points, burr webs 0.05–0.6 mm tall on 30 % of the contours, films over 15 %
/// of the openings. A web standing off an edge in its wall's plane, or a film over a hole,
/// matched to the wall beside it, pulled the field along the span: on this seed 13 contours near
/// the part's end erred over 30 µm (up to 47 µm), 3 of them unflagged. The field now leaves out matches whose
/// scan normal turns from the CAD face's, or that lie beyond the face's extent.
#[test]
fn burrs_and_films_in_the_scan_do_not_pull_the_field() {
    let c = untrimmed_case(305);
    assert!(!c.burrs.is_empty() && !c.blockages.is_empty());
    assert_burrs_do_not_pull(&c, &register_untrimmed(&c));
}

/// The same with the edge terms on (`quality.edge_terms`, off by default): the scanned edges
/// move the field, and flash must not. Contour 47 carries a 53 µm web over 13 of its 20 mm;
/// its stretch reads +41 µm and, before readings of material beyond the contour were left
/// out, pulled contours 47–48 40 µm off.
#[test]
fn with_edge_terms_burrs_still_do_not_pull_the_field() {
    let c = untrimmed_case(305);
    let reg = register_untrimmed_with(&c, |s| s.quality.edge_terms = true);
    let terms = reg.report.global.edge_terms.expect("the edge terms ran");
    assert!(terms.used > 0 && terms.flashed > 0, "{terms:?}");
    assert_burrs_do_not_pull(&c, &reg);
}

/// No contour over 30 µm, none of them trusted, at most 13 flagged and the trusted ones'
/// cross-edge P95 within 12 µm.
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a failed measure must fail the test"
)]
fn assert_burrs_do_not_pull(c: &SynthCase, reg: &Registration) {
    let mut report = Vec::new();
    let mut over = 0;
    let mut silent = 0;
    for q in &reg.report.contours {
        let e = path_errors(&reg.path, &c.truth, |id| id == q.id).unwrap();
        let worst = e.cross_edge_max_mm.max(e.pointwise_p95_mm);
        if worst > 0.030 {
            over += 1;
            silent += usize::from(q.trustworthy);
        }
        report.push(format!(
            "{}: cross max {:.1} µm, bound {:.1} µm, trusted {}",
            q.id,
            1e3 * e.cross_edge_max_mm,
            q.predicted_max_error_um,
            q.trustworthy
        ));
    }
    let flagged = reg
        .report
        .contours
        .iter()
        .filter(|q| !q.trustworthy)
        .count();
    let trusted = |id: i64| {
        reg.report
            .contours
            .iter()
            .any(|q| q.id == id && q.trustworthy)
    };
    let e = path_errors(&reg.path, &c.truth, trusted).unwrap();
    // Measured: 0 over 30 µm, the trusted worst 11.6 µm (P95 5.2 µm); 10 of 52 flagged by the
    // bound. Since the capture scores a start by the share of the scan's points on the whole
    // CAD (it kept its first start here, not the best of eight by the old score), 0 over
    // 30 µm, the trusted worst 6.9 µm (P95 3.8 µm), 13 flagged (two of them by 2 µm).
    assert!(
        over == 0 && silent == 0 && flagged <= 13 && e.cross_edge_p95_mm <= 0.012,
        "{over} contours over 30 µm ({silent} trusted), {flagged} flagged, trusted {e:?}:\n{}",
        report.join("\n")
    );
}
