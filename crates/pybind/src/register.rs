//! Registration bindings: ICP and the Umeyama similarity fit.

use nalgebra::Matrix4;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use trim_geom::PointCloud;
use trim_geom::math::{Similarity3, Vector3};
use trim_geom::normals::{Orientation, estimate_normals};
use trim_geom::transform::{similarity_from_matrix, to_matrix};
use trim_register::{IcpMethod, IcpSettings, IcpTarget, RegisterError, RobustKernel};

use crate::arrays;
use crate::errors::{geom_error, register_error, value_error};
use crate::gil::run_detached;

/// Neighbours used to estimate target normals for point-to-plane ICP when none are given.
pub const DEFAULT_NORMAL_NEIGHBOURS: usize = 16;

/// A 4×4 homogeneous matrix as a numpy array.
pub fn matrix_to_numpy<'py>(py: Python<'py>, m: &Matrix4<f64>) -> Bound<'py, PyArray2<f64>> {
    let rows = (0..4).map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]]);
    arrays::from_rows(py, rows.collect::<Vec<_>>().into_iter())
}

/// A similarity from a 4×4 numpy array (checked: finite, proper scaled rotation).
pub fn similarity_from_numpy(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Similarity3> {
    let rows = arrays::rows::<4>(name, obj)?;
    if rows.len() != 4 {
        return Err(value_error(
            name,
            format!("expected shape (4, 4), got ({}, 4)", rows.len()),
        ));
    }
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    similarity_from_matrix(&m).map_err(|e| value_error(name, e))
}

/// The result of [`icp`].
#[pyclass(module = "trimctl", frozen, get_all)]
pub struct IcpResult {
    /// The 4×4 `target_from_source` transform (scale included).
    pub target_from_source: Py<PyArray2<f64>>,
    /// The scale (1.0 for a rigid fit).
    pub scale: f64,
    /// RMS residual over the final correspondences, mm.
    pub rmse_mm: f64,
    /// Fraction of source points with a correspondence.
    pub fitness: f64,
    /// Number of final correspondences.
    pub correspondences: usize,
    /// Iterations run.
    pub iterations: usize,
    /// Whether ICP met its convergence test before the iteration cap.
    pub converged: bool,
    /// Eigenvalues (ascending) of the final normal matrix: small ones mark directions the data
    /// does not fix.
    pub eigenvalues: Py<PyArray1<f64>>,
}

#[pymethods]
impl IcpResult {
    fn __repr__(&self) -> String {
        format!(
            "IcpResult(scale={:.9}, rmse_mm={:.6}, fitness={:.4}, iterations={}, converged={})",
            self.scale, self.rmse_mm, self.fitness, self.iterations, self.converged
        )
    }
}

fn parse_method(method: &str) -> PyResult<IcpMethod> {
    match method {
        "point_to_plane" => Ok(IcpMethod::PointToPlane),
        "point_to_point" => Ok(IcpMethod::PointToPoint),
        other => Err(value_error(
            "method",
            format!("expected \"point_to_plane\" or \"point_to_point\", got {other:?}"),
        )),
    }
}

fn parse_kernel(kernel: Option<(&str, f64)>) -> PyResult<RobustKernel> {
    match kernel {
        None => Ok(RobustKernel::None),
        Some(("huber", k)) => Ok(RobustKernel::Huber { k_mm: k }),
        Some(("tukey", k)) => Ok(RobustKernel::Tukey { c_mm: k }),
        Some((other, _)) => Err(value_error(
            "kernel",
            format!("expected (\"huber\" | \"tukey\", threshold_mm), got {other:?}"),
        )),
    }
}

/// `max_iterations`, refused naming it (pyo3 raised a bare `OverflowError` for `-1`).
fn iterations(n: &Bound<'_, PyAny>) -> PyResult<usize> {
    arrays::named("max_iterations", n, "a whole number of iterations")
}

/// ICP of `source` onto `target` ((N, 3) float64, mm). Pairs farther apart than
/// `max_distance_mm` are not correspondences. Point-to-plane uses `target_normals`, or estimates
/// them from 16 neighbours when not given. Returns an [`IcpResult`].
#[pyfunction]
#[pyo3(signature = (
    source, target, *, method = "point_to_plane", scale = false, max_distance_mm = 1.0,
    max_iterations = 50, init = None, target_normals = None, kernel = None, trim = 0.0
))]
#[expect(
    clippy::too_many_arguments,
    reason = "mirrors the Python keyword-only signature"
)]
pub fn icp(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    method: &str,
    scale: bool,
    max_distance_mm: f64,
    #[pyo3(from_py_with = iterations)] max_iterations: usize,
    init: Option<&Bound<'_, PyAny>>,
    target_normals: Option<&Bound<'_, PyAny>>,
    kernel: Option<&Bound<'_, PyAny>>,
    trim: f64,
) -> PyResult<IcpResult> {
    let method = parse_method(method)?;
    let kernel: Option<(String, f64)> = kernel
        .map(|k| {
            arrays::named(
                "kernel",
                k,
                "a (name, threshold) pair such as ('huber', 0.1)",
            )
        })
        .transpose()?;
    let kernel = parse_kernel(kernel.as_ref().map(|(n, k)| (n.as_str(), *k)))?;
    let source = PointCloud::new(arrays::points("source", source)?).map_err(geom_error)?;
    let target_points = arrays::points("target", target)?;
    // Given normals are checked here, so their errors name the argument.
    let given = target_normals
        .map(|n| arrays::cloud_with_normals(target_points.clone(), "target_normals", n))
        .transpose()?;
    let initial = match init {
        Some(m) => similarity_from_numpy("init", m)?,
        None => Similarity3::identity(),
    };
    let settings = IcpSettings {
        method,
        with_scale: scale,
        max_correspondence_distance_mm: max_distance_mm,
        max_iterations,
        kernel,
        trim_fraction: trim,
        ..IcpSettings::default()
    };
    settings.validate().map_err(register_error)?;
    let result = run_detached(py, move || -> Result<_, RegisterError> {
        let target = match (given, method) {
            (Some(cloud), _) => cloud,
            (None, IcpMethod::PointToPlane) => {
                let n = estimate_normals(
                    &target_points,
                    DEFAULT_NORMAL_NEIGHBOURS,
                    Orientation::AlongReference(Vector3::z()),
                )?;
                PointCloud::with_normals(target_points, n)?
            }
            (None, IcpMethod::PointToPoint) => PointCloud::new(target_points)?,
        };
        let target = IcpTarget::new(target)?;
        trim_register::icp(&source, &target, &initial, &settings)
    })?
    .map_err(register_error)?;
    Ok(IcpResult {
        target_from_source: matrix_to_numpy(py, &to_matrix(&result.target_from_source)).unbind(),
        scale: result.scale,
        rmse_mm: result.rmse_mm,
        fitness: result.fitness,
        correspondences: result.correspondences,
        iterations: result.iterations,
        converged: result.converged,
        eigenvalues: PyArray1::from_vec(py, result.eigenvalues).unbind(),
    })
}

