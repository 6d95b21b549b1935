//! Red-light framing, host side and pure: the outline of a layer's galvo commands (convex hull
//! or bounding box, in bits, in the galvo's field frame) and the list that traces it
//! (docs/protocols/galvo.md §5a). The convex hull is spade's (the outer face of its Delaunay
//! triangulation, exact predicates), not a hand-written one.

use spade::{DelaunayTriangulation, Point2, Triangulation};
use trim_cell::job::{GalvoSettings, Layer};

use super::list::{OutOfField, mm_to_bits};
use super::protocol::ListCommand;

/// Tags of frame lists: this bit pattern in the high nibble, zone (12 bits) and layer index
/// (16 bits) below. A frame list is never a marked layer; its tag says so in a status block.
pub const FRAME_TAG_BASE: u32 = 0xF000_0000;

/// Which outline framing traces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OutlineKind {
    /// The convex hull of the layer's command points.
    Hull,
    /// Their axis-aligned bounding box in the galvo frame.
    Box,
}

impl std::fmt::Display for OutlineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            OutlineKind::Hull => "hull",
            OutlineKind::Box => "box",
        })
    }
}

/// Why a layer has no outline to trace.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OutlineError {
    /// A command point is outside the galvo field.
    #[error(transparent)]
    OutOfField(#[from] OutOfField),
    /// The layer has no command point.
    #[error("the layer has no galvo command to frame")]
    Empty,
    /// The triangulation behind the hull refused a point.
    #[error("convex hull: {0}")]
    Hull(String),
}

/// The outline of a layer in bits: a convex polygon, counter-clockwise, not closed (the last
/// vertex joins the first), without repeated or collinear vertices. One vertex: every command
/// point is the same; two: they lie on one segment.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Outline {
    /// Hull or box.
    pub kind: OutlineKind,
    /// The vertices (bits), counter-clockwise.
    pub vertices_bits: Vec<[i32; 2]>,
    /// Distinct command points of the layer it encloses.
    pub points: usize,
}

/// The outline of `layer`'s galvo commands (what the galvo is sent, after the height term and
/// the field correction), in bits.
pub fn layer_outline(
    layer: &Layer,
    settings: &GalvoSettings,
    kind: OutlineKind,
) -> Result<Outline, OutlineError> {
    let mut pts = Vec::new();
    for (pi, pl) in layer.polylines.iter().enumerate() {
        for (i, p) in pl.galvo_commands().iter().enumerate() {
            pts.push(mm_to_bits(*p, settings).ok_or(OutOfField {
                polyline: pi,
                point: i,
                x_mm: p[0],
                y_mm: p[1],
            })?);
        }
    }
    pts.sort_unstable();
    pts.dedup();
    if pts.is_empty() {
        return Err(OutlineError::Empty);
    }
    let vertices_bits = match kind {
        OutlineKind::Hull => hull(&pts)?,
        OutlineKind::Box => bounding_box(&pts),
    };
    Ok(Outline {
        kind,
        vertices_bits,
        points: pts.len(),
    })
}

/// The convex hull of distinct points, sorted: spade's triangulation's outer face, turned
/// counter-clockwise, collinear vertices dropped. Points on one line give its two ends.
fn hull(pts: &[[i32; 2]]) -> Result<Vec<[i32; 2]>, OutlineError> {
    if pts.len() <= 2 {
        return Ok(pts.to_vec());
    }
    let vertices: Vec<Point2<f64>> = pts
        .iter()
        .map(|p| Point2::new(f64::from(p[0]), f64::from(p[1])))
        .collect();
    let t: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::bulk_load(vertices)
        .map_err(|e| OutlineError::Hull(e.to_string()))?;
    if t.all_vertices_on_line() {
        // Sorted lexicographically, collinear points run along their line: the ends.
        return Ok(vec![pts[0], pts[pts.len() - 1]]);
    }
    // spade walks the hull clockwise; bits are integers held exactly in f64.
    let mut ring: Vec<[i32; 2]> = t
        .convex_hull()
        .map(|e| {
            let p = e.from().position();
            [p.x as i32, p.y as i32]
        })
        .collect();
    ring.reverse();
    Ok(drop_collinear(ring))
}

