//! The predicted error bound (`predicted_max_error_um`) against ground truth on the seeded
//! accuracy cases (`tests/common/cases.rs`, seeds disjoint from the calibration seeds 101–124
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
/// The flag must not fire on good contours: at most this fraction of the contours whose actual
/// error is under half the tolerance are flagged by the bound (the issue asks for none; the
/// old `degenerate,unsupported` rule fired on a third).
const MAX_FALSE_FLAG_FRACTION: f64 = 0.03;

#[test]
fn the_predicted_bound_covers_the_actual_error() {
    let (mut contours, mut covered, mut good, mut good_flagged) = (0, 0, 0, 0);
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
            if actual_um < 0.5 * tolerance_um {
                good += 1;
                if q.flags.contains(&Flag::PredictedError) {
                    good_flagged += 1;
                }
            }
        }
    }
    let fraction = f64::from(covered) / f64::from(contours);
    assert!(
        fraction >= MIN_COVERED,
        "{covered} of {contours} contours within their bound: {cases_report:#?}"
    );
    assert!(
        f64::from(good_flagged) <= MAX_FALSE_FLAG_FRACTION * f64::from(good),
        "{good_flagged} of {good} good contours flagged by the bound"
    );
}
