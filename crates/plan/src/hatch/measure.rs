//! What a hatch achieved: neighbour spacing measured along the fitted surface, coverage of the
//! scan points inside the boundary, and how far any track point strays outside the boundary.
//!
//! *Spacing.* For every point of a hatch track of level k, the nearest point of the level k + 1
//! tracks (the foot of the perpendicular on their polylines); pairs whose foot falls on a track
//! end (a track cut short by the boundary) or farther than two pitches are not spacings and are
//! left out. The spacing is the length of the surface curve over the straight plane segment
//! between the two (8 chords on the fitted height field): the distance across the surface.

use rayon::prelude::*;
use trim_geom::crop::point_segment_distance;
use trim_geom::{KdTree, Point3};

use super::polygon::Polygon;
use super::{COVERAGE_FACTOR, Hatch, TrackKind};

/// Chords per spacing measurement along the surface.
const SPACING_CHORDS: usize = 8;
/// A neighbour farther than this many pitches is not a neighbour track.
const NEIGHBOUR_PITCHES: f64 = 2.0;

/// Summary statistics of the neighbour spacing (mm).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SpacingStats {
    /// Number of measured spacings.
    pub count: usize,
    /// Mean spacing, mm.
    pub mean_mm: f64,
    /// Coefficient of variation (standard deviation / mean).
    pub cv: f64,
    /// Smallest spacing, mm.
    pub min_mm: f64,
    /// Largest spacing, mm.
    pub max_mm: f64,
}

