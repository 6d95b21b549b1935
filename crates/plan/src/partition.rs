//! Each stretch of a contour marked once (issue 24 point 12; DESIGN.md "Validation"): the
//! polylines a Job marks of one contour must partition it along its arc length.
//!
//! Every planned point remembers where on its input contour it lies (its *source*: vertex index
//! plus the fraction of the next segment), and validation's round trip checks that the galvo
//! point lands there to 1 µm. This check takes those positions to arc length along the
//! contour (its own parameter, so a contour that passes near itself is not confused) and
//! refuses, naming the contour and every (zone, layer) involved:
//! - a polyline that runs back along its contour (its stretch marked twice, whatever the
//!   vertices say);
//! - a polyline that skips a vertex of its contour (it cuts the corner: the stretch it should
//!   follow is not marked, a chord is);
//! - two polylines whose stretches overlap by more than [`PARTITION_TOLERANCE_MM`] of arc
//!   length, however short the overlap and wherever it lies (a junction, or one inside the
//!   other): the stretch is marked twice;
//! - a stretch no polyline marks (a gap longer than the tolerance), at the ends included.
//!
//! A junction (one polyline ending where the next starts) is one point, of zero length: it is
//! no overlap. A closed contour is a line from its first point to its last; a piece never wraps
//! its seam.

use trim_geom::{ContourId, Point3};

/// Overlaps and gaps along a contour up to this much arc length (mm) are rounding: the cut
/// points are interpolated, and 1 nm is far below the spot (tens of µm) and the round-trip
/// tolerance (1 µm).
pub const PARTITION_TOLERANCE_MM: f64 = 1e-6;

/// Slack on a vertex index when deciding whether a polyline passes a vertex (in units of the
/// vertex index): the layer cut drops sub-segments shorter than 1e-12 of their segment.
pub const VERTEX_SLACK: f64 = 1e-9;

/// Where a polyline is in the Job: zone id, layer index and its place in the layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct At {
    /// The zone id (execution order).
    pub zone: usize,
    /// The layer index within the zone.
    pub layer: usize,
    /// The polyline's index within the layer.
    pub polyline: usize,
}

impl std::fmt::Display for At {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "zone {} layer {} polyline {}",
            self.zone, self.layer, self.polyline
        )
    }
}

/// One polyline of a contour: where it is and its points' positions on the contour (vertex
/// index + fraction of the next segment).
#[derive(Debug, Clone, PartialEq)]
pub struct Span {
    /// Where the polyline is.
    pub at: At,
    /// Each point's position on the contour.
    pub source: Vec<f64>,
}

/// Arc length along a polyline of points (mm), per vertex: `table[i]` is the length from
/// vertex 0 to vertex i.
#[must_use]
pub fn arclength_table(points: &[Point3]) -> Vec<f64> {
    let mut out = Vec::with_capacity(points.len());
    let mut s = 0.0;
    out.push(0.0);
    for w in points.windows(2) {
        s += (w[1] - w[0]).norm();
        out.push(s);
    }
    out
}

/// The arc length (mm) at `source` (vertex index + fraction) on a contour whose
/// [`arclength_table`] is `table`; `source` is clamped to the contour.
#[must_use]
pub fn arclength_at(table: &[f64], source: f64) -> f64 {
    let last = table.len().saturating_sub(1);
    if last == 0 {
        return 0.0;
    }
    let s = source.clamp(0.0, last as f64);
    let i = (s.floor() as usize).min(last - 1);
    let t = s - i as f64;
    table[i] + (table[i + 1] - table[i]) * t
}

/// One violation of the partition.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// Whether a stretch is marked twice (the laser-safety invariant: double ablation), not
    /// only left unmarked or off the contour.
    pub marked_twice: bool,
    /// What and where: the contour, the stretch (mm of arc length) and the zones and layers.
    pub line: String,
}

/// The findings' lines, for tests and reports.
#[must_use]
pub fn lines(findings: &[Finding]) -> Vec<String> {
    findings.iter().map(|f| f.line.clone()).collect()
}

