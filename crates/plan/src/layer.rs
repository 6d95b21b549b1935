//! Layers along the zone axis (paper Eq. 14, DESIGN.md "Layers") and the projection to galvo
//! millimetres.
//!
//! With z the height of a point along the zone axis Z above the zone origin O, and z_max, z_min
//! the extremes over the zone: N = floor((z_max − z_min)/ΔH) + 1 layers; layer m (0-based, top
//! first) spans z ∈ [z_max − (m+1)·ΔH, z_max − m·ΔH] and its focus point is
//! P_m = O + (z_max − ΔH/2 − m·ΔH)·Z (paper's P1 and Pm, 1-based there). So every point of a
//! layer lies within ΔH/2 of its focal plane, and ΔH/2 ≤ the focus processing length keeps it
//! in focus.
//!
//! A polyline that crosses a layer boundary is cut exactly at the boundary: the interpolated
//! point (position and feature linear in the segment parameter) ends the polyline in one layer
//! and starts it in the next: no gap, no overlap. Layers that receive no polyline (possible
//! when z_max − z_min is a multiple of ΔH) are dropped.
//!
//! Projection: the galvo point of a registered point P in a layer with focus point F is
//! x = (P − F)·X, y = (P − F)·Y (DESIGN.md "Job"); z = (P − F)·Z, the height over the focal
//! plane, is returned beside it ([`project`]). The Job keeps only (x, y): see
//! [`crate::planner`] for what the round trip guarantees.

use trim_geom::{ContourId, Point3, Vector3};

use crate::error::PlanError;
use crate::piece::Piece;
use trim_cell::job::Frame;
pub use trim_cell::plan_settings::LayerSettings;

/// A subsegment shorter than this (as a fraction of its segment) is dropped when cutting.
pub const MIN_SUBSEGMENT_FRACTION: f64 = 1e-12;

/// The most layers one zone may have: 10,000 layers of the default ΔH (0.59 mm) are a 5.9 m
/// deep zone, of the smallest (1 µm) 10 mm. More is a ΔH far below the part's depth or a path
/// point far off the part, and [`layer_pieces`] refuses it rather than allocate and cut every
/// segment at every boundary.
pub const MAX_LAYERS_PER_ZONE: usize = 10_000;

/// N = floor((z_max − z_min)/ΔH) + 1, paper Eq. 14; saturates at `usize::MAX` (a span that is
/// not finite, or a step that is not a positive number, gives `usize::MAX` too).
#[must_use]
pub fn layer_count(z_min_mm: f64, z_max_mm: f64, step_mm: f64) -> usize {
    let steps = ((z_max_mm - z_min_mm) / step_mm).floor();
    if steps.is_nan() || step_mm.is_nan() || step_mm <= 0.0 {
        return usize::MAX;
    }
    (steps.max(0.0) as usize).saturating_add(1)
}

/// The height of layer m's focal plane above the zone origin: z_max − ΔH/2 − m·ΔH
/// (paper Eq. 14, m 0-based).
#[must_use]
pub fn focus_height_mm(z_max_mm: f64, step_mm: f64, m: usize) -> f64 {
    z_max_mm - step_mm / 2.0 - m as f64 * step_mm
}

/// One polyline of one layer, still in the work-piece frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LayerPiece {
    /// The input contour's id.
    pub contour: ContourId,
    /// Points (mm, work-piece frame), at least two.
    pub points: Vec<Point3>,
    /// Unit feature vector per point.
    pub features: Vec<Vector3>,
    /// Position on the input contour per point (vertex index + fraction).
    pub source: Vec<f64>,
}

/// The layers of one zone (or section).
#[derive(Debug, Clone, PartialEq)]
pub struct ZoneLayers {
    /// ΔH (mm).
    pub step_mm: f64,
    /// The largest height above the origin (mm).
    pub z_max_mm: f64,
    /// The smallest height above the origin (mm).
    pub z_min_mm: f64,
    /// Non-empty layers top down: (Eq. 14 layer number m, its focal height above the origin
    /// in mm, its polylines).
    pub layers: Vec<(usize, f64, Vec<LayerPiece>)>,
}

