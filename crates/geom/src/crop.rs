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

/// A candidate run's length, as a fraction of the crop's radius (see [`crop_near_polyline`]).
const RUN_FRACTION: f64 = 0.25;

/// The runs on either side of a point's own run whose centres may make it a sure point.
const SURE_RUNS: usize = 4;

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
    let segments: Vec<(Point3, Point3)> = match polyline {
        [] => return Ok(Vec::new()),
        [p] => vec![(*p, *p)],
        _ => polyline.windows(2).map(|w| (w[0], w[1])).collect(),
    };
    // Each point is decided once, by the segments near it (a kd-tree over their midpoints),
    // instead of once per segment whose ball holds it: a 15 mm crop around a path of 0.05 mm
    // steps otherwise tests each point against some 600 segments' balls. The decision is the
    // same test, so the result is the same set.
    let mids: Vec<Point3> = segments
        .iter()
        .map(|(a, b)| nalgebra::center(a, b))
        .collect();
    let half_max = segments
        .iter()
        .map(|(a, b)| 0.5 * (b - a).norm())
        .fold(0.0, f64::max);
    let segment_tree = KdTree::build(&mids);
    // A segment within `radius_mm` of a point has its midpoint within `radius_mm` plus its
    // half-length of it (the margin covers rounding).
    let slack = 1e-9 * (1.0 + radius_mm + half_max);
    let reach = radius_mm + half_max + slack;
    let within = |p: &Point3| {
        let Some(nearest) = segment_tree.nearest(p) else {
            return false;
        };
        let (a, b) = segments[nearest.index];
        if point_segment_distance(p, &a, &b) <= radius_mm {
            return true;
        }
        nearest.distance_sq <= reach * reach
            && segment_tree
                .within_radius_unsorted(p, reach)
                .iter()
                .any(|n| {
                    let (a, b) = segments[n.index];
                    point_segment_distance(p, &a, &b) <= radius_mm
                })
    };
    // Candidates: balls around runs of consecutive segments, each run about a quarter of
    // `radius_mm` long (at least a segment), holding every point within `radius_mm` of the run.
    // Short runs keep the balls close about the capsule (a run as long as the radius gives a
    // ball of twice the radius, most of it outside the capsule, each such point then decided
    // by the segment tree), and their centres make nearly every point inside a sure one.
    let run_mm = (RUN_FRACTION * radius_mm).max(half_max);
    let mut runs: Vec<(Point3, f64)> = Vec::new();
    let mut start = 0;
    while start < segments.len() {
        let centre = mids[start];
        let mut extent = 0.0_f64;
        let mut end = start;
        while end < segments.len() {
            let (a, b) = segments[end];
            let e = (a - centre).norm().max((b - centre).norm());
            if end > start && e > run_mm {
                break;
            }
            extent = extent.max(e);
            end += 1;
        }
        runs.push((centre, extent));
        start = end;
    }
    // A point within `radius_mm` of a run's centre (a segment's midpoint) lies within it of
    // that segment, less the margin for rounding: kept without asking the segment tree.
    let sure = (radius_mm - slack).max(0.0).powi(2);
    let mut seen = vec![false; points.len()];
    let mut keep = vec![false; points.len()];
    for (k, (centre, extent)) in runs.iter().enumerate() {
        // The runs next to this one, whose centres a point in its ball most likely lies near
        // (any centre within the radius decides; the segment tree decides the rest exactly).
        let near_runs = &runs[k.saturating_sub(SURE_RUNS)..(k + SURE_RUNS + 1).min(runs.len())];
        for n in tree.within_radius_unsorted(centre, radius_mm + extent + slack) {
            if !seen[n.index] {
                seen[n.index] = true;
                let p = &points[n.index];
                keep[n.index] = n.distance_sq < sure
                    || near_runs.iter().any(|(c, _)| (p - c).norm_squared() < sure)
                    || within(p);
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

    /// Random clouds and polylines (short and long steps, repeated vertices, one-point lines,
    /// radii from 0 to past the cloud): the same set as testing every segment.
    #[test]
    fn matches_every_segment_test() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(21);
        let p = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus, s: f64| {
            Point3::new(
                rng.random_range(-s..s),
                rng.random_range(-s..s),
                rng.random_range(-0.3 * s..0.3 * s),
            )
        };
        for case in 0..40 {
            let pts: Vec<Point3> = (0..2000).map(|_| p(&mut rng, 10.0)).collect();
            let tree = KdTree::build(&pts);
            let n = [1, 2, 5, 60, 400][case % 5];
            let mut line = vec![p(&mut rng, 8.0)];
            for _ in 1..n {
                let step = if rng.random_bool(0.2) { 3.0 } else { 0.05 };
                let last = line[line.len() - 1];
                let d = if rng.random_bool(0.05) {
                    nalgebra::Vector3::zeros()
                } else {
                    p(&mut rng, step).coords
                };
                line.push(last + d);
            }
            for radius in [0.0, 0.1, 0.75, 1.5, 4.0, 15.0, 40.0] {
                let got = crop_near_polyline(&pts, &tree, &line, radius).unwrap();
                let segs: Vec<(Point3, Point3)> = if n == 1 {
                    vec![(line[0], line[0])]
                } else {
                    line.windows(2).map(|w| (w[0], w[1])).collect()
                };
                let expected: Vec<usize> = (0..pts.len())
                    .filter(|&i| {
                        segs.iter()
                            .any(|(a, b)| point_segment_distance(&pts[i], a, b) <= radius)
                    })
                    .collect();
                assert_eq!(got, expected, "case {case}, radius {radius}");
            }
        }
        let tree = KdTree::build(&[]);
        assert!(
            crop_near_polyline(&[], &tree, &[Point3::origin()], 1.0)
                .unwrap()
                .is_empty()
        );
    }
}
