//! The scans `trimctl register` and `trimctl inspect` are given (`--scan`, `--poses`) as one
//! cloud in the work-piece frame (DESIGN.md "Inspection", *Merge and fit*). The merge of scans
//! at machine poses is trim-cell's (`trim_cell::scans_at_poses`); this module picks it or the
//! single scan from the command line's flags.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use trim_cell::scans_at_poses::{merge_files, read_poses};
use trim_geom::PointCloud;
use trim_geom::formats::read_points;

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
    let Some(poses_file) = poses else {
        match files {
            [one] => {
                let scan =
                    read_points(one).with_context(|| format!("reading {}", one.display()))?;
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
    let poses = read_poses(poses_file)?;
    let defaults = JobConfig::default();
    let job = config.unwrap_or(&defaults);
    poses.require_kinematics(job.plan.machine.kinematics)?;
    Ok(merge_files(files, &poses, &job.plan)?)
}
