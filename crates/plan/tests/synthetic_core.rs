//! Done-when checks of issue 3 on the synthetic ceramic-core path (60 contours, like the paper's
//! Fig. 10), through the path CSV contract, for every kinematics and pose mode.

use trim_cell::kinematics::{KinematicsKind, MachineSettings, PoseMode};
use trim_geom::formats::{encode_path, read_path_from_bytes};
use trim_geom::{Contour, Path, Point3, Vector3};
use trim_plan::planner::{PlanSettings, ROUND_TRIP_TOLERANCE_MM, plan_with_report};
use trim_plan::scan_field::LensSettings;
use trim_synth::testing::synthetic_core_path;

/// The seed of the synthetic path.
const SEED: u64 = 0x5eed_0060;

fn core_via_csv() -> Path {
    let path = synthetic_core_path(60, SEED);
    let bytes = encode_path(&path);
    read_path_from_bytes(&bytes, std::path::Path::new("synthetic.csv")).expect("own CSV reads back")
}

#[test]
fn zoning_keeps_five_degrees_with_automatic_k_and_round_trip_holds() {
    let path = core_via_csv();
    for telecentric in [false, true] {
        let settings = PlanSettings {
            field: LensSettings {
                telecentric,
                ..LensSettings::default()
            },
            ..PlanSettings::default()
        };
        let out = plan_with_report(&path, &settings).expect("plans");
        let v = &out.job.validation;
        let zoning_max = out
            .table
            .iter()
            .map(|r| r.max_incidence_deg)
            .fold(0.0, f64::max);
        eprintln!(
            "telecentric={telecentric}: pieces {} k {} (automatic {}) clusters {} merges {} zones {} \
             zoning max incidence {zoning_max:.4}° with lens {:.4}° round trip {:.3e} mm passed {}",
            out.pieces,
            out.k,
            out.automatic_k,
            out.clusters,
            out.merges,
            out.job.zones.len(),
            v.max_incidence_deg,
            v.max_round_trip_error_mm,
            v.passed
        );
        for r in &out.table {
            eprintln!(
                "  zone {:>3} cluster {:>3} ({:8.3}, {:8.3}, {:8.3}, {:6.3}, {:6.3}, {:6.3}) included {:7.4}° incidence {:7.4}° lens {:7.4}°",
                r.zone,
                r.cluster,
                r.centre[0],
                r.centre[1],
                r.centre[2],
                r.centre[3],
                r.centre[4],
                r.centre[5],
                r.max_pairwise_deg,
                r.max_incidence_deg,
                r.max_incidence_with_lens_deg
            );
        }
        assert!(out.automatic_k);
        assert!(zoning_max <= 5.0 + 1e-9, "{zoning_max}");
        assert!(v.max_incidence_deg <= 5.0 + 1e-9);
        assert!(v.max_round_trip_error_mm <= ROUND_TRIP_TOLERANCE_MM);
        assert!(v.passed, "{:?}", v.violations);
        // Every contour id appears in some zone.
        let mut ids: Vec<i64> = out
            .job
            .zones
            .iter()
            .flat_map(|z| z.contours.clone())
            .collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids, (0..60).collect::<Vec<i64>>());
    }
}

#[test]
fn every_trt_kinematics_and_pose_mode_validates() {
    let path = core_via_csv();
    for kinematics in [KinematicsKind::XyzacTrt, KinematicsKind::XyzbcTrt] {
        for pose_mode in [PoseMode::Tcp, PoseMode::Joints] {
            let settings = PlanSettings {
                machine: MachineSettings {
                    kinematics,
                    pose_mode,
                    ..MachineSettings::default()
                },
                ..PlanSettings::default()
            };
            let out = plan_with_report(&path, &settings).expect("plans");
            let v = &out.job.validation;
            assert!(v.passed, "{kinematics:?} {pose_mode:?}: {:?}", v.violations);
            let tilt = kinematics.tilt_axis().expect("a trt machine tilts");
            for (_, _, layer) in out.job.layers() {
                assert!(layer.pose.axis(tilt).is_some() && layer.pose.axis("c").is_some());
            }
        }
    }
}

#[test]
fn fixed_head_plans_a_gentle_dome_and_reports_what_it_cannot_reach() {
    // Holes on z = 0.002·(x² + y²): normals within ~3° of +Z over ±12 mm.
    let mut contours = Vec::new();
    for (id, (cx, cy)) in [(-10.0, -10.0), (0.0, 0.0), (10.0, 5.0), (-5.0, 10.0)]
        .into_iter()
        .enumerate()
    {
        let f = |x: f64, y: f64| 0.002 * (x * x + y * y);
        let n = Vector3::new(-0.004 * cx, -0.004 * cy, 1.0).normalize();
        let points = (0..=16)
            .map(|i| {
                let a = std::f64::consts::TAU * f64::from(i % 16) / 16.0;
                let (x, y) = (cx + a.cos(), cy + a.sin());
                Point3::new(x, y, f(x, y))
            })
            .collect();
        contours.push(Contour::new(id as i64, points, n).expect("valid hole"));
    }
    let path = Path::new(contours).expect("unique ids");
    let settings = PlanSettings {
        machine: MachineSettings {
            kinematics: KinematicsKind::Xyz,
            ..MachineSettings::default()
        },
        ..PlanSettings::default()
    };
    let out = plan_with_report(&path, &settings).expect("plans");
    assert!(
        out.job.validation.passed,
        "{:?}",
        out.job.validation.violations
    );
    for z in &out.job.zones {
        assert!((z.frame.z_axis() - Vector3::z()).norm() < 1e-12);
    }
    // The ceramic core's horizontal normals are out of reach of a fixed head: reported.
    let out = plan_with_report(&core_via_csv(), &settings).expect("plans");
    assert!(!out.job.validation.passed);
    assert!(
        out.job
            .validation
            .violations
            .iter()
            .any(|l| l.contains("incidence"))
    );
}
