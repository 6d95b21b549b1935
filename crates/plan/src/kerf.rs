//! Kerf compensation (issue 23; DESIGN.md "Planning"): each trimming line offset out of the
//! material by half the kerf (plus a clearance), so the kerf's inner side lies on the edge
//! instead of half a kerf inside it (`trim_sim::ablation`: a kerf centred `d` out of the
//! material gouges `w/2 − d`).
//!
//! # Which side is material
//!
//! The path says it through its geometry, not through a column: a contour runs along an edge
//! of a face whose normal is its feature vector `f`, so the material lies on one side of it in
//! that face, to the left (`f × t`, `t` the direction of travel) or to the right. The face's
//! material is bounded by the contours' closed loops: a closed contour (ends within
//! [`JOIN_TOLERANCE_MM`]) is a loop, and open contours whose ends meet end to end, exactly two
//! at each joint, close a loop between them (the synthetic core's outline is six strips).
//! A point of the face is material when it lies inside an odd number of loops (the outline
//! holds the material, a hole inside it does not, an island inside the hole does), the loops
//! projected along `f` onto the face's plane; loops of other faces (feature vectors more than
//! [`SAME_FACE_DEG`] apart) are left out. At up to [`SIDE_SAMPLES`] segments of a contour the
//! points [`PROBE_MM`] to either side are counted; the side is the one inside an odd number,
//! where every sample that tells (the two counts of different parity) agrees.
//!
//! That rule needs the face's outline in the path: a loop that lies inside no other loop and
//! holds none is a hole whose outline is missing or an outline without holes, and the path
//! cannot tell which. Such a loop, an open contour whose ends close no loop, a contour at a
//! joint of more than two ends and one whose samples disagree are *undetermined*: left on the
//! edge, each named with why ([`Side`], [`KerfRecord::uncompensated`]). Hatch tracks (negative
//! ids, [`crate::hatch::track_ids`]) are no edges: never offset, never loops.
//!
//! # The offset
//!
//! Each segment of a compensated contour moves `offset` out of the material along its normal
//! in the face (`±f × segment`); each vertex moves along the bisector of its two segments'
//! normals by `offset / cos(half the turn)` (a mitred offset, at most [`MAX_MITER`] times the
//! offset), so every offset segment stands `offset` from its registered one. At a joint with
//! another compensated contour of its loop the miter takes that contour's segment, so the
//! offset loop stays closed. The planner plans the offset path like the registered one: zones,
//! layers and the galvo projection see the line the beam is to draw, and validation checks the
//! round trip against it and the offset against the registered path.

use std::collections::BTreeMap;

use trim_cell::job::{KerfRecord, UncompensatedContour};
use trim_geom::{Contour, ContourId, Path, Point3, Vector3};

use crate::error::PlanError;
use crate::piece::{angle_rad, check_contour};

/// Contour ends closer than this meet (mm): a contour whose ends meet is closed; open contours
/// whose ends meet join into one loop.
pub const JOIN_TOLERANCE_MM: f64 = 0.01;

/// Loops whose mean feature vectors are further apart than this belong to other faces and do
/// not bound this contour's material (degrees).
pub const SAME_FACE_DEG: f64 = 45.0;

/// The most segments of a contour whose sides are probed.
pub const SIDE_SAMPLES: usize = 8;

/// How far to either side of a segment's midpoint the material is probed (mm): well under the
/// narrowest web between two edges, well over rounding.
pub const PROBE_MM: f64 = 0.02;

/// The largest miter factor: a vertex moves at most this many offsets (a turn sharper than
/// 120° is no edge to trim along).
pub const MAX_MITER: f64 = 2.0;

/// Where a contour's material lies, seen along its feature vector toward the part.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Side {
    /// On the left of the direction of travel (`f × t`).
    Left,
    /// On the right (`−f × t`).
    Right,
    /// Not determined: why.
    Undetermined(String),
}

impl Side {
    /// The sign of the direction out of the material relative to `f × t`: −1 for material on
    /// the left, +1 on the right; `None` when undetermined.
    #[must_use]
    pub fn outward_sign(&self) -> Option<f64> {
        match self {
            Side::Left => Some(-1.0),
            Side::Right => Some(1.0),
            Side::Undetermined(_) => None,
        }
    }
}

