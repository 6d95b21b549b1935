//! The digital twin end to end: a planner that knows the true cell puts every spot on the true
//! trimming line; one that assumes the nominal cell misses it by what the cell's errors say.

#![expect(
    clippy::unwrap_used,
    reason = "integration test: a failed setup step should fail the test loudly"
)]

#[expect(
    dead_code,
    reason = "shared helpers; this test uses two of them (through twin_run)"
)]
#[path = "../../io/tests/common/mod.rs"]
mod common;
#[path = "support/twin_run.rs"]
mod twin_run;

use trim_cell::kinematics::{KinematicsKind, MachineSettings};
use trim_cell::truth::TruthSettings;
use trim_plan::planner::{PlanSettings, plan};
use trim_plan::scan_field::LensSettings;
use trim_sim::twin::{SpotStats, TrueCell, TruePart, Twin};

use twin_run::run_on_twin;

/// A true cell off the nominal one by a few hundredths of a degree and a tenth of a millimetre.
fn truth(kind: KinematicsKind) -> TruthSettings {
    let (tilt_point, tilt_dir) = match kind {
        KinematicsKind::XyzbcTrt => ([-20.12, 0.0, 10.07], [0.0004, 1.0, -0.0003]),
        _ => ([0.0, 20.09, 10.11], [1.0, 0.0005, 0.0004]),
    };
    let mut t = TruthSettings::default();
    t.calibration.c_axis_point_mm = Some([0.13, -0.08, 0.0]);
    t.calibration.c_axis_direction = Some([0.0006, -0.0004, 1.0]);
    if kind == KinematicsKind::XyzbcTrt {
        t.calibration.b_axis_point_mm = Some(tilt_point);
        t.calibration.b_axis_direction = Some(tilt_dir);
    } else {
        t.calibration.a_axis_point_mm = Some(tilt_point);
        t.calibration.a_axis_direction = Some(tilt_dir);
    }
    t
}

/// The line a plan under `settings` means to draw along the true `path` (kerf-compensated as
/// the planner compensates; the spot error is measured against it).
fn intended(path: &trim_geom::Path, settings: &PlanSettings) -> trim_geom::Path {
    trim_plan::kerf::intended_line(path, settings.kerf_offset_mm()).unwrap()
}

