//! Scans of one clamped part taken at several machine poses, as one cloud in the work-piece
//! frame (`trimctl register` and `trimctl inspect`; DESIGN.md "Inspection", *Merge and fit*).
//!
//! A scanner fixed to the machine sees the part from where the machine puts it. What one pose
//! cannot see (the wall below an edge, an end face) another can, and the cell knows each pose:
//! every scan goes into the work-piece frame through the job's `[calibration]` and `[machine]`
//! at its own pose (`poses.csv` as `calibrate cell` reads it), and the clouds are concatenated.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use trim_cell::cell_model::{ScanChain, ScanPose};
use trim_geom::formats::read_points;
use trim_geom::{PointCloud, Similarity3};

use crate::config::JobConfig;

/// The scans `files` as one cloud in the work-piece frame. Without `poses` there must be one
/// scan, taken as it is, or with `config` through its `[calibration]` and `[part.scan_pose]`
/// (as `trimctl run` does). With `poses`, each scan is carried at the pose its file name has
/// there, through `config`'s cell (the nominal cell without one).
pub(crate) fn merged(
    files: &[PathBuf],
    poses: Option<&Path>,
    config: Option<&JobConfig>,
) -> anyhow::Result<PointCloud> {
    let read = |p: &PathBuf| read_points(p).with_context(|| format!("reading {}", p.display()));
    let Some(poses_file) = poses else {
        match files {
            [one] => {
                let scan = read(one)?;
                return match config {
                    Some(c) => c.workpiece_from_scan(&scan),
                    None => Ok(scan),
                };
            }
            _ => bail!(
                "{} scans without --poses: several scans merge only through their machine poses (poses.csv)",
                files.len()
            ),
        }
    };
    let (names, poses, kind) = crate::calibrate_cell::read_poses(poses_file)?;
    let defaults = JobConfig::default();
    let job = config.unwrap_or(&defaults);
    if job.plan.machine.kinematics != kind {
        bail!(
            "{}: the header names a {} cell, the job's [machine] is {}",
            poses_file.display(),
            kind.name(),
            job.plan.machine.kinematics.name()
        );
    }
    let plan = &job.plan;
    let mut points = Vec::new();
    for file in files {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(k) = names.iter().position(|n| *n == name) else {
            bail!(
                "{}: no pose for scan {name} in {}",
                file.display(),
                poses_file.display()
            );
        };
        let chain = ScanChain {
            table: plan.table(),
            scanner: plan.calibration.scanner(),
            pose: ScanPose {
                xyz_mm: poses[k].xyz_mm,
                tilt_deg: poses[k].tilt_deg,
                c_deg: poses[k].c_deg,
            },
            workpiece_origin_mm: plan.machine.workpiece_origin_mm.into(),
        };
        let scan = read(file)?
            .transformed(&Similarity3::from_isometry(
                chain.workpiece_from_scanner(),
                1.0,
            ))
            .with_context(|| format!("{} through [calibration] at its pose", file.display()))?;
        points.extend_from_slice(scan.points());
    }
    Ok(PointCloud::new(points)?)
}