/// Each contour's material side (hatch tracks, negative ids, have none and are not listed).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct MaterialSides {
    /// By contour id.
    pub sides: BTreeMap<ContourId, Side>,
}

impl MaterialSides {
    /// The side of contour `id`; a contour not in the path the sides came from is undetermined.
    #[must_use]
    pub fn of(&self, id: ContourId) -> Side {
        self.sides.get(&id).cloned().unwrap_or_else(|| {
            Side::Undetermined("not in the path its material side was determined from".to_owned())
        })
    }
}

/// Which end of a contour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum End {
    Start,
    Finish,
}

/// A closed loop of the face: its points (closing point not repeated), mean feature and
/// bounding sphere (a line that misses the sphere misses the loop's projection along it).
struct Loop {
    points: Vec<Point3>,
    feature: Vector3,
    centre: Point3,
    radius_mm: f64,
}

impl Loop {
    fn new(points: Vec<Point3>, feature: Vector3) -> Loop {
        let sum: Vector3 = points.iter().map(|p| p.coords).sum();
        let centre = Point3::from(sum / points.len() as f64);
        let radius_mm = points
            .iter()
            .map(|p| (p - centre).norm())
            .fold(0.0, f64::max);
        Loop {
            points,
            feature,
            centre,
            radius_mm,
        }
    }

    /// Whether the line through `q` along the unit `f` passes within the bounding sphere.
    fn near_line(&self, q: &Point3, f: &Vector3) -> bool {
        let r = self.centre - q;
        (r - f * r.dot(f)).norm() <= self.radius_mm
    }
}

/// A contour whose ends meet (within [`JOIN_TOLERANCE_MM`]).
fn is_closed(c: &Contour) -> bool {
    let p = c.points();
    p.len() >= 4 && (p[0] - p[p.len() - 1]).norm() <= JOIN_TOLERANCE_MM
}

fn end_point(c: &Contour, end: End) -> Point3 {
    match end {
        End::Start => c.points()[0],
        End::Finish => c.points()[c.points().len() - 1],
    }
}

/// The joints of the open contours: each end's partner when exactly one other end meets it;
/// and the ends that meet more than one.
type Joints = (
    BTreeMap<(ContourId, End), (ContourId, End)>,
    Vec<(ContourId, End)>,
);

fn joints(open: &[&Contour]) -> Joints {
    let ends: Vec<(ContourId, End, Point3)> = open
        .iter()
        .flat_map(|c| {
            [End::Start, End::Finish]
                .into_iter()
                .map(|e| (c.id(), e, end_point(c, e)))
        })
        .collect();
    let (mut links, mut crowded) = (BTreeMap::new(), Vec::new());
    for (i, (id, end, p)) in ends.iter().enumerate() {
        let partners: Vec<usize> = (0..ends.len())
            .filter(|&j| j != i && (ends[j].2 - p).norm() <= JOIN_TOLERANCE_MM)
            .collect();
        match partners.as_slice() {
            [] => {}
            [j] => {
                links.insert((*id, *end), (ends[*j].0, ends[*j].1));
            }
            _ => crowded.push((*id, *end)),
        }
    }
    // A link holds only when it is mutual (a crowded end's partner keeps no link to it).
    let mutual: BTreeMap<_, _> = links
        .iter()
        .filter(|(a, b)| links.get(b) == Some(a))
        .map(|(a, b)| (*a, *b))
        .collect();
    (mutual, crowded)
}

/// The open contours joined into closed loops: per loop, its members in order, each with
/// whether it runs against the loop. Contours of chains that do not close are not in any.
fn chains(
    open: &[&Contour],
    links: &BTreeMap<(ContourId, End), (ContourId, End)>,
) -> Vec<Vec<(ContourId, bool)>> {
    let mut used = std::collections::BTreeSet::new();
    let mut out = Vec::new();
    for c in open {
        if used.contains(&c.id()) {
            continue;
        }
        let mut members = vec![(c.id(), false)];
        let (mut at, mut closed) = ((c.id(), End::Finish), false);
        while let Some(&(next, entered)) = links.get(&at) {
            if next == c.id() {
                closed = entered == End::Start;
                break;
            }
            if members.iter().any(|(m, _)| *m == next) {
                break;
            }
            let reversed = entered == End::Finish;
            members.push((next, reversed));
            at = (next, if reversed { End::Start } else { End::Finish });
        }
        if closed {
            used.extend(members.iter().map(|(m, _)| *m));
            out.push(members);
        }
    }
    out
}

