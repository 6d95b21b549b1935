//! Accuracy of a registered path against the true one: the cross-edge error (distance from each
//! registered point to the true contour polyline) and the pointwise error (distance to the true
//! position of the same point).

use trim_geom::Path;
use trim_geom::crop::point_segment_distance;

use crate::error::{RegisterError, Result};

/// Error statistics over all points of a path, mm.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathErrors {
    /// 95th percentile of the cross-edge error.
    pub cross_edge_p95_mm: f64,
    /// Largest cross-edge error.
    pub cross_edge_max_mm: f64,
    /// 95th percentile of the pointwise error.
    pub pointwise_p95_mm: f64,
    /// Largest pointwise error.
    pub pointwise_max_mm: f64,
    /// Points scored.
    pub points: usize,
}

/// The `q`-quantile (0–1) of `values` (nearest rank), or 0 when empty.
#[must_use]
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

/// Scores `registered` against `truth` (same contours, ids and point counts), optionally only
/// the contours `keep` accepts (e.g. the trustworthy ones).
pub fn path_errors(
    registered: &Path,
    truth: &Path,
    keep: impl Fn(i64) -> bool,
) -> Result<PathErrors> {
    let mut cross = Vec::new();
    let mut pointwise = Vec::new();
    for c in registered.contours() {
        if !keep(c.id()) {
            continue;
        }
        let t = truth.get(c.id()).ok_or_else(|| RegisterError::Contour {
            contour: c.id(),
            message: "not in the truth path".into(),
        })?;
        if t.points().len() != c.points().len() {
            return Err(RegisterError::LengthMismatch {
                what: "truth contour points",
                expected: c.points().len(),
                got: t.points().len(),
            });
        }
        for (p, q) in c.points().iter().zip(t.points()) {
            pointwise.push((p - q).norm());
            let d = t
                .points()
                .windows(2)
                .map(|w| point_segment_distance(p, &w[0], &w[1]))
                .fold(f64::INFINITY, f64::min);
            cross.push(d);
        }
    }
    Ok(PathErrors {
        cross_edge_p95_mm: quantile(&cross, 0.95),
        cross_edge_max_mm: cross.iter().copied().fold(0.0, f64::max),
        pointwise_p95_mm: quantile(&pointwise, 0.95),
        pointwise_max_mm: pointwise.iter().copied().fold(0.0, f64::max),
        points: cross.len(),
    })
}
