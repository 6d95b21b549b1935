//! The coarse stage's capture range (issue 11 part 4): synthetic cores placed at exact fixture
//! errors are registered from the fixture's nominal pose up to 20° and 20 mm in several
//! directions, within the accuracy targets; beyond that the part is refused with the pose found;
//! a first start that misses is rescued by the further starts, deterministically; a scan that no
//! start lays on the CAD is refused as not captured.

use trim_geom::formats::{Geometry, read_geometry, read_path};
use trim_geom::{Point3, PointCloud, Similarity3};
use trim_register::RegisterError;
use trim_register::eval::path_errors;
use trim_register::regional::{
    CoarseInit, CoarseSettings, RegisterSettings, Registration, register,
};
use trim_synth::{SynthParams, generate};

#[path = "common/posed.rs"]
mod posed;
#[path = "common/untrimmed.rs"]
mod untrimmed;
use posed::{DIRECTIONS, PosedCase, fixture_error, posed_case};
use untrimmed::{register_untrimmed, untrimmed_case, untrimmed_params};

/// The accuracy targets of `tests/regional.rs` (the issue's), mm.
const CROSS_EDGE_P95_MM: f64 = 0.020;
const CROSS_EDGE_MAX_MM: f64 = 0.050;
/// The reported offset from the nominal pose against the true one: the coarse similarity of a
/// deformed core differs from the placement by ≤ 0.04° (measured, examples/capture.rs).
const OFFSET_ROTATION_TOL_DEG: f64 = 0.3;
/// Scan points per case: the accuracy targets hold from 60k (measured 4.7–10 µm P95 at 120k).
const SCAN_POINTS: usize = 80_000;
const SEED: u64 = 7;

fn settings(case: &PosedCase) -> RegisterSettings {
    RegisterSettings {
        scanner_viewpoint_mm: Some(case.scanner_mm.coords.into()),
        ..RegisterSettings::default()
    }
}

fn run(case: &PosedCase, settings: &RegisterSettings) -> Result<Registration, RegisterError> {
    register(
        &case.cad,
        &case.scan,
        &case.path,
        &Similarity3::identity(),
        settings,
    )
}

fn assert_accurate(case: &PosedCase, reg: &Registration, angle_deg: f64, what: &str) {
    let e = path_errors(&reg.path, &case.truth, |_| true).expect("same contours as the truth");
    assert!(
        e.cross_edge_p95_mm <= CROSS_EDGE_P95_MM && e.cross_edge_max_mm <= CROSS_EDGE_MAX_MM,
        "{what}: {e:?}"
    );
    let to_truth = case
        .scan_from_cad_true
        .isometry
        .rotation
        .angle_to(&reg.scan_from_cad.isometry.rotation)
        .to_degrees();
    assert!(
        to_truth <= OFFSET_ROTATION_TOL_DEG,
        "{what}: {to_truth}° from the truth"
    );
    let found = reg.report.global.fixture_offset;
    assert!(
        (found.rotation_deg - angle_deg).abs() <= OFFSET_ROTATION_TOL_DEG,
        "{what}: offset {found:?}"
    );
}

#[test]
fn captures_fixture_errors_up_to_20_degrees_and_20_mm_in_several_directions() {
    let mut cases = vec![(0.0, 0.0, 0)];
    for size in [10.0, 18.0, 20.0] {
        for k in [0, 3, 5, 6] {
            cases.push((size, size, k));
        }
    }
    for (deg, mm, k) in cases {
        let dir = DIRECTIONS[(k + 3) % DIRECTIONS.len()];
        let case = posed_case(
            SEED,
            SCAN_POINTS,
            &fixture_error(deg, DIRECTIONS[k], mm, dir),
        );
        let what = format!("{deg}°/{mm} mm about {:?} along {dir:?}", DIRECTIONS[k]);
        let reg = run(&case, &settings(&case)).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_accurate(&case, &reg, deg, &what);
        // The default start (principal axes) needs no other here: the nominal start costs
        // nothing extra.
        assert_eq!(reg.report.global.coarse_starts, 1, "{what}");
    }
}

