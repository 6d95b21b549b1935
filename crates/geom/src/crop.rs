//! Cropping a cloud to the points near a polyline.

use crate::error::{GeomError, Result};
use crate::kdtree::KdTree;
use crate::math::Point3;

/// The distance (mm) from `p` to the segment `a`–`b`.
#[must_use]
pub fn point_segment_distance(p: &Point3, a: &Point3, b: &Point3) -> f64 {
    let ab = b - a;
    let len_sq = ab.norm_squared();
    let t = if len_sq > 0.0 {
        ((p - a).dot(&ab) / len_sq).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).norm()
}

/// The indices (ascending, unique) of the points of `tree` (built over `points`) that lie
/// within `radius_mm` of the polyline. A one-point polyline is a ball.
pub fn crop_near_polyline(
    points: &[Point3],
    tree: &KdTree,
    polyline: &[Point3],
    radius_mm: f64,
) -> Result<Vec<usize>> {
    if !(radius_mm.is_finite() && radius_mm >= 0.0) {
        return Err(GeomError::invalid(
            "radius_mm",
            format!("radius must be finite and >= 0, got {radius_mm}"),
        ));
    }
    if tree.len() != points.len() {
        return Err(GeomError::LengthMismatch {
            what: "kd-tree points",
            expected: points.len(),
            got: tree.len(),
        });
    }
    let mut keep = vec![false; points.len()];
    let segments: Vec<(Point3, Point3)> = match polyline {
        [] => Vec::new(),
        [p] => vec![(*p, *p)],
        _ => polyline.windows(2).map(|w| (w[0], w[1])).collect(),
    };
    for (a, b) in segments {
        // A ball around the midpoint that holds the whole capsule, then the exact test.
        let mid = nalgebra::center(&a, &b);
        let reach = radius_mm + 0.5 * (b - a).norm();
        for n in tree.within_radius_unsorted(&mid, reach) {
            if !keep[n.index] && point_segment_distance(&points[n.index], &a, &b) <= radius_mm {
                keep[n.index] = true;
            }
        }
    }
    Ok(keep
        .iter()
        .enumerate()
        .filter_map(|(i, &k)| k.then_some(i))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_exactly_the_points_within_the_capsule() {
        let mut pts = Vec::new();
        for i in 0..50 {
            for j in 0..50 {
                pts.push(Point3::new(f64::from(i) * 0.2, f64::from(j) * 0.2, 0.0));
            }
        }
        let tree = KdTree::build(&pts);
        let line = [
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(8.0, 1.0, 0.0),
            Point3::new(8.0, 8.0, 0.0),
        ];
        let got = crop_near_polyline(&pts, &tree, &line, 0.5).unwrap();
        let expected: Vec<usize> = (0..pts.len())
            .filter(|&i| {
                line.windows(2)
                    .any(|w| point_segment_distance(&pts[i], &w[0], &w[1]) <= 0.5)
            })
            .collect();
        assert_eq!(got, expected);
        assert!(!got.is_empty());
        assert!(crop_near_polyline(&pts, &tree, &line, -1.0).is_err());
    }
}
