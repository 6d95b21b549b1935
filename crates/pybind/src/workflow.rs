//! The scripting workflow: the synthetic demo case, path registration, beam figures and the
//! planner. Settings come in as JSON objects with the job.toml keys (so a Python
//! dict and a job.toml table mean the same), geometry as numpy arrays.

use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use trim_cell::{Beam, CellError, LaserLimits};
use trim_plan::PlanError;
use trim_plan::hatch::{HatchError, HatchSettings, hatch};
use trim_plan::planner::{PlanSettings, plan_with_report};
use trim_register::regional::{RegisterSettings, register};
use trim_synth::{SynthParams, generate};

use crate::arrays;
use crate::errors::{PlanningError, geom_error, register_error, value_error};
use crate::gil::run_detached;
use crate::path::{PyPath, cloud_to_numpy};
use crate::register::{matrix_to_numpy, similarity_from_numpy};
use crate::results::{ContourQuality, to_py};

/// Parses settings JSON into `T`, naming the offending key in a `ValueError`.
pub(crate) fn settings_from_json<T: serde::de::DeserializeOwned>(
    what: &str,
    json: &str,
) -> PyResult<T> {
    let de = &mut serde_json::Deserializer::from_str(json);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        value_error(what, format!("{key}: {}", e.inner()))
    })
}

/// Maps a planning error: bad settings to `ValueError`, the rest to `PlanningError`.
pub(crate) fn plan_error(e: PlanError) -> PyErr {
    match e {
        PlanError::Cell(CellError::InvalidSetting { .. }) => value_error("settings", e),
        PlanError::Cell(CellError::OutsideLaserLimits { .. }) => value_error("laser_limits", e),
        other => PlanningError::new_err(other.to_string()),
    }
}

/// Generates the synthetic ceramic-core case. `params_json`: the `SynthParams` keys.
/// Returns a dict of numpy arrays, Paths and the nominal fixture pose.
#[pyfunction]
pub fn synth_case<'py>(py: Python<'py>, params_json: &str) -> PyResult<Bound<'py, PyDict>> {
    let params: SynthParams = settings_from_json("synth", params_json)?;
    params.validate().map_err(geom_error)?;
    let case = run_detached(py, move || generate(&params))?.map_err(geom_error)?;
    let d = PyDict::new(py);
    let (cad, cad_normals) = cloud_to_numpy(py, &case.cad_points);
    d.set_item("cad_points", cad)?;
    d.set_item("cad_normals", cad_normals)?;
    let (scan, scan_normals) = cloud_to_numpy(py, &case.scan);
    d.set_item("scan", scan)?;
    d.set_item("scan_normals", scan_normals)?;
    d.set_item("cad_vertices", arrays::from_points(py, &case.cad_vertices))?;
    let tris: Vec<[f64; 3]> = case
        .cad_triangles
        .iter()
        .map(|t| [f64::from(t[0]), f64::from(t[1]), f64::from(t[2])])
        .collect();
    d.set_item("cad_triangles", arrays::from_rows(py, tris.into_iter()))?;
    d.set_item("path", PyPath { inner: case.path })?;
    d.set_item("truth", PyPath { inner: case.truth })?;
    d.set_item(
        "scan_from_cad_nominal",
        matrix_to_numpy(py, &case.scan_from_cad_nominal.to_homogeneous()),
    )?;
    d.set_item(
        "scan_from_cad_true",
        matrix_to_numpy(py, &case.scan_from_cad_true.to_homogeneous()),
    )?;
    Ok(d)
}

/// What [`register_path`] returns: the registered path, the quality report (dicts), the coarse
/// `scan_from_cad` (4×4) and each contour's typed quality.
type Registered<'py> = (
    PyPath,
    Bound<'py, PyAny>,
    Bound<'py, PyArray2<f64>>,
    Vec<ContourQuality>,
);

/// Registers `path` (CAD frame) onto the scan. `cad` needs outward normals. Returns
/// `(registered Path, quality report as a dict, scan_from_cad 4×4, [ContourQuality])`.
#[pyfunction]
#[pyo3(signature = (cad, cad_normals, scan, path, init, settings_json, scan_normals = None))]
#[expect(
    clippy::too_many_arguments,
    reason = "mirrors the Python wrapper's arguments"
)]
pub fn register_path<'py>(
    py: Python<'py>,
    cad: &Bound<'py, PyAny>,
    cad_normals: &Bound<'py, PyAny>,
    scan: &Bound<'py, PyAny>,
    path: PyPath,
    init: Option<&Bound<'py, PyAny>>,
    settings_json: &str,
    scan_normals: Option<&Bound<'py, PyAny>>,
) -> PyResult<Registered<'py>> {
    let settings: RegisterSettings = settings_from_json("register settings", settings_json)?;
    settings.validate().map_err(register_error)?;
    let cad = arrays::cloud_with_normals(arrays::points("cad", cad)?, "cad_normals", cad_normals)?;
    let scan = arrays::cloud(arrays::points("scan", scan)?, "scan_normals", scan_normals)?;
    let initial = match init {
        Some(m) => similarity_from_numpy("init", m)?,
        None => trim_geom::Similarity3::identity(),
    };
    let inner = path.inner;
    let registration = run_detached(py, move || {
        register(&cad, &scan, &inner, &initial, &settings)
    })?
    .map_err(register_error)?;
    let report = to_py(py, "report", &registration.report)?;
    let quality = registration
        .report
        .contours
        .iter()
        .map(|c| ContourQuality::of(py, c))
        .collect::<PyResult<Vec<_>>>()?;
    Ok((
        PyPath {
            inner: registration.path,
        },
        report,
        matrix_to_numpy(py, &registration.scan_from_cad.to_homogeneous()),
        quality,
    ))
}

