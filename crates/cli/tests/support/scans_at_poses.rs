//! Scans as a scanner fixed to the machine takes them: each part of a work-piece-frame cloud
//! carried into the scanner frame at its own machine pose through the nominal cell, written as
//! a PLY, with the `poses.csv` that `--poses` reads.

use std::path::{Path, PathBuf};

use trim_cell::cell_model::{ScanChain, ScanPose, ScannerPose, TableModel};
use trim_cell::kinematics::MachineSettings;
use trim_geom::formats::{PlyEncoding, write_ply};
use trim_geom::{Point3, PointCloud, Similarity3};
use trim_register::regional::{moments, principal_axes};

/// Writes `{prefix}{k}.ply` for each `(pose, points)` and `poses.csv` naming them, in `dir`.
/// Returns the scan files in order and the poses file.
///
/// # Panics
/// On an empty part or a failed write: this is test code.
pub fn write_scans_at_poses(
    dir: &Path,
    prefix: &str,
    parts: &[(ScanPose, Vec<Point3>)],
) -> (Vec<PathBuf>, PathBuf) {
    let machine = MachineSettings::default();
    let mut csv = String::from("scan,x,y,z,a,c\n");
    let mut files = Vec::new();
    for (k, (pose, points)) in parts.iter().enumerate() {
        let chain = ScanChain {
            table: TableModel::nominal(&machine),
            scanner: ScannerPose::identity(),
            pose: *pose,
            workpiece_origin_mm: machine.workpiece_origin_mm.into(),
        };
        let scanner_from_workpiece =
            Similarity3::from_isometry(chain.workpiece_from_scanner().inverse(), 1.0);
        let seen: Vec<Point3> = points.iter().map(|p| scanner_from_workpiece * p).collect();
        let name = format!("{prefix}{k}.ply");
        let file = dir.join(&name);
        write_ply(
            &file,
            &PointCloud::new(seen).expect("a non-empty part"),
            PlyEncoding::BinaryLittleEndian,
        )
        .expect("the scan is written");
        csv.push_str(&format!(
            "{name},{},{},{},{},{}\n",
            pose.xyz_mm[0], pose.xyz_mm[1], pose.xyz_mm[2], pose.tilt_deg, pose.c_deg
        ));
        files.push(file);
    }
    let poses_file = dir.join("poses.csv");
    std::fs::write(&poses_file, csv).expect("poses.csv is written");
    (files, poses_file)
}

/// `scan`'s points split by the side of the part they lie on (across its thinnest axis): the
/// first side at `poses[0]`, the other at `poses[1]`, as a scanner fixed to the machine sees
/// one side of the part at each of two poses.
#[allow(
    dead_code,
    reason = "not every test file that includes this module splits a scan by side"
)]
pub fn split_by_side(scan: &PointCloud, poses: [ScanPose; 2]) -> Vec<(ScanPose, Vec<Point3>)> {
    let (centre, cov) = moments(scan.points());
    let thickness = principal_axes(&cov).0.column(2).into_owned();
    poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let side = scan
                .points()
                .iter()
                .filter(|p| ((*p - centre).dot(&thickness) >= 0.0) == (k == 0))
                .copied()
                .collect();
            (*pose, side)
        })
        .collect()
}