impl SpacingStats {
    /// Statistics of `values` (mm); zeros when empty.
    #[must_use]
    pub fn of(values: &[f64]) -> SpacingStats {
        if values.is_empty() {
            return SpacingStats::default();
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        SpacingStats {
            count: values.len(),
            mean_mm: mean,
            cv: if mean > 0.0 { var.sqrt() / mean } else { 0.0 },
            min_mm: values.iter().copied().fold(f64::INFINITY, f64::min),
            max_mm: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        }
    }
}

/// The measured quality of a hatch.
#[derive(Debug, Clone, PartialEq)]
pub struct HatchReport {
    /// Number of tracks (hatch and outline).
    pub tracks: usize,
    /// Number of hatch tracks.
    pub hatch_tracks: usize,
    /// Number of points over all tracks.
    pub points: usize,
    /// Neighbour spacing across the surface (see the module docs).
    pub spacing: SpacingStats,
    /// Fraction of the scan points inside the boundary, taken onto the fitted surface (so scan
    /// noise does not count as a gap), within pitch/2 × 1.05 of a track (outline included).
    pub coverage: f64,
    /// The same, counting hatch tracks only.
    pub coverage_hatch_only: f64,
    /// The largest distance from a scan point inside the boundary to a track, mm.
    pub max_gap_mm: f64,
    /// The farthest any track point lies outside the boundary (in the plane frame), mm.
    pub boundary_error_mm: f64,
    /// Per track, per point: the spacing to the nearest neighbour track (mm), where measured;
    /// for plots of the local spacing error.
    pub local_spacing_mm: Vec<Vec<Option<f64>>>,
}

/// Measures `hatch` (see the module docs).
#[must_use]
pub fn measure(hatch: &Hatch) -> HatchReport {
    let surface = &hatch.surface;
    let frame = surface.frame();
    let pitch = hatch.pitch_mm;
    let polygon = Polygon::new(hatch.boundary_plane.clone());
    let level_of = |k: usize| match hatch.tracks[k].kind {
        TrackKind::Hatch { level } => Some(level),
        TrackKind::Outline => None,
    };
    let max_level = (0..hatch.tracks.len()).filter_map(level_of).max();
    // Per level: the plane polylines of its tracks.
    let n_levels = max_level.map_or(0, |m| m + 1);
    let mut by_level: Vec<Vec<Vec<[f64; 2]>>> = vec![Vec::new(); n_levels];
    for (k, t) in hatch.tracks.iter().enumerate() {
        if let Some(l) = level_of(k) {
            by_level[l].push(t.points.iter().map(|p| frame.to_plane(p)).collect());
        }
    }
    // Per level: a kd-tree over its points (in the plane, z = 0) and their owners.
    let trees: Vec<(KdTree, Vec<(usize, usize)>)> = by_level
        .iter()
        .map(|lines| {
            let mut pts = Vec::new();
            let mut owner = Vec::new();
            for (l, line) in lines.iter().enumerate() {
                for (i, p) in line.iter().enumerate() {
                    pts.push(Point3::new(p[0], p[1], 0.0));
                    owner.push((l, i));
                }
            }
            (KdTree::build(&pts), owner)
        })
        .collect();
    let spacing_to = |p: [f64; 2], level: usize| -> Option<f64> {
        let lines = by_level.get(level)?;
        let (tree, owner) = trees.get(level)?;
        let mut best: Option<(f64, [f64; 2], bool)> = None;
        for n in tree.knn(&Point3::new(p[0], p[1], 0.0), 3) {
            let (l, i) = owner[n.index];
            let line = &lines[l];
            for j in [i.saturating_sub(1), i] {
                if j + 1 >= line.len() {
                    continue;
                }
                let (a, b) = (line[j], line[j + 1]);
                let ab = [b[0] - a[0], b[1] - a[1]];
                let len2 = ab[0] * ab[0] + ab[1] * ab[1];
                let u = if len2 > 0.0 {
                    ((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / len2
                } else {
                    0.0
                };
                let at_end = (j == 0 && u <= 0.0) || (j + 2 == line.len() && u >= 1.0);
                let u = u.clamp(0.0, 1.0);
                let foot = [a[0] + u * ab[0], a[1] + u * ab[1]];
                let d = (p[0] - foot[0]).hypot(p[1] - foot[1]);
                if best.is_none_or(|(bd, _, _)| d < bd) {
                    best = Some((d, foot, at_end));
                }
            }
        }
        let (d, foot, at_end) = best?;
        if at_end || d > NEIGHBOUR_PITCHES * pitch {
            return None;
        }
        surface.surface_length(p, foot, SPACING_CHORDS)
    };
    let per_track: Vec<(Vec<Option<f64>>, Vec<f64>)> = hatch
        .tracks
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            let Some(level) = level_of(k) else {
                return (vec![None; t.points.len()], Vec::new());
            };
            let mut forward = Vec::new();
            let local = t
                .points
                .iter()
                .map(|p| {
                    let st = frame.to_plane(p);
                    let f = spacing_to(st, level + 1);
                    if let Some(f) = f {
                        forward.push(f);
                    }
                    f.or_else(|| level.checked_sub(1).and_then(|l| spacing_to(st, l)))
                })
                .collect();
            (local, forward)
        })
        .collect();
    let mut values = Vec::new();
    let mut local_spacing_mm = Vec::with_capacity(per_track.len());
    for (local, forward) in per_track {
        values.extend(forward);
        local_spacing_mm.push(local);
    }
    // Coverage.
    let radius = 0.5 * pitch * COVERAGE_FACTOR;
    let gap = |hatch_only: bool| -> Vec<f64> {
        // Samples along every segment, at most a quarter pitch apart, each owned by its
        // segment: the nearest samples find the nearest segments also where points are placed
        // far apart (chord tolerance).
        let mut pts = Vec::new();
        let mut owner = Vec::new();
        let sample_mm = 0.25 * pitch;
        for (k, t) in hatch.tracks.iter().enumerate() {
            if hatch_only && level_of(k).is_none() {
                continue;
            }
            if t.points.len() == 1 {
                pts.push(t.points[0]);
                owner.push((k, 0));
            }
            for (j, w) in t.points.windows(2).enumerate() {
                let n = ((w[1] - w[0]).norm() / sample_mm).ceil().max(1.0) as usize;
                for i in 0..=n {
                    pts.push(w[0] + (w[1] - w[0]) * (i as f64 / n as f64));
                    owner.push((k, j));
                }
            }
        }
        let tree = KdTree::build(&pts);
        surface
            .inside_points()
            .par_iter()
            .map(|q| {
                // The surface point under the scan point: scan noise is not a coverage gap.
                let on_surface = surface.lift(frame.to_plane(q)).unwrap_or(*q);
                distance_to_tracks(hatch, &tree, &owner, &on_surface)
            })
            .collect()
    };
    let all = gap(false);
    let hatch_only = gap(true);
    let frac = |g: &[f64]| {
        if g.is_empty() {
            0.0
        } else {
            g.iter().filter(|&&d| d <= radius).count() as f64 / g.len() as f64
        }
    };
    let boundary_error_mm = hatch
        .tracks
        .iter()
        .flat_map(|t| t.points.iter())
        .map(|p| {
            let st = frame.to_plane(p);
            if polygon.contains(st) {
                0.0
            } else {
                polygon.distance(st)
            }
        })
        .fold(0.0, f64::max);
    HatchReport {
        tracks: hatch.tracks.len(),
        hatch_tracks: hatch.hatch_tracks().count(),
        points: hatch.num_points(),
        spacing: SpacingStats::of(&values),
        coverage: frac(&all),
        coverage_hatch_only: frac(&hatch_only),
        max_gap_mm: all.iter().copied().fold(0.0, f64::max),
        boundary_error_mm,
        local_spacing_mm,
    }
}

/// The 3D distance from `q` to the nearest track polyline (checked on the segments around the
/// nearest few track points).
fn distance_to_tracks(hatch: &Hatch, tree: &KdTree, owner: &[(usize, usize)], q: &Point3) -> f64 {
    let mut best = f64::INFINITY;
    for n in tree.knn(q, 4) {
        best = best.min(n.distance_sq.sqrt());
        let (k, j) = owner[n.index];
        let track = &hatch.tracks[k].points;
        if j + 1 < track.len() {
            best = best.min(point_segment_distance(q, &track[j], &track[j + 1]));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_values() {
        let s = SpacingStats::of(&[1.0, 1.0, 1.0, 1.0]);
        assert_eq!(s.count, 4);
        assert!((s.mean_mm - 1.0).abs() < 1e-12 && s.cv.abs() < 1e-12);
        let s = SpacingStats::of(&[0.9, 1.1]);
        assert!((s.cv - 0.1).abs() < 1e-12);
        assert_eq!(SpacingStats::of(&[]).count, 0);
    }
}
