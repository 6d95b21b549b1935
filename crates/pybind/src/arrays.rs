//! numpy in and out: `(N, 3)` float64 arrays checked on the way in, moved (not copied) into
//! numpy on the way out.

use nalgebra::{Point3, Vector3};
use numpy::ndarray::Array2;
use numpy::{PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;

use trim_geom::{GeomError, PointCloud};

use crate::errors::value_error;

/// An `(N, 3)` float64 numpy array bound to the GIL lifetime.
pub type Array<'py> = Bound<'py, PyArray2<f64>>;

/// Reads an `(N, cols)` float64 array into rows, refusing another dtype, shape or any NaN/inf.
pub fn rows<const C: usize>(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<[f64; C]>> {
    let array = obj.cast::<PyArray2<f64>>().map_err(|_| {
        let what = describe(obj);
        value_error(
            name,
            format!("expected a numpy float64 array of shape (N, {C}), got {what}"),
        )
    })?;
    let shape = array.shape();
    if shape[1] != C {
        return Err(value_error(
            name,
            format!("expected shape (N, {C}), got ({}, {})", shape[0], shape[1]),
        ));
    }
    let readonly = array.readonly();
    let view = readonly.as_array();
    let mut out = Vec::with_capacity(shape[0]);
    for (i, row) in view.rows().into_iter().enumerate() {
        let mut r = [0.0; C];
        for (j, v) in row.iter().enumerate() {
            if !v.is_finite() {
                return Err(value_error(
                    name,
                    format!("row {i} column {j} is {v}: values must be finite"),
                ));
            }
            r[j] = *v;
        }
        out.push(r);
    }
    Ok(out)
}

fn describe(obj: &Bound<'_, PyAny>) -> String {
    let dtype = obj
        .getattr("dtype")
        .map(|d| d.to_string())
        .unwrap_or_default();
    let shape = obj
        .getattr("shape")
        .map(|s| s.to_string())
        .unwrap_or_default();
    let type_name = obj
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into());
    if dtype.is_empty() {
        format!("a {type_name} (convert with numpy.asarray(x, dtype=numpy.float64))")
    } else {
        format!("a {type_name} of dtype {dtype} and shape {shape}")
    }
}

/// An `(N, 3)` float64 array of points (mm).
pub fn points(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<Point3<f64>>> {
    Ok(rows::<3>(name, obj)?
        .into_iter()
        .map(Point3::from)
        .collect())
}

/// An `(N, 3)` float64 array of vectors.
pub fn vectors(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<Vector3<f64>>> {
    Ok(rows::<3>(name, obj)?
        .into_iter()
        .map(Vector3::from)
        .collect())
}

/// A cloud of `points` with the normals given as the argument `normals_name`. Its errors name
/// that argument: a row count other than the points' (`target_normals: expected 5 rows, one per
/// point, got 4`) or a zero row (`cad_normals: row 3 is zero: a normal needs a direction`).
pub fn cloud_with_normals(
    points: Vec<Point3<f64>>,
    normals_name: &str,
    normals: &Bound<'_, PyAny>,
) -> PyResult<PointCloud> {
    let normals = vectors(normals_name, normals)?;
    PointCloud::with_normals(points, normals).map_err(|e| match e {
        GeomError::LengthMismatch { expected, got, .. } => value_error(
            normals_name,
            format!("expected {expected} rows, one per point, got {got}"),
        ),
        GeomError::ZeroVector { index, .. } => value_error(
            normals_name,
            format!("row {index} is zero: a normal needs a direction"),
        ),
        other => value_error(normals_name, other),
    })
}

/// A cloud of `points`, with normals when `normals` is given (see [`cloud_with_normals`]).
pub fn cloud(
    points: Vec<Point3<f64>>,
    normals_name: &str,
    normals: Option<&Bound<'_, PyAny>>,
) -> PyResult<PointCloud> {
    match normals {
        Some(n) => cloud_with_normals(points, normals_name, n),
        None => PointCloud::new(points).map_err(crate::errors::geom_error),
    }
}

/// An `(N, 2)` float64 array.
#[expect(dead_code, reason = "used by the planner bindings for galvo polylines")]
pub fn points2(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<[f64; 2]>> {
    rows::<2>(name, obj)
}

/// Rows of `C` floats as an `(N, C)` numpy array; the buffer moves into numpy.
pub fn from_rows<'py, const C: usize>(
    py: Python<'py>,
    rows: impl ExactSizeIterator<Item = [f64; C]>,
) -> Bound<'py, PyArray2<f64>> {
    let n = rows.len();
    let flat: Vec<f64> = rows.flat_map(|r| r.into_iter()).collect();
    // The shape matches the buffer by construction (n rows of C values).
    let array = Array2::from_shape_vec((n, C), flat).unwrap_or_else(|_| Array2::zeros((0, C)));
    PyArray2::from_owned_array(py, array)
}

/// Points as an `(N, 3)` numpy array.
pub fn from_points<'py>(py: Python<'py>, pts: &[Point3<f64>]) -> Bound<'py, PyArray2<f64>> {
    from_rows(py, pts.iter().map(|p| [p.x, p.y, p.z]))
}

/// Vectors as an `(N, 3)` numpy array.
pub fn from_vectors<'py>(py: Python<'py>, vs: &[Vector3<f64>]) -> Bound<'py, PyArray2<f64>> {
    from_rows(py, vs.iter().map(|v| [v.x, v.y, v.z]))
}

/// Extracts a keyword argument that pyo3 would convert itself, with its refusal naming the
/// argument: pyo3 names it only in a `TypeError`, so `k=-1` raised a bare `OverflowError`
/// ("can't convert negative int to unsigned") and `viewpoint=(1, 2)` a bare `ValueError`. A
/// wrong type stays a `TypeError`, a wrong value (negative, too big, the wrong length) is a
/// `ValueError`; both read `name: …`, and `expected` says what is taken.
pub fn named<'py, T: FromPyObject<'py>>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    expected: &str,
) -> PyResult<T> {
    obj.extract::<T>().map_err(|e| {
        let py = obj.py();
        let message = format!(
            "{name}: expected {expected}, got {} ({e})",
            describe_value(obj)
        );
        if e.is_instance_of::<pyo3::exceptions::PyTypeError>(py) {
            pyo3::exceptions::PyTypeError::new_err(message)
        } else {
            pyo3::exceptions::PyValueError::new_err(message)
        }
    })
}

/// Three numbers (`viewpoint`, `reference`), refused naming the argument.
pub fn triple(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<[f64; 3]> {
    named(name, obj, "three numbers (x, y, z)")
}

/// `repr(obj)`, cut to 60 characters.
fn describe_value(obj: &Bound<'_, PyAny>) -> String {
    let text = obj
        .repr()
        .map_or_else(|_| "?".to_string(), |r| r.to_string());
    if text.chars().count() > 60 {
        format!("{}…", text.chars().take(60).collect::<String>())
    } else {
        text
    }
}