/// Removes vertices on the line through their neighbours (exact, in integers).
fn drop_collinear(mut ring: Vec<[i32; 2]>) -> Vec<[i32; 2]> {
    let mut changed = true;
    while changed && ring.len() > 2 {
        changed = false;
        let n = ring.len();
        if let Some(i) =
            (0..n).find(|&i| cross(ring[(i + n - 1) % n], ring[i], ring[(i + 1) % n]) == 0)
        {
            ring.remove(i);
            changed = true;
        }
    }
    ring
}

/// The bounding box, counter-clockwise from the lower left; degenerate boxes keep their
/// distinct corners (a segment, a point).
fn bounding_box(pts: &[[i32; 2]]) -> Vec<[i32; 2]> {
    let (mut lo, mut hi) = (pts[0], pts[0]);
    for p in pts {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut ring = vec![lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]];
    ring.dedup();
    if ring.len() > 1 && ring[0] == ring[ring.len() - 1] {
        ring.pop();
    }
    ring
}

/// The z of (b − a) × (c − b): > 0 a left turn.
fn cross(a: [i32; 2], b: [i32; 2], c: [i32; 2]) -> i128 {
    let d = |p: [i32; 2], q: [i32; 2]| {
        [
            i128::from(q[0]) - i128::from(p[0]),
            i128::from(q[1]) - i128::from(p[1]),
        ]
    };
    let (u, v) = (d(a, b), d(b, c));
    u[0] * v[1] - u[1] * v[0]
}

impl Outline {
    /// Whether `p` (bits) lies inside or on the outline.
    #[must_use]
    pub fn covers(&self, p: [i32; 2]) -> bool {
        let v = &self.vertices_bits;
        match v.len() {
            0 => false,
            1 => v[0] == p,
            2 => {
                cross(v[0], v[1], p) == 0
                    && (0..2).all(|k| v[0][k].min(v[1][k]) <= p[k] && p[k] <= v[0][k].max(v[1][k]))
            }
            n => (0..n).all(|i| cross(v[i], v[(i + 1) % n], p) >= 0),
        }
    }

    /// The outline's extent (mm): width and height of its bounding box.
    #[must_use]
    pub fn extent_mm(&self, settings: &GalvoSettings) -> [f64; 2] {
        let mut out = [0.0; 2];
        for (k, o) in out.iter_mut().enumerate() {
            let lo = self.vertices_bits.iter().map(|p| p[k]).min().unwrap_or(0);
            let hi = self.vertices_bits.iter().map(|p| p[k]).max().unwrap_or(0);
            *o = f64::from(hi - lo) / settings.bits_per_mm;
        }
        out
    }
}

/// Whether a status's tag is a frame list's ([`frame_tag`]): a frame replaces the status of the
/// list before it, so "an earlier list of this run" must never be read from a frame's tag
/// (a job whose digest bits matched a frame's would have a marked layer read as never run).
#[must_use]
pub fn is_frame_tag(tag: u32) -> bool {
    tag & 0xF000_0000 == FRAME_TAG_BASE
}

/// The tag of the frame list of zone `zone`, layer `layer`.
#[must_use]
pub fn frame_tag(zone: usize, layer: usize) -> u32 {
    let z = u32::try_from(zone & 0x0FFF).unwrap_or(0);
    let l = u32::try_from(layer & 0xFFFF).unwrap_or(0);
    FRAME_TAG_BASE | (z << 16) | l
}