#[test]
fn a_part_beyond_the_range_is_refused_with_the_pose_found() {
    for (deg, mm, k) in [(35.0, 40.0, 0), (35.0, 40.0, 5), (30.0, 0.0, 3)] {
        let dir = DIRECTIONS[(k + 3) % DIRECTIONS.len()];
        let case = posed_case(
            SEED,
            SCAN_POINTS,
            &fixture_error(deg, DIRECTIONS[k], mm, dir),
        );
        let err = run(&case, &settings(&case)).unwrap_err();
        let RegisterError::OutsideCaptureRange {
            rotation_deg,
            translation_mm,
            max_rotation_deg,
            max_translation_mm,
        } = err
        else {
            panic!("{deg}°/{mm} mm: {err}");
        };
        assert!((rotation_deg - deg).abs() < 1.0, "{err}");
        // The offset is the CAD centroid's, 2 mm from the origin the error turns about.
        assert!((translation_mm - mm).abs() < 2.0, "{err}");
        assert_eq!((max_rotation_deg, max_translation_mm), (20.0, 20.0));
        let message = err.to_string();
        for part in [
            "fixture's nominal pose",
            "[part.scan_from_cad]",
            "--initial",
            "seated",
        ] {
            assert!(message.contains(part), "{part:?} missing: {message}");
        }
    }
    // A narrower range refuses what the default captures.
    let case = posed_case(
        SEED,
        SCAN_POINTS,
        &fixture_error(18.0, DIRECTIONS[1], 5.0, DIRECTIONS[2]),
    );
    let mut narrow = settings(&case);
    narrow.coarse.capture_rotation_deg = 10.0;
    let err = run(&case, &narrow).unwrap_err();
    assert!(
        matches!(err, RegisterError::OutsideCaptureRange { .. }),
        "{err}"
    );
}

#[test]
fn a_first_start_that_misses_is_rescued_by_the_further_starts_deterministically() {
    // From the nominal pose as given (no centroid, no axes) the top level's 12 mm reach does
    // not find a core 20° and 20 mm off; the further starts do.
    let case = posed_case(
        SEED,
        SCAN_POINTS,
        &fixture_error(20.0, DIRECTIONS[0], 20.0, DIRECTIONS[3]),
    );
    let mut s = settings(&case);
    s.coarse.init = CoarseInit::Nominal;
    let reg = run(&case, &s).unwrap();
    assert!(
        reg.report.global.coarse_starts > 1,
        "{:?}",
        reg.report.global
    );
    assert_accurate(&case, &reg, 20.0, "nominal start, 20°/20 mm");
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| run(&case, &s).unwrap());
    assert_eq!(
        reg.scan_from_cad.to_homogeneous(),
        one_thread.scan_from_cad.to_homogeneous()
    );
    assert_eq!(
        reg.report.global.coarse_starts,
        one_thread.report.global.coarse_starts
    );
}

#[test]
fn a_scan_that_no_start_lays_on_the_cad_is_not_captured() {
    // A 30 mm ball where the core should be: every start fits it somewhere, none lays it on
    // the core.
    let case = posed_case(SEED, SCAN_POINTS, &Similarity3::identity());
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let n = 20_000;
    let ball: Vec<Point3> = (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            Point3::new(30.0 * r * a.cos(), 30.0 * r * a.sin(), 30.0 * z)
        })
        .collect();
    let scan = PointCloud::new(ball).unwrap();
    let err = register(
        &case.cad,
        &scan,
        &case.path,
        &Similarity3::identity(),
        &settings(&case),
    )
    .unwrap_err();
    assert!(
        matches!(err, RegisterError::NotCaptured { starts, .. } if starts > 1),
        "{err}"
    );
}

#[test]
fn a_one_view_core_is_held_along_its_span_by_the_faces_the_scanner_saw() {
    // The project's core from one view tilted 25°, with burrs and films (the detection test's
    // seed 202): its end faces are seen at 77° or not at all, and at the 2 mm top level its
    // holes are smaller than a voxel. The capture's CAD, culled at the nominal pose, left every
    // start 2.1 mm along the span, beyond the finer levels' reach, and the part was refused
    // with every contour 1.8–2.5 mm off. Fitted again against the CAD the scan supports at
    // the captured pose, it registers.
    let case = untrimmed_case(202);
    assert_eq!(case.views.len(), 1, "the case is a one-view scan");
    assert_eq!(case.scan_from_cad_nominal, Similarity3::identity());
    let reg = register_untrimmed(&case);
    // The targets on the trusted contours (measured: 5.1 µm max).
    assert_registers(&reg, &case.truth);
}

/// The part is not refused, at least 45 of its contours are trusted, and those meet the issue's
/// targets: cross-edge P95 ≤ 12 µm and max ≤ 30 µm.
fn assert_registers(reg: &Registration, truth: &trim_geom::Path) {
    assert!(
        reg.report.global.refused.is_none(),
        "{:?}",
        reg.report.global
    );
    let trusted: Vec<i64> = reg
        .report
        .contours
        .iter()
        .filter(|q| q.trustworthy)
        .map(|q| q.id)
        .collect();
    assert!(
        trusted.len() >= 45,
        "{} of {} contours trusted",
        trusted.len(),
        reg.report.contours.len()
    );
    let e = path_errors(&reg.path, truth, |id| trusted.contains(&id))
        .expect("same contours as the truth");
    eprintln!("{} trusted: {e:?}", trusted.len());
    assert!(
        e.cross_edge_p95_mm <= 0.012 && e.cross_edge_max_mm <= 0.030,
        "{e:?}"
    );
}

