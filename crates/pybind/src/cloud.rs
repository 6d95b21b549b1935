//! Point-cloud processing from trim-geom: normals and voxel down-sampling.

use numpy::PyArray2;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use trim_geom::math::{Point3, Vector3};
use trim_geom::normals::{Orientation, estimate_normals as estimate};
use trim_geom::voxel::voxel_downsample as downsample;

use crate::arrays::{self, Array};
use crate::errors::{geom_error, refuse_renamed, value_error};
use crate::gil::run_detached;

/// Estimates unit normals by PCA over the `k` nearest neighbours, oriented toward `viewpoint`
/// (mm) or along `reference`; with neither, along +Z. A point whose neighbours span no plane
/// (at one place or on one line) gets +Z with a `TrimWarning` counting such points; a cloud
/// of only such points raises `ValueError`.
#[pyfunction]
#[pyo3(signature = (points, *, k = 16, viewpoint = None, reference = None))]
pub fn estimate_normals<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = neighbours)] k: usize,
    viewpoint: Option<&Bound<'py, PyAny>>,
    reference: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let pts = arrays::points("points", points)?;
    let viewpoint = viewpoint
        .map(|v| arrays::triple("viewpoint", v))
        .transpose()?;
    let reference = reference
        .map(|r| arrays::triple("reference", r))
        .transpose()?;
    let orientation = match (viewpoint, reference) {
        (Some(_), Some(_)) => {
            return Err(value_error(
                "viewpoint",
                "give either viewpoint or reference, not both",
            ));
        }
        (Some(v), None) => Orientation::TowardViewpoint(Point3::from(v)),
        (None, Some(r)) => Orientation::AlongReference(Vector3::from(r)),
        (None, None) => Orientation::AlongReference(Vector3::z()),
    };
    let normals = run_detached(py, move || estimate(&pts, k, orientation))?.map_err(geom_error)?;
    Ok(arrays::from_vectors(py, &normals))
}

/// `k`, refused naming it (pyo3 raised a bare `OverflowError` for `k=-1`).
fn neighbours(k: &Bound<'_, PyAny>) -> PyResult<usize> {
    arrays::named("k", k, "a whole number of neighbours")
}

/// Down-samples to one point per occupied `voxel_mm` cube: the centroid of its points.
/// Returns `(points, normals)`; `normals` is `None` when none were given. The old name `voxel`
/// raises `TypeError` naming `voxel_mm`.
#[pyfunction]
#[pyo3(signature = (points, *, voxel_mm = None, normals = None, **renamed))]
pub fn voxel_downsample<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    voxel_mm: Option<f64>,
    normals: Option<&Bound<'py, PyAny>>,
    renamed: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Array<'py>, Option<Array<'py>>)> {
    refuse_renamed("voxel_downsample", renamed, &[("voxel", "voxel_mm")])?;
    let voxel = voxel_mm.ok_or_else(|| {
        PyTypeError::new_err("voxel_downsample() missing required keyword argument 'voxel_mm'")
    })?;
    let pts = arrays::points("points", points)?;
    let cloud = arrays::cloud(pts, "normals", normals)?;
    let down = run_detached(py, move || downsample(&cloud, voxel))?.map_err(geom_error)?;
    Ok((
        arrays::from_points(py, down.points()),
        down.normals().map(|n| arrays::from_vectors(py, n)),
    ))
}
