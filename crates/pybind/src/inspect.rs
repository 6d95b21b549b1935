//! `trimctl.inspect`: registers a scan of the trimmed part onto the CAD and judges every contour
//! (trim-inspect; DESIGN.md "Inspection"). The results are typed classes built here, not JSON.

use pyo3::prelude::*;
use trim_geom::PointCloud;
use trim_geom::mesh::Mesh;
use trim_inspect::inputs::{check_path_on_cad, check_scan_for_fit};
use trim_inspect::{InspectError, InspectSettings, Placement, inspect as measure};
use trim_register::regional::{RegisterSettings, register};

use crate::arrays;
use crate::errors::{TrimError, geom_error, register_error, value_error};
use crate::gil::run_detached;
use crate::path::PyPath;
use crate::register::similarity_from_numpy;

/// One contour's inspection: what stands out of the nominal solid near it, what is missing
/// below it, how much of its opening is covered (and, where the scan sees a film over it from
/// both sides, the film's thickness), and the ISO 14253-1 verdict.
#[pyclass(module = "trimctl", name = "ContourInspection", frozen, get_all)]
#[derive(Debug, Clone)]
pub struct PyContourInspection {
    /// The contour id.
    pub id: i64,
    /// ``"pass"``, ``"fail"`` or ``"undecided"``.
    pub verdict: String,
    /// The largest excess above the nominal solid within the band (µm; 0: none above noise).
    pub excess_height_um: f64,
    /// The length of contour with excess (mm).
    pub excess_length_mm: f64,
    /// The deepest gouge below the nominal surface (µm).
    pub gouge_depth_um: f64,
    /// The share of the opening this contour rims still covered by a film (``None``: no
    /// opening); a burr web standing into it from the rim is excess, not cover.
    pub blocked_fraction: Option<f64>,
    /// The expanded uncertainty U (µm).
    pub uncertainty_um: f64,
    /// The share of the contour the scan covers, 0–1.
    pub coverage: f64,
    /// Why the verdict is what it is.
    pub reason: String,
    /// The registration's bound for the contour (µm), one term of U.
    pub bound_um: f64,
    /// The thickness of the film over the opening this contour rims (µm): its upper side's
    /// median reading less its underside's, along the opening's normal. ``None`` where no film
    /// is seen from both sides (no opening, an open one, or a film seen from above only).
    pub film_thickness_um: Option<f64>,
    /// The standard uncertainty (k = 1) of ``film_thickness_um`` (µm): the two medians' from
    /// the noise and a systematic 3 µm, in quadrature. ``None`` where no film is measured.
    pub film_uncertainty_um: Option<f64>,
}

#[pymethods]
impl PyContourInspection {
    fn __repr__(&self) -> String {
        format!(
            "ContourInspection(id={}, verdict={:?}, excess_height_um={:.1}, gouge_depth_um={:.1}, uncertainty_um={:.1})",
            self.id, self.verdict, self.excess_height_um, self.gouge_depth_um, self.uncertainty_um
        )
    }
}

/// A whole inspection: the tolerance, the scan noise used and each contour's result.
#[pyclass(module = "trimctl", name = "Inspection", frozen, get_all)]
#[derive(Debug, Clone)]
pub struct PyInspection {
    /// The tolerance judged against (µm).
    pub tolerance_um: f64,
    /// The scan noise used, given or estimated (µm).
    pub noise_um: f64,
    /// Per contour, in path order.
    pub contours: Vec<PyContourInspection>,
    /// Scan points measured.
    pub points_measured: usize,
}

#[pymethods]
impl PyInspection {
    /// The ids of the contours with this verdict (``"pass"``, ``"fail"``, ``"undecided"``).
    fn ids(&self, verdict: &str) -> PyResult<Vec<i64>> {
        if !["pass", "fail", "undecided"].contains(&verdict) {
            return Err(value_error(
                "verdict",
                format!("{verdict:?}: give \"pass\", \"fail\" or \"undecided\""),
            ));
        }
        Ok(self
            .contours
            .iter()
            .filter(|c| c.verdict == verdict)
            .map(|c| c.id)
            .collect())
    }

    fn __repr__(&self) -> String {
        let n = |v: &str| self.contours.iter().filter(|c| c.verdict == v).count();
        format!(
            "Inspection({} contours: {} pass, {} fail, {} undecided; tolerance {} µm, noise {:.1} µm)",
            self.contours.len(),
            n("pass"),
            n("fail"),
            n("undecided"),
            self.tolerance_um,
            self.noise_um
        )
    }
}

