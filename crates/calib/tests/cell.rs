//! `calibrate cell` recovers a seeded true cell from synthetic sphere scans (10 µm scan noise,
//! 2 µm tool-mark noise) to the targets: axis directions within 0.003°, axis points
//! within 5 µm across the axis, the scanner within 5 µm / 0.003°.

use trim_calib::CalibError;
use trim_calib::artefact::{ArtefactTruth, default_poses, observe, synth_artefacts};
use trim_calib::cell_calibration::{
    calibrate_cell, direction_error_deg, line_offset_mm, rotation_about, rotation_error_deg,
};
use trim_cell::cell_model::{AxisLine, ScannerPose, TableModel};
use trim_cell::kinematics::{KinematicsKind, MachineSettings};
use trim_geom::{Point3, UnitVector3, Vector3};

const DIAMETER_MM: f64 = 25.4;

fn tilt(line: &AxisLine, axis: Vector3, deg: f64, offset: Vector3) -> AxisLine {
    AxisLine {
        point_mm: line.point_mm + offset,
        direction: UnitVector3::new_normalize(
            rotation_about(&axis, deg) * line.direction.into_inner(),
        ),
    }
}

fn truth(kind: KinematicsKind, seed: u64) -> (TableModel, TableModel, ScannerPose) {
    let nominal = TableModel::nominal(&MachineSettings {
        kinematics: kind,
        ..MachineSettings::default()
    });
    let s = seed as f64;
    let mut t = nominal;
    t.tilt = tilt(
        &nominal.tilt,
        Vector3::new(0.0, 1.0, 0.3 * s),
        0.03 + 0.01 * s,
        Vector3::new(0.0, 0.12, -0.09 * s),
    );
    t.rotary = tilt(
        &nominal.rotary,
        Vector3::new(1.0, -0.4 * s, 0.0),
        0.04,
        Vector3::new(0.1 * s, -0.13, 0.0),
    );
    let scanner = ScannerPose {
        rotation: rotation_about(&Vector3::new(0.3, -1.0, 0.2 * s), 0.15 + 0.05 * s),
        translation_mm: Vector3::new(0.31, -0.22 * s, 0.4),
    };
    (nominal, t, scanner)
}

fn recover(kind: KinematicsKind, seed: u64) {
    let (nominal, table, scanner) = truth(kind, seed);
    let sphere = Point3::new(40.0, 30.0, 25.0);
    let poses = default_poses(&nominal, &sphere);
    let art = synth_artefacts(
        &ArtefactTruth {
            table,
            scanner,
            sphere_table_mm: sphere,
            diameter_mm: DIAMETER_MM,
            tool_offset_mm: [0.0, 0.0],
        },
        &poses,
        0.010,
        seed,
    );
    let obs = observe(&art, DIAMETER_MM).expect("spheres");
    let cal = calibrate_cell(&nominal, &obs, &art.tool_mark_mm).expect("solve");
    let dir_tilt = direction_error_deg(&cal.table.tilt.direction, &table.tilt.direction);
    let dir_c = direction_error_deg(&cal.table.rotary.direction, &table.rotary.direction);
    let off_tilt = line_offset_mm(&table.tilt, &cal.table.tilt, &sphere) * 1e3;
    let off_c = line_offset_mm(&table.rotary, &cal.table.rotary, &sphere) * 1e3;
    let rot = rotation_error_deg(&cal.scanner.rotation, &scanner.rotation);
    let trans = (cal.scanner.translation_mm - scanner.translation_mm).norm() * 1e3;
    eprintln!(
        "{kind:?} seed {seed}: tilt dir {dir_tilt:.5}° point {off_tilt:.2} µm; C dir {dir_c:.5}° point {off_c:.2} µm; scanner {rot:.5}° {trans:.2} µm; rms {:.2} µm; sd: tilt {:.5}° {:.2} µm, C {:.5}° {:.2} µm, scanner {:.5}° {:.2} µm",
        cal.report.rms_um,
        cal.report.tilt_direction_sd_deg,
        cal.report.tilt_point_sd_um,
        cal.report.c_direction_sd_deg,
        cal.report.c_point_sd_um,
        cal.report.scanner_rotation_sd_deg,
        cal.report.scanner_translation_sd_um,
    );
    assert!(
        dir_tilt <= 0.003 && dir_c <= 0.003,
        "directions {dir_tilt} {dir_c}"
    );
    assert!(off_tilt <= 5.0 && off_c <= 5.0, "points {off_tilt} {off_c}");
    assert!(rot <= 0.003 && trans <= 5.0, "scanner {rot} {trans}");
}

