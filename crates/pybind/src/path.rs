//! Trimming paths and file I/O: `read_points`, `read_path`, `write_path` and the `Path` class.

use std::path::PathBuf;

use numpy::PyArray1;
use pyo3::prelude::*;
use trim_geom::formats;
use trim_geom::{Contour, ContourId, PointCloud};

use crate::arrays::{self, Array};
use crate::errors::{geom_error, value_error};
use crate::gil::run_detached;

/// A trimming path: contours with ids, points (mm) and unit feature vectors, as in the path CSV
/// (`contour,x,y,z,u,v,w`). Row arrays hold one row per point, contour after contour.
#[pyclass(module = "trimctl", name = "Path", frozen)]
#[derive(Clone)]
pub struct PyPath {
    /// The Rust path.
    pub inner: trim_geom::Path,
}

#[pymethods]
impl PyPath {
    /// A path from row arrays: `ids` (N,) integers, `points` (N, 3), `features` (N, 3). Rows of
    /// one contour must be contiguous and in path order; each contour needs ≥ 2 points.
    #[new]
    fn new(
        ids: &Bound<'_, PyAny>,
        points: &Bound<'_, PyAny>,
        features: &Bound<'_, PyAny>,
    ) -> PyResult<PyPath> {
        let ids: Vec<i64> = ids
            .extract::<Vec<i64>>()
            .map_err(|_| value_error("ids", "expected a sequence or array of integers"))?;
        let points = arrays::points("points", points)?;
        let features = arrays::vectors("features", features)?;
        if ids.len() != points.len() || features.len() != points.len() {
            return Err(value_error(
                "ids",
                format!(
                    "ids, points and features must have one row per point: got {}, {}, {}",
                    ids.len(),
                    points.len(),
                    features.len()
                ),
            ));
        }
        let mut contours = Vec::new();
        let mut start = 0;
        while start < ids.len() {
            let id = ids[start];
            let end = ids[start..]
                .iter()
                .position(|&i| i != id)
                .map_or(ids.len(), |n| start + n);
            if contours.iter().any(|c: &Contour| c.id() == id) {
                return Err(value_error(
                    "ids",
                    format!(
                        "contour {id} appears again at row {start}: rows of a contour must be contiguous"
                    ),
                ));
            }
            contours.push(
                Contour::with_features(
                    id,
                    points[start..end].to_vec(),
                    features[start..end].to_vec(),
                )
                .map_err(|e| value_error("points", e))?,
            );
            start = end;
        }
        let inner = trim_geom::Path::new(contours).map_err(|e| value_error("ids", e))?;
        Ok(PyPath { inner })
    }

    /// The contour id of each row, (N,) int64.
    #[getter]
    fn ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let ids: Vec<i64> = self
            .inner
            .contours()
            .iter()
            .flat_map(|c| std::iter::repeat_n(c.id(), c.points().len()))
            .collect();
        PyArray1::from_vec(py, ids)
    }

    /// The points, (N, 3) mm.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> Array<'py> {
        let pts: Vec<_> = self.inner.points().copied().collect();
        arrays::from_points(py, &pts)
    }

    /// The unit feature vectors, (N, 3).
    #[getter]
    fn features<'py>(&self, py: Python<'py>) -> Array<'py> {
        let fs: Vec<_> = self
            .inner
            .contours()
            .iter()
            .flat_map(|c| c.features().iter().copied())
            .collect();
        arrays::from_vectors(py, &fs)
    }

    /// The contour ids in path order.
    #[getter]
    fn contour_ids(&self) -> Vec<ContourId> {
        self.inner.contours().iter().map(Contour::id).collect()
    }

    /// The total number of points.
    #[getter]
    fn num_points(&self) -> usize {
        self.inner.num_points()
    }

    /// One contour's `(points (n, 3), features (n, 3))`.
    fn contour<'py>(&self, py: Python<'py>, id: ContourId) -> PyResult<(Array<'py>, Array<'py>)> {
        let c = self
            .inner
            .get(id)
            .ok_or_else(|| value_error("id", format!("no contour {id} in this path")))?;
        Ok((
            arrays::from_points(py, c.points()),
            arrays::from_vectors(py, c.features()),
        ))
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Path({} contours, {} points)",
            self.inner.len(),
            self.inner.num_points()
        )
    }
}

/// Reads a point cloud (PLY, PCD, XYZ). Returns `(points (N, 3), normals (N, 3) or None)`.
#[pyfunction]
pub fn read_points<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Array<'py>, Option<Array<'py>>)> {
    let cloud = run_detached(py, move || formats::read_points(&path))?.map_err(geom_error)?;
    Ok(cloud_to_numpy(py, &cloud))
}

/// A cloud as `(points, normals or None)` numpy arrays.
pub fn cloud_to_numpy<'py>(
    py: Python<'py>,
    cloud: &PointCloud,
) -> (Array<'py>, Option<Array<'py>>) {
    (
        arrays::from_points(py, cloud.points()),
        cloud.normals().map(|n| arrays::from_vectors(py, n)),
    )
}

/// Writes a point cloud in the format its extension names (`.ply` binary PLY, `.pcd` binary PCD,
/// `.xyz`/`.txt` text; double precision, with normals when given), so `read_points` reads it back
/// exactly. Refuses `.stl`, `.csv`, unknown extensions and an empty cloud, writing nothing.
#[pyfunction]
#[pyo3(signature = (path, points, *, normals = None))]
pub fn write_points(
    py: Python<'_>,
    path: PathBuf,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let pts = arrays::points("points", points)?;
    let cloud = arrays::cloud(pts, "normals", normals)?;
    run_detached(py, move || formats::write_points(&path, &cloud))?.map_err(geom_error)
}

/// Reads a path CSV (`contour,x,y,z,u,v,w`).
#[pyfunction]
pub fn read_path(py: Python<'_>, path: PathBuf) -> PyResult<PyPath> {
    let inner = run_detached(py, move || formats::read_path(&path))?.map_err(geom_error)?;
    Ok(PyPath { inner })
}

/// Writes a path CSV (`contour,x,y,z,u,v,w`), round-tripping every f64 exactly.
#[pyfunction]
pub fn write_path(py: Python<'_>, path: PathBuf, trim_path: PyPath) -> PyResult<()> {
    run_detached(py, move || formats::write_path(&path, &trim_path.inner))?.map_err(geom_error)
}
