//! Results built in Rust for Python: serde values as Python objects (dicts, lists, floats,
//! ints, strings, `None`; what `pythonize` does, through `serde_json::Value`), and the typed
//! per-contour registration quality. Nothing crosses as JSON text to be parsed again.

use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde::Serialize;
use serde_json::Value;

use crate::errors::value_error;

/// `value` as Python objects: its serde form with JSON's types (a map a dict, a sequence a
/// list, a number an int or float, a unit `None`).
pub fn to_py<'py, T: Serialize>(
    py: Python<'py>,
    what: &str,
    value: &T,
) -> PyResult<Bound<'py, PyAny>> {
    let v = serde_json::to_value(value).map_err(|e| value_error(what, e))?;
    value_to_py(py, &v)
}

fn value_to_py<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => match (n.as_i64(), n.as_u64()) {
            (Some(i), _) => i.into_pyobject(py)?.into_any(),
            (None, Some(u)) => u.into_pyobject(py)?.into_any(),
            _ => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Array(items) => {
            let list = PyList::empty(py);
            for item in items {
                list.append(value_to_py(py, item)?)?;
            }
            list.into_any()
        }
        Value::Object(map) => {
            let dict = PyDict::new(py);
            for (k, item) in map {
                dict.set_item(k, value_to_py(py, item)?)?;
            }
            dict.into_any()
        }
    })
}

/// One registered contour's quality (`registration.json`'s `contours` entry), typed.
///
/// `predicted_max_error_um` is the registration's own bound on the contour's largest
/// cross-edge error, from the field's posterior deviation across the contour (`field_sigma_mm`
/// along `field_weak_direction`), its residual, its coverage and its distance to supporting scan
/// data; over `quality.tolerance_um` (default 30) it flags the contour `predicted_error`.
/// `residual_rms_mm` is `None` when no scan point is near. `degeneracy_ratio` and
/// `weakest_direction`: how well the patch's normals fix it, and along which direction least;
/// `support_ratio` the same ratio along that direction over the support radius.
/// `end_support_mm`: for a strip, how far its ends lie from scan surface facing along it.
/// `model_disagreement_mm`: how far apart the field and a second fit at 0.75× its control
/// spacing put the contour (large where the smoothness prior, not the data, places it), both
/// conditioned on the strips' scanned edges; `model_disagreement_faces_mm` the same between the
/// two fits to the faces alone (how much the readings brought them together).
/// `opening_slide_mm`, `opening_gain`, `opening_cover_gain`: for a closed contour, the opening
/// check (how far off the scan shows its opening, and the agreement that gains; a misplaced
/// opening flags `opening_misplaced` and refuses the part). `scan_edge_gap_um`: for an open
/// contour or a hole's rim, how far it lies beyond the material the scan shows beside it
/// (negative: no gap; `None` where the scan does not locate its edge); over the tolerance it flags
/// `edge_off_scan`. `scan_slide_gap_um`: the part of that gap a misregistration can make (a
/// strip's gap; for a rim the scan reads larger all round, its slide's alone: the field cannot
/// resize a hole); over the tolerance it puts the part in doubt (every contour whose `doubt_bound_um`,
/// its bound at 1.5σ, exceeds `quality.doubt_bound_fraction` of the tolerance is then flagged
/// `part_in_doubt`, and so is every strip sharing an end with a strip then untrusted).
/// `scan_edges`: the scanned-edge readings behind that gap, one dict per stretch (`at_mm`,
/// `offset_um`, `sigma_um`, `points`, `from`, `flash_share`, `size_um`: a rim's change of
/// size, 0 for a strip), as in registration.json; the
/// edge terms condition the field on a strip's (not a rim's). A strip
/// whose readings show more than 20 µm of material beyond it, or a strip sharing an end with
/// one, is flagged `material_beyond` (the edge may lie inside the material, or a burr stands
/// there; the part is not refused for it). A strip one of whose readings still puts it more
/// than 12 µm beyond the material at 2σ (0.4 of the tolerance: the cross-edge P95 promised),
/// or a strip sharing an end with one, is flagged `edge_gap` (the part is not put in doubt).
#[pyclass(module = "trimctl", frozen, get_all)]
pub struct ContourQuality {
    /// The contour id.
    pub id: i64,
    /// Contour points.
    pub points: usize,
    /// Matched scan points.
    pub scan_points: usize,
    /// Fraction of contour points with a matched scan point.
    pub coverage: f64,
    /// RMS point-to-plane residual, mm; `None` without scan points.
    pub residual_rms_mm: Option<f64>,
    /// `λmin/λmax` of the patch's translational normal matrix.
    pub degeneracy_ratio: f64,
    /// The patch's least-constrained direction, scan frame (3,).
    pub weakest_direction: Py<PyArray1<f64>>,
    /// The same ratio along that direction over the support radius.
    pub support_ratio: f64,
    /// Largest field displacement along the contour, mm.
    pub max_field_displacement_mm: f64,
    /// The field's posterior standard deviation across the contour, mm.
    pub field_sigma_mm: f64,
    /// The direction of that deviation, scan frame (3,).
    pub field_weak_direction: Py<PyArray1<f64>>,
    /// Distance to the nearest scan surface facing along the weak direction, mm.
    pub support_distance_mm: f64,
    /// For a strip, how far its ends lie from scan surface facing along it, mm.
    pub end_support_mm: f64,
    /// How far apart the field and the check fit put the contour, mm (0 without
    /// `quality.model_check`).
    pub model_disagreement_mm: f64,
    /// The same between the two fits to the faces alone, before the edge terms, mm.
    pub model_disagreement_faces_mm: f64,
    /// The posterior deviation across the contour alone, mm.
    pub cross_sigma_mm: f64,
    /// For an open contour, the posterior deviation at its ends in any direction, mm (0 for a
    /// closed one).
    pub end_sigma_mm: f64,
    /// The chance that the contour lies farther across itself than the cross-edge P95 limit
    /// (`report["global"]["p95_limit_um"]`, 12 µm of a 30 µm tolerance), from the posterior
    /// across it; `None` without a posterior (global mode).
    pub p95_risk: Option<f64>,
    /// For a closed contour, how far off the scan shows its opening, mm; `None` for an open
    /// contour or too small an opening (the opening check, flag `opening_misplaced`).
    pub opening_slide_mm: Option<f64>,
    /// The agreement that slide gains, over the opening's cells.
    pub opening_gain: Option<f64>,
    /// The part of that gain over the opening itself.
    pub opening_cover_gain: Option<f64>,
    /// How far the contour lies beyond the material the scan shows beside it, µm (2σ; negative:
    /// no gap; a hole's rim from the edge fitted over it); `None` for a closed contour longer
    /// than a hole's, a rim under a film, or an edge the scan does not locate (flag
    /// `edge_off_scan`).
    pub scan_edge_gap_um: Option<f64>,
    /// The part of `scan_edge_gap_um` a misregistration can make, µm: a strip's gap; for a
    /// rim the scan reads larger all round, its slide's alone; over the tolerance the part is
    /// in doubt.
    pub scan_slide_gap_um: Option<f64>,
    /// The scanned-edge readings along the contour, one dict per stretch: `at_mm` (arc
    /// length of its middle), `offset_um` (negative: the contour lies beyond the material),
    /// `sigma_um`, `points`, `from` (`wall` or `face`), `flash_share`, `size_um` (a rim's
    /// change of size, the same on every arc; 0 for a strip); for a hole's rim, one per
    /// arc of the edge fitted over the whole rim. Empty where the scan does not locate the
    /// edge.
    pub scan_edges: Py<pyo3::types::PyTuple>,
    /// The predicted bound on the largest cross-edge error, µm.
    pub predicted_max_error_um: f64,
    /// The same under a tenth of the whole prior, µm: what the part's doubt counts a contour
    /// as flagged by (more than `max_untrusted_fraction` of the contours over the tolerance by
    /// this or flagged puts the part in doubt).
    pub part_bound_um: f64,
    /// The contour's own bound at 1.5σ, µm: what the part's rules count it by.
    pub doubt_bound_um: f64,
    /// What was found wrong (the report's flag names).
    pub flags: Py<pyo3::types::PyTuple>,
    /// Whether the planner may use the contour.
    pub trustworthy: bool,
}