/// The list that traces `outline` once, closed: the job's jump speed for every move (a quick,
/// steady red outline; nothing is marked), no laser delays, the job's scanner delays; a jump to
/// the first vertex, then a `MARK` along each edge back to it. A one-vertex outline is one
/// zero-length vector (a dot).
#[must_use]
pub fn frame_list(outline: &Outline, settings: &GalvoSettings) -> Vec<ListCommand> {
    let bits_per_ms = settings.bits_per_mm / 1000.0;
    let ns = |us: f64| (us * 1000.0).round().clamp(0.0, f64::from(u32::MAX)) as u32;
    let v = &outline.vertices_bits;
    let mut out = vec![
        ListCommand::Speeds {
            jump_bits_per_ms: settings.jump_speed_mm_per_s * bits_per_ms,
            mark_bits_per_ms: settings.jump_speed_mm_per_s * bits_per_ms,
        },
        ListCommand::LaserDelays {
            on_ns: 0,
            off_ns: 0,
        },
        ListCommand::ScannerDelays {
            jump_ns: ns(settings.jump_delay_us),
            mark_ns: ns(settings.mark_delay_us),
            polygon_ns: ns(settings.polygon_delay_us),
        },
    ];
    let Some(&start) = v.first() else {
        return out;
    };
    out.push(ListCommand::Jump {
        x: start[0],
        y: start[1],
    });
    for p in v.iter().skip(1).chain(std::iter::once(&start)) {
        out.push(ListCommand::Mark { x: p[0], y: p[1] });
    }
    out
}

#[cfg(test)]
mod tests {
    use trim_cell::job::{Polyline, Pose};

    use super::*;

    fn layer(polylines: Vec<Vec<[f64; 2]>>) -> Layer {
        Layer {
            index: 0,
            focus_point: [0.0; 3],
            pose: Pose::default(),
            polylines: polylines
                .into_iter()
                .enumerate()
                .map(|(i, p)| Polyline::from_points(i as i64, p))
                .collect(),
        }
    }

    #[test]
    fn frame_tags_are_told_from_list_tags() {
        assert!(is_frame_tag(frame_tag(0, 0)));
        assert!(is_frame_tag(frame_tag(4095, 65535)));
        assert!(!is_frame_tag(0x7FFF_FFFF));
        assert!(!is_frame_tag(0xE123_0001));
    }

