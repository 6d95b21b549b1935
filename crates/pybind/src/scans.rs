//! Scans taken at several machine poses, merged into one cloud in the work-piece frame
//! (`trim_cell::scans_at_poses`; DESIGN.md "Inspection", *Merge and fit*).

use numpy::PyArray2;
use pyo3::prelude::*;
use std::path::PathBuf;
use trim_cell::cell_model::ScanPose;

use trim_cell::scans_at_poses::{merge, merge_files, read_poses as read_poses_file};
use trim_geom::PointCloud;
use trim_plan::planner::PlanSettings;

use crate::arrays;
use crate::errors::{scans_error, value_error};
use crate::gil::run_detached;
use crate::workflow::{plan_error, settings_from_json};

/// Merges scans taken at machine poses into one cloud in the work-piece frame. `scans`: a
/// sequence of `(N_i, 3)` float64 arrays, scanner frame, mm; `poses_json`: one JSON object per
/// scan with the `[part.scan_pose]` keys (`xyz_mm`, `tilt_deg`, `c_deg`); `settings_json`: the
/// planner's job.toml keys, of which `machine` and `calibration` carry the scans. Returns the
/// `(N, 3)` merged points, scans in order.
#[pyfunction]
pub fn merge_scans<'py>(
    py: Python<'py>,
    scans: &Bound<'py, PyAny>,
    poses_json: Vec<String>,
    settings_json: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let settings: PlanSettings = settings_from_json("settings", settings_json)?;
    settings.validate().map_err(|e| plan_error(e.into()))?;
    let clouds = scans
        .try_iter()
        .map_err(|_| value_error("scans", "expected a sequence of (N, 3) float64 arrays"))?
        .enumerate()
        .map(|(k, scan)| {
            let name = format!("scans[{k}]");
            let points = arrays::points(&name, &scan?)?;
            PointCloud::new(points).map_err(|e| value_error(&name, e))
        })
        .collect::<PyResult<Vec<_>>>()?;
    if clouds.len() != poses_json.len() {
        return Err(value_error(
            "scans, poses",
            format!(
                "{} scans but {} poses: give one pose per scan",
                clouds.len(),
                poses_json.len()
            ),
        ));
    }
    let at = poses_json
        .iter()
        .enumerate()
        .map(|(k, json)| settings_from_json::<ScanPose>(&format!("poses[{k}]"), json))
        .collect::<PyResult<Vec<_>>>()?;
    let scans: Vec<(ScanPose, PointCloud)> = at.into_iter().zip(clouds).collect();
    let merged = run_detached(py, move || merge(&scans, &settings))?.map_err(scans_error)?;
    Ok(arrays::from_points(py, merged.points()))
}

/// One row of poses.csv as Python takes it: the scan's file name, X, Y, Z (mm), the tilting
/// axis and C (degrees).
type PoseRow = (String, [f64; 3], f64, f64);

/// Reads poses.csv (`scan,x,y,z,a,c`, or `b` for `a` on a B/C cell), the format `trimctl
/// register --poses` and `calibrate cell` read. Returns the kinematics its header implies
/// (`"xyzac-trt"` or `"xyzbc-trt"`) and its rows in file order as `(scan file name, [x, y, z]
/// mm, tilt deg, c deg)`. Errors name the file and the line (`FileFormatError`).
#[pyfunction]
pub fn read_poses(py: Python<'_>, path: PathBuf) -> PyResult<(String, Vec<PoseRow>)> {
    let poses = run_detached(py, move || read_poses_file(&path))?.map_err(scans_error)?;
    let rows = poses
        .rows
        .iter()
        .map(|r| (r.scan.clone(), r.pose.xyz_mm, r.pose.tilt_deg, r.pose.c_deg))
        .collect();
    Ok((poses.kinematics.name().to_owned(), rows))
}

/// Merges the scan files `files` (PLY/PCD/XYZ, scanner frame, mm), each at the pose its file
/// name has in the poses file `poses`, into one cloud in the work-piece frame, as `trimctl
/// register --scan A --scan B --poses poses.csv` does: the poses file's header must name the
/// cell of `settings_json`'s `machine` (the nominal A/C cell without it). Returns the `(N, 3)`
/// merged points, files in order.
#[pyfunction]
pub fn merge_scan_files<'py>(
    py: Python<'py>,
    files: Vec<PathBuf>,
    poses: PathBuf,
    settings_json: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let settings: PlanSettings = settings_from_json("settings", settings_json)?;
    settings.validate().map_err(|e| plan_error(e.into()))?;
    let merged = run_detached(py, move || {
        let poses = read_poses_file(&poses)?;
        poses.require_kinematics(settings.machine.kinematics)?;
        merge_files(&files, &poses, &settings)
    })?
    .map_err(scans_error)?;
    Ok(arrays::from_points(py, merged.points()))
}