#[pymethods]
impl ContourQuality {
    fn __repr__(&self) -> String {
        format!(
            "ContourQuality(id={}, predicted_max_error_um={:.1}, trustworthy={})",
            self.id, self.predicted_max_error_um, self.trustworthy
        )
    }
}

impl ContourQuality {
    /// The Python object of one contour's quality.
    pub fn of(py: Python<'_>, c: &trim_register::regional::ContourQuality) -> PyResult<Self> {
        let flags: Vec<String> = c
            .flags
            .iter()
            .map(|f| match serde_json::to_value(f) {
                Ok(Value::String(s)) => s,
                _ => format!("{f:?}"),
            })
            .collect();
        Ok(ContourQuality {
            id: c.id,
            points: c.points,
            scan_points: c.scan_points,
            coverage: c.coverage,
            residual_rms_mm: c.residual_rms_mm,
            degeneracy_ratio: c.degeneracy_ratio,
            weakest_direction: PyArray1::from_slice(py, &c.weakest_direction).unbind(),
            support_ratio: c.support_ratio,
            max_field_displacement_mm: c.max_field_displacement_mm,
            field_sigma_mm: c.field_sigma_mm,
            field_weak_direction: PyArray1::from_slice(py, &c.field_weak_direction).unbind(),
            support_distance_mm: c.support_distance_mm,
            end_support_mm: c.end_support_mm,
            model_disagreement_mm: c.model_disagreement_mm,
            model_disagreement_faces_mm: c.model_disagreement_faces_mm,
            cross_sigma_mm: c.cross_sigma_mm,
            end_sigma_mm: c.end_sigma_mm,
            p95_risk: c.p95_risk,
            opening_slide_mm: c.opening_slide_mm,
            opening_gain: c.opening_gain,
            opening_cover_gain: c.opening_cover_gain,
            scan_edge_gap_um: c.scan_edge_gap_um,
            scan_slide_gap_um: c.scan_slide_gap_um,
            scan_edges: pyo3::types::PyTuple::new(
                py,
                c.scan_edges
                    .iter()
                    .map(|r| to_py(py, "a scanned-edge reading", r))
                    .collect::<PyResult<Vec<_>>>()?,
            )?
            .unbind(),
            predicted_max_error_um: c.predicted_max_error_um,
            part_bound_um: c.part_bound_um,
            doubt_bound_um: c.doubt_bound_um,
            flags: pyo3::types::PyTuple::new(py, flags)?.unbind(),
            trustworthy: c.trustworthy,
        })
    }
}