/// Every violation of "each stretch of contour `id` (vertices `points`) is marked once" by
/// `spans` (its polylines in the Job), naming the contour and the zones and layers. Empty when
/// the spans partition the contour.
#[must_use]
pub fn violations(id: ContourId, points: &[Point3], spans: &[Span]) -> Vec<Finding> {
    let mut out = Vec::new();
    let mut push = |marked_twice: bool, line: String| out.push(Finding { marked_twice, line });
    if points.len() < 2 {
        push(false, format!("contour {id}: fewer than 2 points"));
        return out;
    }
    let table = arclength_table(points);
    let total = table[table.len() - 1];
    let last = (points.len() - 1) as f64;
    // Each polyline's stretch [from, to] in arc length (mm).
    let mut stretches: Vec<(f64, f64, At)> = Vec::with_capacity(spans.len());
    for span in spans {
        let Some((&first, _)) = span.source.split_first() else {
            push(false, format!("contour {id}: {} has no points", span.at));
            continue;
        };
        if let Some(bad) = span
            .source
            .iter()
            .find(|s| !s.is_finite() || **s < -VERTEX_SLACK || **s > last + VERTEX_SLACK)
        {
            push(
                false,
                format!(
                    "contour {id}: {} has a point at {bad} off the contour (vertices 0–{last})",
                    span.at
                ),
            );
            continue;
        }
        let mut max_s = arclength_at(&table, first);
        let (mut lo, mut hi) = (max_s, max_s);
        for w in span.source.windows(2) {
            let (a, b) = (w[0], w[1]);
            let (la, lb) = (arclength_at(&table, a), arclength_at(&table, b));
            if lb < max_s - PARTITION_TOLERANCE_MM {
                push(
                    true,
                    format!(
                        "contour {id}: {} runs back along it from {max_s:.6} mm to {lb:.6} mm (that stretch marked twice)",
                        span.at
                    ),
                );
            }
            max_s = max_s.max(lb);
            lo = lo.min(lb);
            hi = hi.max(lb);
            // A vertex strictly between two consecutive points is skipped: the polyline's
            // segment is a chord, not the contour.
            let (p, q) = (a.min(b), a.max(b));
            let skipped = (p + VERTEX_SLACK).floor() + 1.0;
            if skipped < q - VERTEX_SLACK && (la - lb).abs() > PARTITION_TOLERANCE_MM {
                push(
                    false,
                    format!(
                        "contour {id}: {} skips its vertex {skipped} between {la:.6} mm and {lb:.6} mm (a chord, not the contour)",
                        span.at
                    ),
                );
            }
        }
        stretches.push((lo, hi, span.at));
    }
    if stretches.is_empty() {
        push(
            false,
            format!("contour {id}: not planned (no polyline marks it)"),
        );
        return out;
    }
    stretches.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    // Sweep: `reach` is the farthest end so far, `owner` the polyline that reaches it.
    let (start, _, first_at) = stretches[0];
    if start > PARTITION_TOLERANCE_MM {
        push(
            false,
            format!("contour {id}: 0–{start:.6} mm not marked (before {first_at})"),
        );
    }
    let (mut reach, mut owner) = (stretches[0].1, stretches[0].2);
    for &(from, to, at) in &stretches[1..] {
        if from < reach - PARTITION_TOLERANCE_MM {
            let end = reach.min(to);
            push(
                true,
                format!(
                    "contour {id}: {from:.6}–{end:.6} mm of its {total:.6} mm marked twice ({:.6} mm): {owner} and {at}",
                    end - from
                ),
            );
        } else if from > reach + PARTITION_TOLERANCE_MM {
            push(
                false,
                format!(
                    "contour {id}: {reach:.6}–{from:.6} mm not marked (between {owner} and {at})"
                ),
            );
        }
        if to > reach {
            (reach, owner) = (to, at);
        }
    }
    if reach < total - PARTITION_TOLERANCE_MM {
        push(
            false,
            format!("contour {id}: {reach:.6}–{total:.6} mm not marked (after {owner})"),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight contour of `n` unit segments along x.
    fn line(n: usize) -> Vec<Point3> {
        (0..=n).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect()
    }

    fn span(zone: usize, layer: usize, source: &[f64]) -> Span {
        Span {
            at: At {
                zone,
                layer,
                polyline: 0,
            },
            source: source.to_vec(),
        }
    }

    #[test]
    fn a_partition_passes_in_any_order() {
        let pts = line(4);
        let spans = [
            span(6, 0, &[2.5, 3.0, 4.0]),
            span(0, 0, &[0.0, 1.0, 2.0, 2.5]),
        ];
        assert!(violations(7, &pts, &spans).is_empty());
        // A junction inside a segment, and cut points a rounding error apart.
        let spans = [
            span(0, 0, &[0.0, 1.0, 1.3 + 1e-12]),
            span(1, 2, &[1.3, 2.0, 3.0, 4.0]),
        ];
        assert!(violations(7, &pts, &spans).is_empty());
    }

    #[test]
    fn a_sub_segment_overlap_at_a_junction_is_refused_naming_both() {
        let pts = line(4);
        // Zone 0's piece runs on past 2.5 to 2.6; zone 6's starts at 2.5.
        let spans = [
            span(0, 0, &[0.0, 1.0, 2.0, 2.6]),
            span(6, 0, &[2.5, 3.0, 4.0]),
        ];
        let found = violations(7, &pts, &spans);
        assert!(found.iter().all(|f| f.marked_twice), "{found:?}");
        let v = lines(&found);
        assert_eq!(v.len(), 1, "{v:?}");
        assert!(
            v[0].contains("contour 7")
                && v[0].contains("marked twice")
                && v[0].contains("zone 0 layer 0")
                && v[0].contains("zone 6 layer 0")
                && v[0].contains("2.500000–2.600000 mm"),
            "{v:?}"
        );
    }

    #[test]
    fn overlaps_measure_arc_length_not_vertex_index() {
        // Segment 1–2 is 10 mm long: an overlap of 0.01 of its index is 0.1 mm.
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(11.0, 0.0, 0.0),
        ];
        let v = lines(&violations(
            3,
            &pts,
            &[span(0, 0, &[0.0, 1.0, 1.51]), span(1, 0, &[1.5, 2.0])],
        ));
        assert!(v[0].contains("(0.100000 mm)"), "{v:?}");
        // Over a zero-length segment (a repeated point) an overlap in index is none in length.
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        let spans = [span(0, 0, &[0.0, 1.0, 1.7]), span(1, 0, &[1.2, 2.0, 3.0])];
        assert!(violations(3, &pts, &spans).is_empty());
    }

    #[test]
    fn a_polyline_that_runs_back_or_holds_another_is_refused() {
        let pts = line(4);
        // Back from 3.0 to 2.5 and on: 2.5–3.0 marked twice by one polyline.
        let v = lines(&violations(
            5,
            &pts,
            &[span(2, 1, &[0.0, 1.0, 2.0, 3.0, 2.5, 3.0, 4.0])],
        ));
        assert!(v.iter().any(|l| l.contains("runs back")), "{v:?}");
        // One polyline inside another.
        let v = lines(&violations(
            5,
            &pts,
            &[span(0, 0, &[0.0, 4.0]), span(3, 1, &[1.2, 1.4])],
        ));
        assert!(
            v.iter().any(|l| l.contains("marked twice")
                && l.contains("zone 0")
                && l.contains("zone 3 layer 1")),
            "{v:?}"
        );
    }

    #[test]
    fn gaps_corners_and_strays_are_refused() {
        let pts = line(4);
        let v = lines(&violations(
            1,
            &pts,
            &[span(0, 0, &[0.0, 1.0, 2.0]), span(1, 0, &[2.1, 3.0, 4.0])],
        ));
        assert!(v[0].contains("2.000000–2.100000 mm not marked"), "{v:?}");
        let v = lines(&violations(
            1,
            &pts,
            &[span(0, 0, &[0.5, 1.0, 2.0, 3.0, 4.0])],
        ));
        assert!(v[0].contains("0–0.500000 mm not marked"), "{v:?}");
        let v = lines(&violations(
            1,
            &pts,
            &[span(0, 0, &[0.0, 1.0, 2.0, 3.0, 3.9])],
        ));
        assert!(v[0].contains("not marked (after"), "{v:?}");
        let v = lines(&violations(
            1,
            &pts,
            &[span(0, 0, &[0.0, 1.5, 2.0, 3.0, 4.0])],
        ));
        assert!(v[0].contains("skips its vertex 1"), "{v:?}");
        let v = lines(&violations(1, &pts, &[]));
        assert!(v[0].contains("not planned"), "{v:?}");
        let v = lines(&violations(1, &pts, &[span(0, 0, &[0.0, 4.5])]));
        assert!(v[0].contains("off the contour"), "{v:?}");
    }
}