/// The result of [`umeyama`].
#[pyclass(module = "trimctl", frozen, get_all)]
pub struct UmeyamaResult {
    /// The 4×4 `b_from_a` similarity (the rows of `a` onto the rows of `b`, scale included).
    pub b_from_a: Py<PyArray2<f64>>,
    /// Its scale (1.0 for a rigid fit).
    pub scale: f64,
    /// The RMS residual over the pairs, mm.
    pub rmse_mm: f64,
}

#[pymethods]
impl UmeyamaResult {
    fn __repr__(&self) -> String {
        format!(
            "UmeyamaResult(scale={:.9}, rmse_mm={:.6})",
            self.scale, self.rmse_mm
        )
    }
}

/// The closed-form similarity (Umeyama) that maps the rows of `a` onto the rows of `b`: an
/// [`UmeyamaResult`] with the 4×4 `b_from_a`, its scale and the RMS residual (mm).
#[pyfunction]
#[pyo3(signature = (a, b, *, scale = true))]
pub fn umeyama<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
    scale: bool,
) -> PyResult<UmeyamaResult> {
    let a = arrays::points("a", a)?;
    let b = arrays::points("b", b)?;
    if a.len() != b.len() {
        return Err(value_error(
            "b",
            format!("has {} rows, a has {}: rows must pair up", b.len(), a.len()),
        ));
    }
    let fit =
        run_detached(py, move || trim_register::umeyama(&a, &b, scale))?.map_err(register_error)?;
    let m = to_matrix(&fit.target_from_source);
    Ok(UmeyamaResult {
        b_from_a: matrix_to_numpy(py, &m).unbind(),
        scale: fit.target_from_source.scaling(),
        rmse_mm: fit.rms_mm,
    })
}