    #[test]
    fn the_hull_of_a_square_with_inner_and_edge_points_is_its_corners() {
        let s = GalvoSettings::default(); // 10 000 bits/mm
        let l = layer(vec![
            vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 2.0]],
            vec![[1.0, 1.0], [0.0, 2.0], [0.5, 0.5], [0.0, 1.0]],
        ]);
        let o = layer_outline(&l, &s, OutlineKind::Hull).unwrap();
        assert_eq!(o.points, 8);
        assert_eq!(o.vertices_bits.len(), 4, "{:?}", o.vertices_bits);
        // Counter-clockwise: every turn is a left turn.
        let v = &o.vertices_bits;
        for i in 0..4 {
            assert!(cross(v[i], v[(i + 1) % 4], v[(i + 2) % 4]) > 0);
        }
        for c in [[0, 0], [20_000, 0], [20_000, 20_000], [0, 20_000]] {
            assert!(v.contains(&c), "{c:?} not in {v:?}");
        }
        assert!(o.covers([10_000, 10_000]) && o.covers([20_000, 5_000]));
        assert!(!o.covers([20_001, 5_000]) && !o.covers([-1, 0]));
        assert_eq!(o.extent_mm(&s), [2.0, 2.0]);
        let b = layer_outline(&l, &s, OutlineKind::Box).unwrap();
        assert_eq!(
            b.vertices_bits,
            vec![[0, 0], [20_000, 0], [20_000, 20_000], [0, 20_000]]
        );
    }

    #[test]
    fn random_layers_lie_inside_their_hull_and_the_hull_is_tight() {
        let s = GalvoSettings::default();
        // A seeded xorshift64: uniform in [lo, hi).
        let mut state = 0x5EED_0014_u64;
        let mut uniform = |lo: f64, hi: f64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 11) as f64 / (1_u64 << 53) as f64
        };
        for _ in 0..20 {
            let polylines: Vec<Vec<[f64; 2]>> = (0..5)
                .map(|_| {
                    (0..40)
                        .map(|_| [uniform(-20.0, 20.0), uniform(-7.0, 9.0)])
                        .collect()
                })
                .collect();
            let l = layer(polylines);
            let o = layer_outline(&l, &s, OutlineKind::Hull).unwrap();
            let b = layer_outline(&l, &s, OutlineKind::Box).unwrap();
            for pl in &l.polylines {
                for p in pl.galvo_commands() {
                    let q = mm_to_bits(*p, &s).unwrap();
                    assert!(o.covers(q) && b.covers(q), "{q:?} outside");
                }
            }
            // Tight: every hull vertex is a command point, and no vertex is inside the others.
            let n = o.vertices_bits.len();
            for i in 0..n {
                let v = o.vertices_bits[i];
                assert!(l.polylines.iter().any(|pl| {
                    pl.galvo_commands()
                        .iter()
                        .any(|p| mm_to_bits(*p, &s) == Some(v))
                }));
                let rest = Outline {
                    vertices_bits: (0..n)
                        .filter(|&j| j != i)
                        .map(|j| o.vertices_bits[j])
                        .collect(),
                    ..o.clone()
                };
                assert!(!rest.covers(v));
            }
        }
    }

    #[test]
    fn degenerate_layers_give_a_segment_or_a_dot_and_empty_ones_are_refused() {
        let s = GalvoSettings::default();
        let line = layer(vec![vec![[0.0, 0.0], [1.0, 1.0], [3.0, 3.0], [2.0, 2.0]]]);
        let o = layer_outline(&line, &s, OutlineKind::Hull).unwrap();
        assert_eq!(o.vertices_bits, vec![[0, 0], [30_000, 30_000]]);
        assert!(o.covers([20_000, 20_000]) && !o.covers([20_000, 20_001]));
        let dot = layer(vec![vec![[1.0, -1.0], [1.0, -1.0]]]);
        let o = layer_outline(&dot, &s, OutlineKind::Box).unwrap();
        assert_eq!(o.vertices_bits, vec![[10_000, -10_000]]);
        let cmds = frame_list(&o, &s);
        assert_eq!(
            cmds[3..],
            [
                ListCommand::Jump {
                    x: 10_000,
                    y: -10_000
                },
                ListCommand::Mark {
                    x: 10_000,
                    y: -10_000
                }
            ]
        );
        assert_eq!(
            layer_outline(&layer(vec![]), &s, OutlineKind::Hull),
            Err(OutlineError::Empty)
        );
        let far = layer(vec![vec![[0.0, 0.0], [0.0, 60.0]]]);
        assert!(matches!(
            layer_outline(&far, &s, OutlineKind::Hull),
            Err(OutlineError::OutOfField(OutOfField {
                polyline: 0,
                point: 1,
                ..
            }))
        ));
    }

    #[test]
    fn the_frame_list_closes_the_outline_at_the_jump_speed() {
        let s = GalvoSettings::default();
        let o = Outline {
            kind: OutlineKind::Box,
            vertices_bits: vec![[0, 0], [10, 0], [10, 10], [0, 10]],
            points: 4,
        };
        let cmds = frame_list(&o, &s);
        let speed = s.jump_speed_mm_per_s * s.bits_per_mm / 1000.0;
        assert_eq!(
            cmds[0],
            ListCommand::Speeds {
                jump_bits_per_ms: speed,
                mark_bits_per_ms: speed
            }
        );
        assert_eq!(cmds[3], ListCommand::Jump { x: 0, y: 0 });
        assert_eq!(cmds.last(), Some(&ListCommand::Mark { x: 0, y: 0 }));
        assert_eq!(
            cmds.iter()
                .filter(|c| matches!(c, ListCommand::Mark { .. }))
                .count(),
            4
        );
        assert_eq!(frame_tag(3, 2), 0xF003_0002);
    }
}