/// The mesh's triangles: an (N, 3) integer array (or float64 holding whole numbers) of vertex
/// indices.
fn triangle_indices(a: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    let bad = |v: String| value_error("cad_triangles", format!("{v} is not a vertex index"));
    if let Ok(ints) = a.extract::<numpy::PyReadonlyArray2<'_, i64>>() {
        let view = ints.as_array();
        if view.ncols() != 3 {
            return Err(value_error(
                "cad_triangles",
                format!("expected shape (N, 3), got {:?}", view.shape()),
            ));
        }
        return view
            .rows()
            .into_iter()
            .map(|r| {
                let idx = |v: i64| u32::try_from(v).map_err(|_| bad(v.to_string()));
                Ok([idx(r[0])?, idx(r[1])?, idx(r[2])?])
            })
            .collect();
    }
    arrays::points("cad_triangles", a)?
        .iter()
        .map(|t| {
            let idx = |v: f64| {
                (v >= 0.0 && v.fract() == 0.0 && v < f64::from(u32::MAX))
                    .then_some(v as u32)
                    .ok_or_else(|| bad(v.to_string()))
            };
            Ok([idx(t.x)?, idx(t.y)?, idx(t.z)?])
        })
        .collect()
}

fn inspect_error(e: InspectError) -> PyErr {
    match e {
        InspectError::Empty { .. }
        | InspectError::NonFinite { .. }
        | InspectError::InvalidSetting { .. }
        | InspectError::OutsideCad { .. }
        | InspectError::TooFewPoints { .. } => value_error("inspect", e),
        other => TrimError::new_err(other.to_string()),
    }
}

/// Registers ``scan`` (scan frame) onto the CAD (mesh ``cad_vertices``/``cad_triangles`` for
/// the distances, points ``cad_points`` with outward ``cad_normals`` for the fit) from the
/// fixture pose ``init`` (4 × 4 ``scan_from_cad``; default identity), then measures every
/// contour of ``path``: excess, gouge, blocked share, coverage, U and the verdict.
#[pyfunction]
#[pyo3(signature = (
    cad_vertices, cad_triangles, cad_points, cad_normals, path, scan, *,
    init = None, viewpoint_mm = None, tolerance_um = 30.0, band_mm = 0.5, noise_um = None
))]
#[expect(
    clippy::too_many_arguments,
    reason = "mirrors the Python signature: keyword options"
)]
pub fn inspect<'py>(
    py: Python<'py>,
    cad_vertices: &Bound<'py, PyAny>,
    cad_triangles: &Bound<'py, PyAny>,
    cad_points: &Bound<'py, PyAny>,
    cad_normals: &Bound<'py, PyAny>,
    path: PyPath,
    scan: &Bound<'py, PyAny>,
    init: Option<&Bound<'py, PyAny>>,
    viewpoint_mm: Option<&Bound<'py, PyAny>>,
    tolerance_um: f64,
    band_mm: f64,
    noise_um: Option<f64>,
) -> PyResult<PyInspection> {
    let viewpoint_mm = viewpoint_mm
        .map(|v| arrays::triple("viewpoint_mm", v))
        .transpose()?;
    let vertices = arrays::points("cad_vertices", cad_vertices)?;
    let triangles = triangle_indices(cad_triangles)?;
    let mesh = Mesh::new(vertices, triangles).map_err(geom_error)?;
    let cad = arrays::cloud_with_normals(
        arrays::points("cad_points", cad_points)?,
        "cad_normals",
        cad_normals,
    )?;
    let scan =
        PointCloud::new(arrays::points("scan", scan)?).map_err(|e| value_error("scan", e))?;
    let initial = match init {
        Some(m) => similarity_from_numpy("init", m)?,
        None => trim_geom::Similarity3::identity(),
    };
    let settings = InspectSettings {
        tolerance_um,
        band_mm,
        noise_um,
        ..InspectSettings::default()
    };
    settings.validate().map_err(inspect_error)?;
    let register_settings = RegisterSettings {
        scanner_viewpoint_mm: viewpoint_mm,
        ..RegisterSettings::default()
    };
    let path = path.inner;
    // Before the fit, which sizes its own structures by the path (a contour 10 m off aborted
    // the process allocating 174 GB) and reports a sparse scan in its own terms.
    check_path_on_cad(mesh.vertices(), &path).map_err(inspect_error)?;
    check_scan_for_fit(
        "scan",
        scan.len(),
        register_settings.coarse.min_voxel_points,
    )
    .map_err(inspect_error)?;
    let result = run_detached(py, move || {
        let reg =
            register(&cad, &scan, &path, &initial, &register_settings).map_err(register_error)?;
        measure(
            &mesh,
            &path,
            scan.points(),
            &Placement::from_registration(&reg),
            &settings,
        )
        .map_err(inspect_error)
    })??;
    Ok(PyInspection {
        tolerance_um: result.tolerance_um,
        noise_um: result.noise_um,
        points_measured: result.points_measured,
        contours: result
            .contours
            .into_iter()
            .map(|c| PyContourInspection {
                id: c.id,
                verdict: c.verdict.as_str().to_string(),
                excess_height_um: c.excess_height_um,
                excess_length_mm: c.excess_length_mm,
                gouge_depth_um: c.gouge_depth_um,
                blocked_fraction: c.blocked_fraction,
                uncertainty_um: c.uncertainty_um,
                coverage: c.coverage,
                reason: c.reason,
                bound_um: c.bound_um,
                film_thickness_um: c.film.map(|f| f.thickness_um),
                film_uncertainty_um: c.film.map(|f| f.uncertainty_um),
            })
            .collect(),
    })
}
