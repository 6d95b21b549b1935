//! The accuracy targets and the predicted error bound (`predicted_max_error_um`) against ground
//! truth on the seeded accuracy cases (`tests/common/cases.rs`, seeds disjoint from the calibration seeds 101–124
//! the `BOUND_*` constants were fitted on).

#[path = "common/cases.rs"]
mod cases;

use trim_register::eval::path_errors;
use trim_register::regional::{Flag, RegisterSettings, register};
use trim_synth::generate;

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

#[test]
fn the_predicted_bound_covers_the_actual_error() {
    let (mut contours, mut covered, mut good, mut good_flagged) = (0, 0, 0, 0);
    let (mut bad, mut bad_trusted) = (0, 0);
    let mut cases_report = Vec::new();
    for seed in SEEDS {
        let c = generate(&cases::case_params(seed, 150_000, 200_000)).unwrap();
        let settings = RegisterSettings {
            scanner_viewpoint_mm: Some(c.scanner_in_scan.coords.into()),
            ..RegisterSettings::default()
        };
        let reg = register(
            &c.cad_points,
            &c.scan,
            &c.path,
            &c.scan_from_cad_nominal,
            &settings,
        )
        .unwrap();
        // The accuracy targets, every case.
        let all = path_errors(&reg.path, &c.truth, |_| true).unwrap();
        assert!(
            all.cross_edge_p95_mm <= CROSS_EDGE_P95_MM
                && all.cross_edge_max_mm <= CROSS_EDGE_MAX_MM
                && all.pointwise_p95_mm <= POINTWISE_P95_MM,
            "seed {seed}: {all:?}"
        );
        let tolerance_um = settings.quality.tolerance_um;
        for q in &reg.report.contours {
            let actual_um = path_errors(&reg.path, &c.truth, |id| id == q.id)
                .unwrap()
                .cross_edge_max_mm
                * 1e3;
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
}