/// Even-odd test of `q` against a polygon, both projected onto the plane spanned by `e1`, `e2`.
fn inside(q: &Point3, polygon: &[Point3], e1: &Vector3, e2: &Vector3) -> bool {
    let (qx, qy) = (q.coords.dot(e1), q.coords.dot(e2));
    let mut odd = false;
    let n = polygon.len();
    for k in 0..n {
        let (a, b) = (&polygon[k], &polygon[(k + 1) % n]);
        let (ax, ay, bx, by) = (
            a.coords.dot(e1),
            a.coords.dot(e2),
            b.coords.dot(e1),
            b.coords.dot(e2),
        );
        if (ay > qy) != (by > qy) && qx < ax + (qy - ay) / (by - ay) * (bx - ax) {
            odd = !odd;
        }
    }
    odd
}

/// How many `loops` of the face with normal `f` hold `q` (projected along `f`).
fn holding(q: &Point3, f: &Vector3, t: &Vector3, loops: &[Loop]) -> usize {
    let e1 = t.normalize();
    let e2 = f.cross(&e1);
    let same_face = SAME_FACE_DEG.to_radians();
    loops
        .iter()
        .filter(|l| {
            angle_rad(&l.feature, f) <= same_face
                && l.near_line(q, f)
                && inside(q, &l.points, &e1, &e2)
        })
        .count()
}

/// In-face unit normal of segment `k` of `c` toward its left (`f × t`), `None` for a segment
/// along the feature vector or of no length.
fn left_normal(c: &Contour, k: usize) -> Option<Vector3> {
    let (p, f) = (c.points(), c.features());
    let t = p[k + 1] - p[k];
    (f[k] + f[k + 1]).cross(&t).try_normalize(1e-12)
}

/// The material side of one contour by probing up to [`SIDE_SAMPLES`] of its segments.
fn probe_side(c: &Contour, loops: &[Loop]) -> Side {
    let segments = c.points().len() - 1;
    let samples = segments.min(SIDE_SAMPLES);
    let (mut left, mut right, mut silent) = (0, 0, 0);
    for s in 0..samples {
        let k = (2 * s + 1) * segments / (2 * samples);
        let Some(m) = left_normal(c, k) else {
            silent += 1;
            continue;
        };
        let (p, f) = (c.points(), c.features());
        let mid = nalgebra::center(&p[k], &p[k + 1]);
        let f = (f[k] + f[k + 1]).normalize();
        let t = p[k + 1] - p[k];
        let on_left = holding(&(mid + m * PROBE_MM), &f, &t, loops) % 2 == 1;
        let on_right = holding(&(mid - m * PROBE_MM), &f, &t, loops) % 2 == 1;
        match (on_left, on_right) {
            (true, false) => left += 1,
            (false, true) => right += 1,
            _ => silent += 1,
        }
    }
    match (left, right) {
        (l, 0) if l > 0 && l >= silent => Side::Left,
        (0, r) if r > 0 && r >= silent => Side::Right,
        _ => Side::Undetermined(format!(
            "its sides disagree: of {samples} probed segments {left} have the material on the \
             left, {right} on the right, {silent} tell neither"
        )),
    }
}