/// Refuses `beam`'s operating point when it is outside `limits_json` (a laser profile's
/// `[limits]` keys: `pulse_energy_uj_max`, `average_power_w_max`, `rep_rate_khz_min`,
/// `rep_rate_khz_max`) with a `ValueError` naming every limit broken; nothing to check without
/// limits.
fn check_laser_limits(beam: &Beam, limits_json: Option<&str>) -> PyResult<()> {
    let Some(json) = limits_json else {
        return Ok(());
    };
    let limits: LaserLimits = settings_from_json("laser_limits", json)?;
    limits
        .validate()
        .map_err(|e| value_error("laser_limits", e))?;
    beam.check_limits(&limits, "laser_limits")
        .map_err(|e| plan_error(e.into()))
}

/// The beam figures (the keys of `trimctl beam`) as a dict. `beam_json`: the `[beam]` keys;
/// `limits_json`: the source's limits (a laser profile's `[limits]` keys), which the operating
/// point must be within.
#[pyfunction]
#[pyo3(signature = (beam_json, limits_json = None))]
pub fn beam_report<'py>(
    py: Python<'py>,
    beam_json: &str,
    limits_json: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    let beam: Beam = settings_from_json("beam", beam_json)?;
    beam.validate().map_err(|e| plan_error(e.into()))?;
    check_laser_limits(&beam, limits_json)?;
    to_py(py, "beam", &beam.report())
}

/// Plans a job from a registered path. `settings_json`: the planner's job.toml keys
/// (`max_incidence_deg`, `beam`, `zoning`, `layers`, `field`, `machine`, `galvo`). Returns
/// `(job, zone table, {"k": .., "automatic_k": .., "pieces": ..})` as Python dicts and lists
/// built here (the Job's serde form). `limits_json`:
/// as for [`beam_report`], checked against the settings' beam before planning.
#[pyfunction]
#[pyo3(signature = (path, settings_json, limits_json = None))]
pub fn plan_path<'py>(
    py: Python<'py>,
    path: PyPath,
    settings_json: &str,
    limits_json: Option<&str>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let settings: PlanSettings = settings_from_json("plan settings", settings_json)?;
    settings.validate().map_err(|e| plan_error(e.into()))?;
    check_laser_limits(&settings.beam, limits_json)?;
    let out =
        run_detached(py, move || plan_with_report(&path.inner, &settings))?.map_err(plan_error)?;
    let meta = serde_json::json!({
        "k": out.k,
        "automatic_k": out.automatic_k,
        "pieces": out.pieces,
    });
    Ok((
        to_py(py, "job", &out.job)?,
        to_py(py, "table", &out.table)?,
        to_py(py, "meta", &meta)?,
    ))
}

/// Plans equal-spacing hatch tracks on a scanned surface (`trim_plan::hatch`). `points` (N, 3)
/// and optional `normals` (N, 3): the surface scan, mm; `boundary` (M, 3): a closed polyline on
/// it (a polygon: the last row may repeat the first, else the closing edge is implied); `settings_json`: the `[[hatch]]` keys (`pitch_mm`,
/// `angle_deg`, `method`, `step_mm`, `chord_tolerance_mm`, `outline`, `grid_mm`). Returns the
/// tracks as a Path: contour = track id in serpentine order, features = unit surface normals.
/// `spot`: `(spot diameter mm, overlap)`, which sets the pitch (`HatchSettings::from_spot`).
#[pyfunction]
#[pyo3(signature = (points, boundary, settings_json, normals = None, spot = None))]
pub fn hatch_surface(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    boundary: &Bound<'_, PyAny>,
    settings_json: &str,
    normals: Option<&Bound<'_, PyAny>>,
    spot: Option<(f64, f64)>,
) -> PyResult<PyPath> {
    let mut settings: HatchSettings = settings_from_json("hatch settings", settings_json)?;
    if let Some((diameter_mm, overlap)) = spot {
        settings.pitch_mm = HatchSettings::from_spot(diameter_mm, overlap)
            .map_err(hatch_error)?
            .pitch_mm;
    }
    settings.validate().map_err(hatch_error)?;
    let points = arrays::points("points", points)?;
    let boundary = arrays::points("boundary", boundary)?;
    let cloud = arrays::cloud(points, "normals", normals)?;
    let planned =
        run_detached(py, move || hatch(&cloud, &boundary, &settings))?.map_err(hatch_error)?;
    let inner = planned.to_path().map_err(hatch_error)?;
    Ok(PyPath { inner })
}

/// Maps a hatching error: bad settings and inputs to `ValueError`, the rest to `PlanningError`.
fn hatch_error(e: HatchError) -> PyErr {
    match e {
        HatchError::InvalidSetting { .. }
        | HatchError::NonFinite { .. }
        | HatchError::EmptyScan
        | HatchError::BoundaryTooShort { .. }
        | HatchError::BoundaryNotClosed { .. }
        | HatchError::BoundaryOffSurface { .. } => value_error("hatch", e),
        other => PlanningError::new_err(other.to_string()),
    }
}