#[test]
fn a_one_view_core_slid_along_its_span_is_retried_and_registers() {
    // The project's own benchmark case 618 (`outside.py --generator own --set tune`): one view
    // tilted 25°, burrs on 30 % of the contours, 0.05 mm path spacing. Its coarse fit settles
    // about 2.5 mm along the span (coarse rmse 214 µm, every contour 2–2.7 mm off) and the
    // openings check refuses the part; the retry's start 3 mm along the long axis settles on the
    // truth (coarse rmse 117 µm) and is taken.
    let case = generate(&SynthParams {
        seed: 618,
        scan_points: 200_000,
        cad_points: 200_000,
        pose_deg: 10.71,
        pose_mm: 12.4,
        scale_range: 0.0051,
        pressing_tilt_deg: 17.1,
        sag_mm: 0.41,
        bend_tilt_deg: 14.4,
        twist_deg: 0.095,
        shrink_gradient: 0.00137,
        noise_mm: 0.0091,
        scanner_views: 1,
        dropouts: 1,
        path_spacing_mm: 0.05,
        burr_fraction: 0.3,
        burr_height_mm: [0.05, 0.6],
        ..SynthParams::default()
    })
    .expect("the case generates");
    // As the benchmark registers it: its files written and read back (`trimctl register --cad
    // cad.stl --scan scan.ply --path path.csv`: the mesh's vertices and the scan in single
    // precision, the CAD sampled from the mesh as the CLI samples it).
    let dir = std::env::temp_dir().join(format!("trimctl-slide-retry-{}", std::process::id()));
    case.write_case(&dir).expect("the case's files are written");
    let read = |name: &str| read_geometry(&dir.join(name)).expect("a file the case wrote");
    let (Geometry::Mesh(mesh), Geometry::Points(scan)) = (read("cad.stl"), read("scan.ply")) else {
        panic!("cad.stl is a mesh and scan.ply a point cloud");
    };
    let path = read_path(&dir.join("path.csv")).expect("the case's path");
    std::fs::remove_dir_all(&dir).expect("the case's folder is removed");
    let settings = RegisterSettings::default();
    let cad = mesh.sample_area_weighted(settings.cad_sample_points, 1);
    let reg = register(&cad, &scan, &path, &Similarity3::identity(), &settings)
        .expect("a refusal is a report, not an error");
    let retry = reg.report.global.slide_retry.clone();
    eprintln!(
        "{retry:?}, coarse rmse {} mm",
        reg.report.global.coarse_rmse_mm
    );
    let retry = retry.expect("the first registration is refused and retried");
    assert!(retry.taken && retry.shift_mm != 0.0, "{retry:?}");
    assert!(retry.first_refusal.contains("opening"), "{retry:?}");
    // Measured: 49 of 52 trusted, 5.8 µm at most.
    assert_registers(&reg, &case.truth);
    // Without the retry the part is refused, as before.
    let first = register(
        &cad,
        &scan,
        &path,
        &Similarity3::identity(),
        &RegisterSettings {
            coarse: CoarseSettings {
                slide_retry: false,
                ..settings.coarse.clone()
            },
            ..settings
        },
    )
    .expect("a refusal is a report, not an error");
    assert!(first.report.global.refused.is_some());
    assert!(first.report.global.slide_retry.is_none());
}

#[test]
fn a_dense_scan_with_a_view_from_below_is_captured_at_the_first_start() {
    // The project's core with the built-in demo's scanner (two views above, one below), burrs
    // and films, scanned at 1M points (the detection test's seed 201 at twice its density) and
    // registered with its first view's position. The capture scored a start by the share of
    // the top level's 2 mm voxels within 1 mm of the CAD culled toward that view: the view from
    // below and the stray points (1 % within 2 mm of the part, filling a voxel past three
    // points more often the denser the scan) kept it at 0.74 at 500k points after eight starts,
    // and at 1M the best of eight laid 56.1 % of the scan on the CAD and the part was refused.
    // Scored by the scan's points on the whole CAD, the first start is kept.
    let case = generate(&SynthParams {
        scanner_views: trim_synth::DEMO_SCANNER_VIEWS,
        scan_points: 1_000_000,
        ..untrimmed_params(201)
    })
    .expect("the case generates");
    let reg = register_untrimmed(&case);
    let global = &reg.report.global;
    eprintln!(
        "starts {}, score {:.3}",
        global.coarse_starts, global.capture_score
    );
    // Measured: the first start, 0.915 of the points within 1 mm.
    assert_eq!(global.coarse_starts, 1, "{global:?}");
    assert!(global.capture_score >= 0.9, "{global:?}");
    // Measured: 51 of 52 trusted, cross-edge P95 1.9 µm, max 3.0 µm.
    assert_registers(&reg, &case.truth);
}