/// Each contour's material side, from the path's own geometry (see the module docs).
#[must_use]
pub fn material_sides(path: &Path) -> MaterialSides {
    let edges: Vec<&Contour> = path.contours().iter().filter(|c| c.id() >= 0).collect();
    let open: Vec<&Contour> = edges.iter().copied().filter(|c| !is_closed(c)).collect();
    let (links, crowded) = joints(&open);
    let mut loops: Vec<Loop> = Vec::new();
    // Per contour: the loop it belongs to.
    let mut loop_of: BTreeMap<ContourId, usize> = BTreeMap::new();
    for c in edges.iter().filter(|c| is_closed(c)) {
        loop_of.insert(c.id(), loops.len());
        let p = c.points();
        loops.push(Loop::new(
            p[..p.len() - 1].to_vec(),
            c.feature().into_inner(),
        ));
    }
    for members in chains(&open, &links) {
        let (mut points, mut feature) = (Vec::new(), Vector3::zeros());
        for (id, reversed) in &members {
            let Some(c) = path.get(*id) else { continue };
            let mut p = c.points().to_vec();
            if *reversed {
                p.reverse();
            }
            points.extend_from_slice(&p[..p.len() - 1]);
            feature += c.feature().into_inner() * c.length();
            loop_of.insert(*id, loops.len());
        }
        loops.push(Loop::new(points, feature.normalize()));
    }
    // A loop inside another of its face, or holding one, is bounded by the outline in the
    // path.
    let same_face = SAME_FACE_DEG.to_radians();
    let anchored: Vec<bool> = (0..loops.len())
        .map(|i| {
            let f = loops[i].feature;
            let t = loops[i].points[1] - loops[i].points[0];
            let encloses = |outer: usize, inner: usize| {
                outer != inner
                    && angle_rad(&loops[inner].feature, &f) <= same_face
                    && holding(&loops[inner].points[0], &f, &t, &loops[outer..=outer]) == 1
            };
            (0..loops.len()).any(|j| encloses(j, i) || encloses(i, j))
        })
        .collect();
    let mut sides = BTreeMap::new();
    for c in &edges {
        let id = c.id();
        let side = match loop_of.get(&id) {
            Some(&l) if anchored[l] => probe_side(c, &loops),
            Some(_) => Side::Undetermined(
                "a closed loop that lies inside no other contour's loop and holds none: a hole \
                 whose outline is not in the path, or an outline without holes"
                    .to_owned(),
            ),
            None if crowded.iter().any(|(cid, _)| *cid == id) => Side::Undetermined(
                "an open contour whose end meets more than one other contour's end".to_owned(),
            ),
            None => Side::Undetermined(format!(
                "an open contour whose ends close no loop with other contours' ends (within \
                 {JOIN_TOLERANCE_MM} mm)"
            )),
        };
        sides.insert(id, side);
    }
    MaterialSides { sides }
}

/// Outward in-face unit normals of every segment of `c` on its side `sign` (see
/// [`Side::outward_sign`]).
fn outward_normals(c: &Contour, sign: f64) -> Vec<Option<Vector3>> {
    (0..c.points().len() - 1)
        .map(|k| left_normal(c, k).map(|m| m * sign))
        .collect()
}

/// A vertex's offset: along the bisector of its segments' normals `a` and `b`, in the face with
/// normal `f`, mitred so each segment stands `offset_mm` off.
fn mitred(a: Option<Vector3>, b: Option<Vector3>, f: &Vector3, offset_mm: f64) -> Vector3 {
    let (a, b) = match (a, b) {
        (Some(a), Some(b)) => (a, b),
        (Some(n), None) | (None, Some(n)) => (n, n),
        (None, None) => return Vector3::zeros(),
    };
    let sum = a + b;
    let bisector = (sum - f * sum.dot(f)).try_normalize(1e-9).unwrap_or(a);
    let cos_half = bisector.dot(&a).max(1.0 / MAX_MITER);
    bisector * (offset_mm / cos_half)
}

/// The path with every contour whose side is known moved `offset_mm` out of the material
/// (hatch tracks and undetermined contours as they were), and the record of what moved.
pub fn compensate(
    path: &Path,
    sides: &MaterialSides,
    offset_mm: f64,
) -> Result<(Path, KerfRecord), PlanError> {
    let mut record = KerfRecord {
        offset_mm,
        compensated: Vec::new(),
        uncompensated: Vec::new(),
    };
    for c in path.contours() {
        check_contour(c)?;
    }
    let normals: BTreeMap<ContourId, Vec<Option<Vector3>>> = path
        .contours()
        .iter()
        .filter(|c| c.id() >= 0)
        .filter_map(|c| {
            let sign = sides.of(c.id()).outward_sign()?;
            Some((c.id(), outward_normals(c, sign)))
        })
        .collect();
    // The open contours' joints, for the miter at a contour's ends.
    let open: Vec<&Contour> = path
        .contours()
        .iter()
        .filter(|c| c.id() >= 0 && !is_closed(c))
        .collect();
    let (links, _) = joints(&open);
    let neighbour = |id: ContourId, end: End| -> Option<Vector3> {
        let (other, at) = links.get(&(id, end))?;
        let n = normals.get(other)?;
        match at {
            End::Start => *n.first()?,
            End::Finish => *n.last()?,
        }
    };
    let mut contours = Vec::with_capacity(path.len());
    for c in path.contours() {
        let id = c.id();
        let Some(n) = normals.get(&id) else {
            if let Side::Undetermined(reason) = sides.of(id)
                && id >= 0
            {
                record.uncompensated.push(UncompensatedContour {
                    contour: id,
                    reason,
                });
            }
            contours.push(c.clone());
            continue;
        };
        let (p, f) = (c.points(), c.features());
        let last = p.len() - 1;
        let closed = is_closed(c);
        let moved: Vec<Point3> = (0..=last)
            .map(|i| {
                let before = if i > 0 {
                    n[i - 1]
                } else if closed {
                    n[last - 1]
                } else {
                    neighbour(id, End::Start)
                };
                let after = if i < last {
                    n[i]
                } else if closed {
                    n[0]
                } else {
                    neighbour(id, End::Finish)
                };
                p[i] + mitred(before, after, &f[i], offset_mm)
            })
            .collect();
        contours.push(c.with_points(moved)?);
        record.compensated.push(id);
    }
    Ok((Path::new(contours)?, record))
}