async fn spots(settings: &PlanSettings, truth: &TruthSettings) -> SpotStats {
    let path = trim_synth::testing::synthetic_core_path(16, 3);
    let job = plan(&path, settings).unwrap();
    assert!(job.validation.passed, "{:?}", job.validation.violations);
    let twin = Twin::new(
        TrueCell::new(truth, settings),
        TruePart::new(&intended(&path, settings)),
    );
    run_on_twin(job.clone(), &twin).await;
    let errors: Vec<f64> = twin.spots().iter().map(|s| s.error_mm).collect();
    let vectors: usize = job
        .layers()
        .flat_map(|(_, _, l)| l.polylines.iter())
        .map(|p| p.points.len() - 1)
        .sum();
    assert_eq!(errors.len(), 2 * vectors, "every vector's two ends landed");
    SpotStats::of_mm(&errors)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_planner_that_knows_the_true_axes_lands_on_the_line_for_both_kinematics() {
    for kind in [KinematicsKind::XyzacTrt, KinematicsKind::XyzbcTrt] {
        let truth = truth(kind);
        let nominal = PlanSettings {
            machine: MachineSettings {
                kinematics: kind,
                ..MachineSettings::default()
            },
            field: LensSettings {
                telecentric: true,
                ..LensSettings::default()
            },
            ..PlanSettings::default()
        };
        let calibrated = PlanSettings {
            calibration: truth.calibration.clone(),
            ..nominal.clone()
        };
        let known = spots(&calibrated, &truth).await;
        let assumed = spots(&nominal, &truth).await;
        eprintln!(
            "{kind:?}: calibrated axes: P95 {:.3} µm max {:.3} µm; nominal axes: P95 {:.1} µm max {:.1} µm",
            known.p95_um, known.max_um, assumed.p95_um, assumed.max_um
        );
        // Galvo bits are 0.1 µm: what is left is quantisation (P95), and at the largest
        // incidence the covering allows (5° with the real ray) the twin's tangent-plane landing
        // against the polyline's chords (max 0.53 µm measured).
        assert!(known.p95_um < 0.1, "{kind:?}: {known:?}");
        assert!(known.max_um < 1.0, "{kind:?}: {known:?}");
        assert!(
            assumed.p95_um > 20.0,
            "{kind:?}: the twin sees the axis errors: {assumed:?}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_planner_that_knows_the_head_field_and_pivot_lands_on_the_line() {
    use trim_cell::lens::{FieldCorrection, LensDistortion};
    let mut truth = TruthSettings {
        head: LensDistortion {
            offset_mm: [0.0, 0.0],
            rotation_deg: 0.12,
            barrel_per_mm2: 4.0e-7,
            trapezoid_per_mm: [1.0e-5, -8.0e-6],
        },
        ..truth(KinematicsKind::XyzacTrt)
    };
    truth.calibration.lens.pivot_to_focal_plane_mm = Some(240.0);
    let dir = tempfile::tempdir().unwrap();
    let field_file = dir.path().join("field.json");
    let head = truth.head;
    FieldCorrection::sample(50.0, 65, |c| head.land(c))
        .write(&field_file)
        .unwrap();
    let nominal = PlanSettings {
        calibration: truth.calibration.clone(),
        ..PlanSettings::default()
    };
    let mut calibrated = nominal.clone();
    calibrated.calibration.field_correction = Some(field_file);
    calibrated.calibration.lens.pivot_to_focal_plane_mm =
        truth.calibration.lens.pivot_to_focal_plane_mm;
    let known = spots(&calibrated, &truth).await;
    let assumed = spots(&nominal, &truth).await;
    eprintln!(
        "head field and pivot known: P95 {:.3} µm max {:.3} µm; assumed ideal: P95 {:.1} µm max {:.1} µm",
        known.p95_um, known.max_um, assumed.p95_um, assumed.max_um
    );
    // The twin's rays are its own computation (pivot above the field centre, through D(c)),
    // independent of the planner's height term and field inverse.
    assert!(known.max_um < 1.0, "{known:?}");
    assert!(assumed.p95_um > 10.0, "{assumed:?}");
}

/// The burr webs a run leaves and the gouges it cuts, from the twin's landed lines on a burred
/// synthetic core (its true path planned as if registered perfectly, each contour marked with
/// the passes its thickest web needs): the largest residual web and gouge over all contours, µm.
/// With kerf compensation on, every contour's material side must have been found.
async fn trim_outcome(settings: &PlanSettings, truth: &TruthSettings) -> (f64, f64) {
    use trim_sim::twin_part::TwinPart;
    let case = trim_synth::generate(&trim_synth::SynthParams {
        seed: 11,
        scan_points: 1_000,
        cad_points: 1_000,
        burr_fraction: 0.5,
        burr_thickness_mm: [0.02, 0.1],
        ..trim_synth::SynthParams::default()
    })
    .unwrap();
    let process = settings.process;
    let truth_path = case.truth.clone();
    let mut part = TwinPart::new(case, trim_geom::Similarity3::identity());
    let edges = part.edges().unwrap();
    let mut job = plan(&truth_path, settings).unwrap();
    assert!(job.validation.passed, "{:?}", job.validation.violations);
    if let Some(kerf) = &job.kerf {
        assert!(kerf.uncompensated.is_empty(), "{:?}", kerf.uncompensated);
        assert_eq!(kerf.compensated.len(), edges.len());
    }
    for z in &mut job.zones {
        for l in &mut z.layers {
            for p in &mut l.polylines {
                let e = edges.iter().find(|e| e.contour == p.contour).unwrap();
                let thickest = e.burr_thickness_mm.iter().copied().fold(0.0, f64::max);
                p.passes = process.passes_through(thickest).unwrap();
            }
        }
    }
    let twin = Twin::new(
        TrueCell::new(truth, settings),
        TruePart::new(&intended(&truth_path, settings)),
    );
    run_on_twin(job, &twin).await;
    let kerf = process.kerf_width_mm(&settings.beam);
    let after = part.trim(&twin.cuts(), &process, kerf).unwrap();
    let residual = after.iter().map(|c| c.residual_um).fold(0.0, f64::max) / 1e3;
    let gouge = after.iter().map(|c| c.gouge_um).fold(0.0, f64::max) / 1e3;
    eprintln!(
        "kerf {:.1} µm, compensation {}: residual web max {:.1} µm, gouge max {:.1} µm over {} contours",
        kerf * 1e3,
        settings
            .kerf_offset_mm()
            .map_or_else(|| "off".to_owned(), |d| format!("{:.1} µm", d * 1e3)),
        residual * 1e3,
        gouge * 1e3,
        edges.len()
    );
    (residual * 1e3, gouge * 1e3)
}

/// Kerf compensation: the calibrated cell on the compensated line severs every web and cuts
/// the edge back by no more than the landing error; the same line on the edge gouges half the
/// kerf everywhere; the nominal cell misses by its axis errors.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calibrated_cell_cuts_every_burr_off_without_gouging_and_a_nominal_one_does_not() {
    let truth = truth(KinematicsKind::XyzacTrt);
    let nominal = PlanSettings {
        field: LensSettings {
            telecentric: true,
            ..LensSettings::default()
        },
        ..PlanSettings::default()
    };
    let calibrated = PlanSettings {
        calibration: truth.calibration.clone(),
        ..nominal.clone()
    };
    assert!(calibrated.trim.kerf_compensation, "on by default");
    let half_kerf_um = 1e3 * calibrated.process.kerf_width_mm(&calibrated.beam) / 2.0;
    // Compensated: the kerf's inner side on the edge. What is left is the landing error (max
    // 0.53 µm, the spot test above) and the miter on the rims' chords (0.1 µm): no web taller
    // than 1 µm, no gouge deeper than 3 µm (the bound), against 20.5 µm uncompensated.
    let (residual, gouge) = trim_outcome(&calibrated, &truth).await;
    assert!(residual < 1.0, "{residual}");
    assert!(gouge <= 3.0, "{gouge}");
    // On the edge (compensation off): the kerf's half behind the edge, within a micrometre.
    let mut on_edge = calibrated.clone();
    on_edge.trim.kerf_compensation = false;
    let (residual, gouge) = trim_outcome(&on_edge, &truth).await;
    assert!(residual < 1.0, "{residual}");
    assert!((gouge - half_kerf_um).abs() < 1.0, "{gouge}");
    let (residual, gouge) = trim_outcome(&nominal, &truth).await;
    assert!(
        residual > 30.0 || gouge > 30.0,
        "the twin sees the axis errors: {residual} {gouge}"
    );
}