#[test]
fn recovers_an_ac_cell_to_the_targets() {
    for seed in 1..=5 {
        recover(KinematicsKind::XyzacTrt, seed);
    }
}

#[test]
fn recovers_a_bc_cell_to_the_targets() {
    for seed in 1..=3 {
        recover(KinematicsKind::XyzbcTrt, seed);
    }
}

#[test]
fn degenerate_pose_sets_are_refused_naming_the_axis() {
    let (nominal, table, scanner) = truth(KinematicsKind::XyzacTrt, 1);
    let sphere = Point3::new(40.0, 30.0, 25.0);
    let mut poses = default_poses(&nominal, &sphere);
    for p in &mut poses {
        p.tilt_deg = 0.0;
    }
    let art = synth_artefacts(
        &ArtefactTruth {
            table,
            scanner,
            sphere_table_mm: sphere,
            diameter_mm: DIAMETER_MM,
            tool_offset_mm: [0.0, 0.0],
        },
        &poses,
        0.010,
        1,
    );
    let obs = observe(&art, DIAMETER_MM).expect("spheres");
    let e = calibrate_cell(&nominal, &obs, &art.tool_mark_mm).expect_err("no A motion");
    assert!(
        matches!(e, CalibError::Degenerate(_)) && e.to_string().contains("A line"),
        "{e}"
    );
    let e = calibrate_cell(&nominal, &obs[..5], &art.tool_mark_mm).expect_err("too few");
    assert!(
        matches!(
            e,
            CalibError::TooFew {
                needed: 8,
                got: 5,
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn converges_from_nominal_for_a_cell_far_off_it() {
    // 1° scanner rotation, 5 mm scanner translation, 0.1° axis tilts, 1 mm axis offsets.
    let nominal = TableModel::nominal(&MachineSettings::default());
    let mut table = nominal;
    table.tilt = tilt(
        &nominal.tilt,
        Vector3::new(0.0, 1.0, 0.5),
        0.1,
        Vector3::new(0.0, 0.7, -0.7),
    );
    table.rotary = tilt(
        &nominal.rotary,
        Vector3::new(1.0, 1.0, 0.0),
        0.1,
        Vector3::new(0.8, -0.6, 0.0),
    );
    let scanner = ScannerPose {
        rotation: rotation_about(&Vector3::new(0.5, -1.0, 0.7), 1.0),
        translation_mm: Vector3::new(3.0, -3.0, 2.6),
    };
    let sphere = Point3::new(40.0, 30.0, 25.0);
    let poses = default_poses(&nominal, &sphere);
    let art = synth_artefacts(
        &ArtefactTruth {
            table,
            scanner,
            sphere_table_mm: sphere,
            diameter_mm: DIAMETER_MM,
            tool_offset_mm: [0.0, 0.0],
        },
        &poses,
        0.010,
        9,
    );
    let obs = observe(&art, DIAMETER_MM).expect("spheres");
    let cal = calibrate_cell(&nominal, &obs, &art.tool_mark_mm).expect("solve");
    assert!(direction_error_deg(&cal.table.tilt.direction, &table.tilt.direction) <= 0.003);
    assert!(direction_error_deg(&cal.table.rotary.direction, &table.rotary.direction) <= 0.003);
    assert!(line_offset_mm(&table.tilt, &cal.table.tilt, &sphere) <= 0.005);
    assert!(line_offset_mm(&table.rotary, &cal.table.rotary, &sphere) <= 0.005);
    assert!(rotation_error_deg(&cal.scanner.rotation, &scanner.rotation) <= 0.003);
    assert!((cal.scanner.translation_mm - scanner.translation_mm).norm() <= 0.005);
    assert!(cal.report.rms_um < 3.0, "{:?}", cal.report);
}