/// The line a plan under `offset_mm` means to draw along `path`: `path` compensated by its own
/// material sides (the digital twin measures the spot error against it). With `None`, `path`.
pub fn intended_line(path: &Path, offset_mm: Option<f64>) -> Result<Path, PlanError> {
    match offset_mm {
        Some(d) => Ok(compensate(path, &material_sides(path), d)?.0),
        None => Ok(path.clone()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_shapes::square;

    /// The distance of `q` from the square's rim (positive outside the square).
    fn outside_square(q: &Point3, s: f64) -> f64 {
        let h = s / 2.0;
        let (dx, dy) = (q.x.abs() - h, q.y.abs() - h);
        if dx > 0.0 || dy > 0.0 {
            dx.max(0.0).hypot(dy.max(0.0))
        } else {
            dx.max(dy)
        }
    }

    #[test]
    fn a_square_holes_rim_moves_into_the_hole_and_the_outline_out_of_the_part() {
        // A 20 mm outline holding a 4 mm square hole; either winding of either loop.
        for (outline_cw, hole_cw) in [(false, false), (true, false), (false, true), (true, true)] {
            let path = Path::new(vec![
                square(1, 20.0, 10, outline_cw),
                square(2, 4.0, 8, hole_cw),
            ])
            .unwrap();
            let sides = material_sides(&path);
            let d = 0.0205;
            let (moved, record) = compensate(&path, &sides, d).unwrap();
            assert_eq!(record.compensated, vec![1, 2], "{sides:?}");
            assert!(record.uncompensated.is_empty());
            // The outline's material is inside it: its line moves out of the square by d.
            for q in moved.get(1).unwrap().points() {
                let out = outside_square(q, 20.0);
                assert!(
                    out >= d - 1e-12 && out <= MAX_MITER * d,
                    "outline {q}: {out}"
                );
            }
            // The hole's material is outside it: its line moves into the hole by d (corners
            // mitred: d·√2 along the diagonal).
            for q in moved.get(2).unwrap().points() {
                let out = outside_square(q, 4.0);
                assert!(
                    (out + d).abs() < 1e-12 || (out + d * 2f64.sqrt()).abs() < 1e-12,
                    "hole {q}: {out}"
                );
            }
            // Every offset segment of the hole stands d from the rim: the midpoint of each.
            for w in moved.get(2).unwrap().points().windows(2) {
                let mid = nalgebra::center(&w[0], &w[1]);
                assert!((outside_square(&mid, 4.0) + d).abs() < 1e-12, "{mid}");
            }
        }
    }

    #[test]
    fn an_outline_of_open_strips_is_one_loop_and_the_joints_are_mitred() {
        // The 20 mm outline as four open strips (one reversed), holding a round hole.
        let h = 10.0;
        let strip = |id, a: [f64; 2], b: [f64; 2]| {
            let points = (0..=20)
                .map(|k| {
                    let t = f64::from(k) / 20.0;
                    Point3::new(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), 0.0)
                })
                .collect();
            Contour::new(id, points, Vector3::z()).unwrap()
        };
        let hole = Contour::new(
            5,
            (0..=36)
                .map(|k| {
                    let a = std::f64::consts::TAU * f64::from(k % 36) / 36.0;
                    Point3::new(2.0 + a.cos(), a.sin(), 0.0)
                })
                .collect(),
            Vector3::z(),
        )
        .unwrap();
        let path = Path::new(vec![
            strip(1, [-h, -h], [h, -h]),
            strip(2, [h, -h], [h, h]),
            strip(3, [-h, h], [h, h]),
            strip(4, [-h, h], [-h, -h]),
            hole,
        ])
        .unwrap();
        let sides = material_sides(&path);
        // Seen from +z: strips 1, 2, 4 run counter-clockwise (material left), 3 clockwise.
        assert_eq!(sides.of(1), Side::Left);
        assert_eq!(sides.of(2), Side::Left);
        assert_eq!(sides.of(3), Side::Right);
        assert_eq!(sides.of(4), Side::Left);
        // The hole runs counter-clockwise: its material, outside it, on the right.
        assert_eq!(sides.of(5), Side::Right);
        let d = 0.02;
        let (moved, _) = compensate(&path, &sides, d).unwrap();
        for id in 1..=4 {
            for q in moved.get(id).unwrap().points() {
                let out = outside_square(q, 20.0);
                assert!(out >= d - 1e-12, "strip {id} {q}: {out}");
            }
        }
        // The corner between strips 1 and 2 is mitred: both ends at (h + d, −h − d).
        let corner = Point3::new(h + d, -h - d, 0.0);
        assert!((moved.get(1).unwrap().points()[20] - corner).norm() < 1e-12);
        assert!((moved.get(2).unwrap().points()[0] - corner).norm() < 1e-12);
        // The hole's line moves toward its centre by d (mitred on its chords).
        for q in moved.get(5).unwrap().points() {
            let r = (q - Point3::new(2.0, 0.0, 0.0)).norm();
            assert!(r < 1.0 - d + 1e-12 && r > 1.0 - MAX_MITER * d, "{r}");
        }
    }

    #[test]
    fn contours_whose_side_the_path_cannot_tell_are_named_and_left_on_the_edge() {
        // A lone hole (no outline around it) and an open strip.
        let strip = Contour::new(
            8,
            vec![Point3::new(20.0, 0.0, 0.0), Point3::new(30.0, 0.0, 0.0)],
            Vector3::z(),
        )
        .unwrap();
        let path = Path::new(vec![square(7, 4.0, 4, false), strip]).unwrap();
        let sides = material_sides(&path);
        let (moved, record) = compensate(&path, &sides, 0.02).unwrap();
        assert!(record.compensated.is_empty());
        let named: Vec<ContourId> = record.uncompensated.iter().map(|u| u.contour).collect();
        assert_eq!(named, vec![7, 8]);
        assert!(record.uncompensated[0].reason.contains("closed loop"));
        assert!(record.uncompensated[1].reason.contains("open contour"));
        assert_eq!(moved, path, "nothing moved");
    }

    #[test]
    fn a_loop_on_another_face_does_not_bound_this_ones_material() {
        // The outline's face is z = 0 (feature +z); a square of the same size on a wall
        // (feature +x) around the hole's projection must not flip the hole's side.
        let wall = Contour::new(
            9,
            square(9, 6.0, 4, false)
                .points()
                .iter()
                .map(|p| Point3::new(15.0, p.x, p.y))
                .collect(),
            Vector3::x(),
        )
        .unwrap();
        let path = Path::new(vec![
            square(1, 20.0, 10, false),
            square(2, 4.0, 8, false),
            wall,
        ])
        .unwrap();
        let sides = material_sides(&path);
        assert_eq!(sides.of(1), Side::Left);
        assert_eq!(sides.of(2), Side::Right);
    }

    #[test]
    fn hatch_tracks_are_never_offset_nor_listed() {
        let track = Contour::new(
            -1,
            vec![Point3::new(-1.0, 5.0, 0.0), Point3::new(1.0, 5.0, 0.0)],
            Vector3::z(),
        )
        .unwrap();
        let path = Path::new(vec![
            square(1, 20.0, 10, false),
            square(2, 4.0, 8, false),
            track.clone(),
        ])
        .unwrap();
        let (moved, record) = compensate(&path, &material_sides(&path), 0.02).unwrap();
        assert_eq!(moved.get(-1), Some(&track));
        assert_eq!(record.compensated, vec![1, 2]);
        assert!(record.uncompensated.is_empty());
    }
}