/// Cuts the pieces into layers of height `step_mm` along `axis` (unit) above `origin`. Refuses
/// a step that is not a finite number > 0 (a beam whose focus length is zero or NaN) and a
/// zone of more than [`MAX_LAYERS_PER_ZONE`] layers, naming `layers.step_mm`, the contours and
/// the count.
pub fn layer_pieces(
    pieces: &[Piece],
    origin: &Point3,
    axis: &Vector3,
    step_mm: f64,
) -> Result<ZoneLayers, PlanError> {
    if !(step_mm.is_finite() && step_mm > 0.0) {
        return Err(PlanError::setting(
            "layers.step_mm",
            step_mm,
            "ΔH must be a finite number > 0 (is the beam's focus processing length zero?)",
        ));
    }
    let height = |p: &Point3| (p - origin).dot(axis);
    let (mut z_min, mut z_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in pieces.iter().flat_map(|p| p.points.iter()) {
        let z = height(p);
        z_min = z_min.min(z);
        z_max = z_max.max(z);
    }
    let n = layer_count(z_min, z_max, step_mm);
    if n > MAX_LAYERS_PER_ZONE {
        let mut contours: Vec<ContourId> = pieces.iter().map(|p| p.contour).collect();
        contours.sort_unstable();
        contours.dedup();
        return Err(PlanError::TooManyLayers {
            contours,
            span_mm: z_max - z_min,
            step_mm,
            layers: n,
            max: MAX_LAYERS_PER_ZONE,
        });
    }
    let layer_of = |z: f64| (((z_max - z) / step_mm).floor().max(0.0) as usize).min(n - 1);
    let mut by_layer: Vec<Vec<LayerPiece>> = vec![Vec::new(); n];

    for piece in pieces {
        let mut current: Option<(usize, LayerPiece)> = None;
        let mut close = |cur: &mut Option<(usize, LayerPiece)>| {
            if let Some((l, lp)) = cur.take()
                && lp.points.len() >= 2
            {
                by_layer[l].push(lp);
            }
        };
        for i in 0..piece.points.len() - 1 {
            let (pa, pb) = (piece.points[i], piece.points[i + 1]);
            let (za, zb) = (height(&pa), height(&pb));
            // Parameters where the segment crosses layer boundaries z_max − j·ΔH.
            let mut cuts: Vec<(f64, f64)> = Vec::new();
            if (zb - za).abs() > 0.0 {
                let (lo, hi) = (za.min(zb), za.max(zb));
                for j in 1..n {
                    let boundary = z_max - j as f64 * step_mm;
                    if boundary > lo && boundary < hi {
                        cuts.push(((boundary - za) / (zb - za), boundary));
                    }
                }
            }
            cuts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let point_at = |t: f64| {
                (
                    pa + (pb - pa) * t,
                    (piece.features[i] * (1.0 - t) + piece.features[i + 1] * t).normalize(),
                    piece.source[i] + (piece.source[i + 1] - piece.source[i]) * t,
                )
            };
            let mut ts: Vec<(f64, f64)> = vec![(0.0, za)];
            ts.extend(cuts);
            ts.push((1.0, zb));
            for w in ts.windows(2) {
                let ((t0, z0), (t1, z1)) = (w[0], w[1]);
                if t1 - t0 < MIN_SUBSEGMENT_FRACTION {
                    continue;
                }
                let layer = layer_of(0.5 * (z0 + z1));
                let end = if t1 >= 1.0 {
                    (pb, piece.features[i + 1], piece.source[i + 1])
                } else {
                    point_at(t1)
                };
                match &mut current {
                    Some((l, lp)) if *l == layer => {
                        lp.points.push(end.0);
                        lp.features.push(end.1);
                        lp.source.push(end.2);
                    }
                    _ => {
                        close(&mut current);
                        let start = if t0 <= 0.0 {
                            (pa, piece.features[i], piece.source[i])
                        } else {
                            point_at(t0)
                        };
                        current = Some((
                            layer,
                            LayerPiece {
                                contour: piece.contour,
                                points: vec![start.0, end.0],
                                features: vec![start.1, end.1],
                                source: vec![start.2, end.2],
                            },
                        ));
                    }
                }
            }
        }
        close(&mut current);
    }
    let layers = by_layer
        .into_iter()
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(m, l)| (m, focus_height_mm(z_max, step_mm, m), l))
        .collect();
    Ok(ZoneLayers {
        step_mm,
        z_max_mm: z_max,
        z_min_mm: z_min,
        layers,
    })
}

