//! The Job's machine poses checked against the machine's axis limits (`[machine]`) before
//! anything moves: `run` (the executor) and `frame` refuse a job with a pose outside them,
//! whatever validation said or however the job file was edited.

use trim_cell::job::{Job, LayerKey, Pose};
use trim_cell::kinematics::{AxisPose, MachineSettings, limit_violation};

use crate::cnc::AXES;

/// A layer's pose the machine cannot take.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key}: pose {pose} outside the machine ([machine]): {why}")]
pub struct PoseOutOfLimits {
    /// The layer.
    pub key: LayerKey,
    /// The pose, as `x=… y=… …` (mm, degrees).
    pub pose: String,
    /// Which axis and limit.
    pub why: String,
}

fn pose_text(pose: &Pose) -> String {
    pose.0
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Why `pose` is not one the machine can take: an axis the CNC does not have, a value that is
/// not finite, an axis of the kinematics missing, or outside the world or joint limits.
pub fn pose_violation(machine: &MachineSettings, pose: &Pose) -> Option<String> {
    for (axis, v) in &pose.0 {
        if !AXES.contains(&axis.as_str()) {
            return Some(format!("unknown axis {axis:?}"));
        }
        if !v.is_finite() {
            return Some(format!("axis {axis} = {v}"));
        }
    }
    let Some(axis_pose) = AxisPose::from_job_pose(pose, machine.kinematics) else {
        return Some(format!(
            "an axis of the {:?} kinematics is missing",
            machine.kinematics
        ));
    };
    limit_violation(machine, &axis_pose)
}

/// Checks the poses of `keys`' layers (every layer when `None`).
pub fn check_poses(
    job: &Job,
    machine: &MachineSettings,
    keys: Option<&[LayerKey]>,
) -> Result<(), PoseOutOfLimits> {
    for (key, _, layer) in job.layers() {
        if keys.is_some_and(|k| !k.contains(&key)) {
            continue;
        }
        if let Some(why) = pose_violation(machine, &layer.pose) {
            return Err(PoseOutOfLimits {
                key,
                pose: pose_text(&layer.pose),
                why,
            });
        }
    }
    Ok(())
}
