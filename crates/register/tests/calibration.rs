//! The accuracy targets and the predicted error bound (`predicted_max_error_um`) against ground
//! truth on the seeded accuracy cases (`tests/common/cases.rs`, seeds disjoint from the calibration seeds 101–124
//! the `BOUND_*` constants were fitted on).

#[path = "common/cases.rs"]
mod cases;

use trim_geom::PointCloud;
use trim_register::eval::path_errors;
use trim_register::regional::{
    Flag, REGION_DOUBT_FRACTION, REGION_FAR_OFF_FRACTION, REGION_MIN_FAR_OFF, RegisterSettings,
    register,
};
use trim_synth::{SynthCase, SynthParams, generate};

/// Test seeds (4 and 8 take the far end of every range).
const SEEDS: [u64; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
/// The calibration target: the actual largest cross-edge error stays under the bound
/// on at least this fraction of contours.
const MIN_COVERED: f64 = 0.95;
/// At most this fraction of the contours under half the tolerance may be flagged.
const MAX_FALSE_ALARMS: f64 = 0.05;
/// The accuracy targets on every seeded case, mm.
const CROSS_EDGE_P95_MM: f64 = 0.012;
const CROSS_EDGE_MAX_MM: f64 = 0.030;
const POINTWISE_P95_MM: f64 = 0.020;

/// The registration of `scan` (the case's own, or part of it) onto the case's path, from the
/// case's scanner viewpoint with `settings` otherwise.
fn register_case(
    c: &SynthCase,
    scan: &PointCloud,
    settings: &RegisterSettings,
) -> trim_register::regional::Registration {
    register(
        &c.cad_points,
        scan,
        &c.path,
        &c.scan_from_cad_nominal,
        settings,
    )
    .expect("registered")
}

/// The default settings, looking from the case's first scanner view.
fn settings_for(c: &SynthCase) -> RegisterSettings {
    RegisterSettings {
        scanner_viewpoint_mm: Some(c.scanner_in_scan.coords.into()),
        ..RegisterSettings::default()
    }
}

#[test]
fn the_predicted_bound_covers_the_actual_error() {
    let (mut contours, mut covered, mut good, mut good_flagged) = (0, 0, 0, 0);
    let (mut bad, mut bad_trusted) = (0, 0);
    // The P95 risk's prediction: the trusted contours expected beyond the cross-edge P95 limit
    // (the sum of their `p95_risk`), and how many are.
    let (mut expected_over_p95, mut over_p95) = (0.0, 0u32);
    let mut cases_report = Vec::new();
    for seed in SEEDS {
        let c = generate(&cases::case_params(seed, 150_000, 200_000)).unwrap();
        let settings = settings_for(&c);
        let reg = register_case(&c, &c.scan, &settings);
        // The accuracy targets, every case.
        let all = path_errors(&reg.path, &c.truth, |_| true).unwrap();
        assert!(
            all.cross_edge_p95_mm <= CROSS_EDGE_P95_MM
                && all.cross_edge_max_mm <= CROSS_EDGE_MAX_MM
                && all.pointwise_p95_mm <= POINTWISE_P95_MM,
            "seed {seed}: {all:?}"
        );
        let tolerance_um = settings.quality.tolerance_um;
        let expected = reg.report.global.expected_over_p95.expect("a posterior");
        assert!(
            (expected
                - reg
                    .report
                    .contours
                    .iter()
                    .filter(|q| q.trustworthy)
                    .filter_map(|q| q.p95_risk)
                    .sum::<f64>())
            .abs()
                < 1e-9
        );
        expected_over_p95 += expected;
        for q in &reg.report.contours {
            let own = path_errors(&reg.path, &c.truth, |id| id == q.id).unwrap();
            let actual_um = own.cross_edge_max_mm * 1e3;
            if q.trustworthy && own.cross_edge_p95_mm > CROSS_EDGE_P95_MM {
                over_p95 += 1;
                cases_report.push(format!(
                    "seed {seed} contour {}: trusted, own P95 {:.1} µm (P95 risk {:?})",
                    q.id,
                    own.cross_edge_p95_mm * 1e3,
                    q.p95_risk
                ));
            }
            assert!(
                q.predicted_max_error_um.is_finite() && q.predicted_max_error_um > 0.0,
                "{q:?}"
            );
            // The flag follows the bound.
            assert_eq!(
                q.flags.contains(&Flag::PredictedError),
                q.predicted_max_error_um > tolerance_um,
                "{q:?}"
            );
            contours += 1;
            if actual_um <= q.predicted_max_error_um {
                covered += 1;
            } else {
                cases_report.push(format!(
                    "seed {seed} contour {}: actual {actual_um:.1} µm > predicted {:.1} µm",
                    q.id, q.predicted_max_error_um
                ));
            }
            // Few contours under half the tolerance are flagged (the old
            // `degenerate,unsupported` rule fired on a third of them), and every contour over
            // the tolerance is.
            if actual_um < 0.5 * tolerance_um {
                good += 1;
                if !q.trustworthy {
                    good_flagged += 1;
                    cases_report.push(format!(
                        "seed {seed} contour {}: actual {actual_um:.1} µm flagged {:?} (predicted {:.1} µm)",
                        q.id, q.flags, q.predicted_max_error_um
                    ));
                }
            }
            if actual_um > tolerance_um {
                bad += 1;
                if q.trustworthy {
                    bad_trusted += 1;
                    cases_report.push(format!(
                        "seed {seed} contour {}: actual {actual_um:.1} µm trusted (predicted {:.1} µm)",
                        q.id, q.predicted_max_error_um
                    ));
                }
            }
        }
    }
    let fraction = f64::from(covered) / f64::from(contours);
    assert!(
        fraction >= MIN_COVERED,
        "{covered} of {contours} contours within their bound: {cases_report:#?}"
    );
    // The false-alarm target (issue 21): the bound is taken under a tenth of the
    // field's prior so that what the data do not fix shows (no silent miss on the outside
    // generator's cases), and a few good contours far from any wall pay for that.
    assert!(
        f64::from(good_flagged) <= MAX_FALSE_ALARMS * f64::from(good),
        "{good_flagged} of {good} good contours flagged: {cases_report:#?}"
    );
    assert_eq!(
        bad_trusted, 0,
        "{bad_trusted} of {bad} contours over the tolerance trusted: {cases_report:#?}"
    );
    // The risks do not understate: no more trusted contours beyond the P95 limit than their
    // sum allows, within a Poisson count's upper 99.7 % (λ + 3√λ, and 2 more for a small λ).
    assert!(
        f64::from(over_p95) <= expected_over_p95 + 3.0 * expected_over_p95.sqrt() + 2.0,
        "{over_p95} trusted contours beyond the P95 limit, {expected_over_p95:.2} expected: {cases_report:#?}"
    );
}

/// The part's end the scanner cannot see: every scan point beyond this far along the long axis
/// from the part's middle, as a share of its half length, is removed.
const UNSEEN_FROM: f64 = 0.7;
/// The curl of that end, mm (starting at 40 % of the half length: partly seen).
const TIP_CURL_MM: f64 = 0.3;
/// The model check's median disagreement on the contours over the tolerance is at least this
/// many times its median on the good ones (measured: 21.9 against 1.2 µm).
const MODEL_CHECK_RATIO: f64 = 5.0;

#[test]
fn contours_in_a_region_the_scanner_cannot_see_are_flagged_when_they_err() {
    // The hardest seeded core (every range at its far end) with a curled end (a warp the bend
    // does not explain) that the scanner does not see: the strips and rims there have partial
    // data or none, and the field carries them from the rest of the part.
    let c = generate(&SynthParams {
        tip_curl_mm: TIP_CURL_MM,
        ..cases::case_params(4, 150_000, 200_000)
    })
    .unwrap();
    let bounds = trim_geom::Aabb::around(c.cad_points.points()).unwrap();
    let (centre, long) = (bounds.center(), {
        let mut axis = trim_geom::Vector3::zeros();
        axis[bounds.extent().iamax()] = 1.0;
        axis
    });
    let half = 0.5 * bounds.extent().max();
    let cad_from_scan = c.scan_from_cad_true.inverse();
    let keep: Vec<usize> = (0..c.scan.len())
        .filter(|&i| {
            let p = cad_from_scan.transform_point(&c.scan.points()[i]);
            (p - centre).dot(&long) < UNSEEN_FROM * half
        })
        .collect();
    let scan = c.scan.select(&keep).unwrap();
    let settings = settings_for(&c);
    let reg = register_case(&c, &scan, &settings);
    let tolerance_um = settings.quality.tolerance_um;
    let mut over = Vec::new();
    // The model check's disagreement (µm) on the contours over the tolerance and on those
    // under half of it.
    let (mut over_disagree, mut good_disagree) = (Vec::new(), Vec::new());
    for q in &reg.report.contours {
        let actual_um = path_errors(&reg.path, &c.truth, |id| id == q.id)
            .unwrap()
            .cross_edge_max_mm
            * 1e3;
        if actual_um > tolerance_um {
            over.push((q.id, actual_um, q.predicted_max_error_um, q.flags.clone()));
            over_disagree.push(q.model_disagreement_mm * 1e3);
        } else if actual_um < 0.5 * tolerance_um {
            good_disagree.push(q.model_disagreement_mm * 1e3);
        }
    }
    // The second fit (`quality.model_check`) disagrees where the prior, not the data, places
    // the contours: on the unseen end, several times more than on the contours the data fix.
    good_disagree.sort_by(f64::total_cmp);
    let good_median = good_disagree[good_disagree.len() / 2];
    let over_median = {
        over_disagree.sort_by(f64::total_cmp);
        over_disagree
            .get(over_disagree.len() / 2)
            .copied()
            .unwrap_or(0.0)
    };
    assert!(
        over_median > 0.0 && over_median >= MODEL_CHECK_RATIO * good_median,
        "model check: median disagreement {over_median:.1} µm over the tolerance, \
         {good_median:.1} µm on good contours"
    );
    // The case does what it is for: some contours really err over the tolerance...
    assert!(
        over.len() >= 3,
        "{} contours erred over {tolerance_um} µm",
        over.len()
    );
    // ...and every one of them is flagged.
    let silent: Vec<_> = over.iter().filter(|o| o.3.is_empty()).collect();
    assert!(
        silent.is_empty(),
        "trusted over the tolerance: {silent:?} (of {over:?})"
    );
    // Among them strips the scan covers in part, which only the predicted bound can flag.
    assert!(
        over.iter().any(|o| o.3 == [Flag::PredictedError]),
        "none flagged by the bound alone: {over:?}"
    );
    // The unseen end is a stretch of the part in doubt (`region_in_doubt`): the contours far
    // off by their bounds there are named, and so is every contour flagged for reaching into
    // that stretch, each with a bound at 1.5σ over two thirds of the tolerance.
    let region = reg
        .report
        .global
        .region_in_doubt
        .as_deref()
        .expect("the unseen end in doubt");
    let far: Vec<i64> = reg
        .report
        .contours
        .iter()
        .filter(|q| q.doubt_bound_um.max(q.part_bound_um) > REGION_FAR_OFF_FRACTION * tolerance_um)
        .map(|q| q.id)
        .collect();
    assert!(far.len() >= REGION_MIN_FAR_OFF, "{far:?}");
    let named = |from: &str, to: &str| -> Vec<i64> {
        // "contour 7 there" or "contours 7, 9 there".
        let list = region.split(from).nth(1).and_then(|s| s.split(to).next());
        list.unwrap_or_else(|| panic!("{region}"))
            .trim_start_matches("s ")
            .split(", ")
            .map(|id| id.parse().unwrap_or_else(|_| panic!("{region}")))
            .collect()
    };
    assert_eq!(named("contours (", ")"), far, "{region}");
    let stretched: Vec<i64> = reg
        .report
        .contours
        .iter()
        .filter(|q| q.flags.contains(&Flag::RegionInDoubt))
        .map(|q| q.id)
        .collect();
    assert!(!stretched.is_empty(), "{region}");
    assert_eq!(named("so contour", " there"), stretched, "{region}");
    for q in reg
        .report
        .contours
        .iter()
        .filter(|q| stretched.contains(&q.id))
    {
        assert!(
            q.doubt_bound_um > REGION_DOUBT_FRACTION * tolerance_um && !far.contains(&q.id),
            "{}: {:.1} µm",
            q.id,
            q.doubt_bound_um
        );
    }
}

/// The in-plane bend case: the bend turned this far from the thickness axis toward the chord.
const IN_PLANE_BEND_TILT_DEG: f64 = 60.0;

/// The largest true cross-edge error over the trusted contours and over all, and the contours
/// over the tolerance left trusted, µm.
fn trusted_and_all_max_um(
    reg: &trim_register::regional::Registration,
    truth: &trim_geom::Path,
    tolerance_um: f64,
) -> (f64, f64, Vec<(i64, f64)>) {
    let (mut trusted, mut all, mut silent) = (0.0_f64, 0.0_f64, Vec::new());
    for q in &reg.report.contours {
        // A contour that cannot be scored counts as infinitely wrong.
        let e = path_errors(&reg.path, truth, |id| id == q.id)
            .map_or(f64::INFINITY, |e| e.cross_edge_max_mm * 1e3);
        all = all.max(e);
        if q.trustworthy {
            trusted = trusted.max(e);
            if e > tolerance_um {
                silent.push((q.id, e));
            }
        }
    }
    (trusted, all, silent)
}

#[test]
fn a_core_bent_in_its_own_plane_keeps_its_edges_on_the_line_under_the_beam_prior() {
    // The hardest seeded core with its bend turned toward the chord: the bend moves the
    // leading and trailing edges along the span (its cross-sections turn), which the faces and
    // edges, all running along the span, do not show. On this core the slots and holes near
    // the edges and the three views fix that motion well without the beam prior too
    // (measured: largest error 11.5 µm with it, 13.1 µm without); the outside generator's
    // blade, whose edge strips run the whole span with nothing beside them, is where the
    // prior mattered (docs/DESIGN.md). So this asserts the targets with the prior and that it
    // costs nothing here, not a gain.
    let c = generate(&SynthParams {
        bend_tilt_deg: IN_PLANE_BEND_TILT_DEG,
        ..cases::case_params(4, 150_000, 200_000)
    })
    .unwrap();
    let mut measured = Vec::new();
    for beam in [true, false] {
        let mut settings = settings_for(&c);
        settings.field.beam_kinematics = beam;
        let reg = register_case(&c, &c.scan, &settings);
        let (trusted, all, silent) =
            trusted_and_all_max_um(&reg, &c.truth, settings.quality.tolerance_um);
        eprintln!(
            "beam prior {beam}: max over trusted {trusted:.1} µm, over all {all:.1} µm, {} flagged, silent {silent:?}",
            reg.report.global.untrustworthy
        );
        measured.push((trusted, all, silent));
    }
    let (on, off) = (&measured[0], &measured[1]);
    assert!(
        on.2.is_empty(),
        "silent misses with the beam prior: {:?}",
        on.2
    );
    assert!(
        on.0 <= CROSS_EDGE_MAX_MM * 1e3,
        "max over trusted {} µm",
        on.0
    );
    assert!(
        on.1 <= off.1 + 2.0,
        "the beam prior made it worse: {} µm with it, {} µm without",
        on.1,
        off.1
    );
}