/// Projects a work-piece point to galvo millimetres and its height over the focal plane:
/// (x, y, z) = ((P − F)·X, (P − F)·Y, (P − F)·Z).
#[must_use]
pub fn project(frame: &Frame, focus_point: &Point3, point: &Point3) -> ([f64; 2], f64) {
    let d = point - focus_point;
    (
        [d.dot(&frame.x_axis()), d.dot(&frame.y_axis())],
        d.dot(&frame.z_axis()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> Piece {
        // Rises 1.0 mm along x over 10 mm, then comes back down: crosses boundaries twice.
        let points = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 1.0),
            Point3::new(20.0, 0.0, 0.05),
        ];
        Piece {
            contour: 9,
            features: vec![Vector3::z(); 3],
            source: vec![0.0, 1.0, 2.0],
            points,
        }
    }

    #[test]
    fn eq14_counts_and_heights() {
        assert_eq!(layer_count(0.0, 1.0, 0.3), 4);
        assert_eq!(layer_count(0.0, 0.0, 0.3), 1);
        assert!((focus_height_mm(1.0, 0.3, 0) - 0.85).abs() < 1e-15);
        assert!((focus_height_mm(1.0, 0.3, 3) - (-0.05)).abs() < 1e-12);
    }

    #[test]
    fn cuts_exactly_at_boundaries_without_gap_or_overlap() {
        let step = 0.3;
        let zl = layer_pieces(&[ramp()], &Point3::origin(), &Vector3::z(), step).unwrap();
        assert_eq!(zl.layers.len(), 4);
        let mut intervals: Vec<(f64, f64)> = Vec::new();
        for (_, focus_z, polylines) in &zl.layers {
            for lp in polylines {
                for (p, s) in lp.points.iter().zip(&lp.source) {
                    assert!(
                        (p.z - focus_z).abs() <= step / 2.0 + 1e-12,
                        "{} vs {focus_z}",
                        p.z
                    );
                    // The point lies on the input polyline at its source parameter.
                    let i = (s.floor() as usize).min(1);
                    let t = s - i as f64;
                    let q = ramp().points[i] + (ramp().points[i + 1] - ramp().points[i]) * t;
                    assert!((q - p).norm() < 1e-12);
                }
                intervals.push((lp.source[0], *lp.source.last().unwrap()));
            }
        }
        intervals.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert!(intervals[0].0.abs() < 1e-15);
        for w in intervals.windows(2) {
            assert!((w[0].1 - w[1].0).abs() < 1e-12, "gap or overlap: {w:?}");
        }
        assert!((intervals.last().unwrap().1 - 2.0).abs() < 1e-15);
        // 1.0 mm up over ΔH = 0.3: cuts at z = 0.7, 0.4, 0.1 going up, 0.7, 0.4, 0.1 coming
        // down (0.05 is below 0.1) → 7 polylines.
        assert_eq!(intervals.len(), 7);
    }

    #[test]
    fn a_zero_or_nan_step_and_too_many_layers_are_refused_not_a_panic() {
        for step in [0.0, f64::NAN, -0.3, f64::INFINITY] {
            let e = layer_pieces(&[ramp()], &Point3::origin(), &Vector3::z(), step)
                .unwrap_err()
                .to_string();
            assert!(e.contains("layers.step_mm"), "{step}: {e}");
        }
        // The ramp is 1 mm deep: 1 µm gives about 1,000 layers, within the cap; a point 1e6 mm up
        // gives 10⁹ at 1 µm, refused with the contour and the count.
        let fine = layer_pieces(&[ramp()], &Point3::origin(), &Vector3::z(), 1e-3).unwrap();
        assert!(
            (1000..=1001).contains(&fine.layers.len()),
            "{}",
            fine.layers.len()
        );
        let mut far = ramp();
        far.points[1].z = 1e6;
        let e = layer_pieces(&[far], &Point3::origin(), &Vector3::z(), 1e-3)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("layers.step_mm") && e.contains("[9]") && e.contains("1000000001 layers"),
            "{e}"
        );
        assert_eq!(layer_count(0.0, 1.0, 0.0), usize::MAX);
        assert_eq!(layer_count(0.0, f64::INFINITY, 0.3), usize::MAX);
        assert_eq!(layer_count(0.0, 1e300, 1e-300), usize::MAX);
    }

    #[test]
    fn step_refuses_half_step_beyond_focus() {
        let s = LayerSettings {
            step_mm: Some(1.0),
            ..LayerSettings::default()
        };
        let e = s.step_for(0.4).unwrap_err();
        assert!(e.to_string().contains("layers.step_mm"), "{e}");
        assert!((LayerSettings::default().step_for(0.4).unwrap() - 0.6).abs() < 1e-15);
    }
}
