//! What the laser's landed lines remove from the true part (DESIGN.md "Ablation and the twin's
//! part"): burr webs cut through or left standing, and gouges where a cut reaches into the
//! material.
//!
//! The true part's trimming edges are [`TrueEdge`]s: a polyline on the part (work-piece frame),
//! the direction out of the material at each point (in the face, across the edge) and the burr
//! web standing there (its reach off the edge and its thickness; zero where the edge is clean).
//! A landed mark vector is a segment on the part ([`LandedCut`]); every time the list is marked
//! its segments land again, so a line marked `p` times is `p` cuts. A cut belongs to an edge
//! point when it runs along the edge (within 45°), on the face (within 0.3 mm) and no deeper
//! than 0.5 mm behind the edge: a cut across the edge near a corner trims the neighbouring edge,
//! one further in is another feature's.
//!
//! The model, at each edge point, along the line out of the material:
//! - a cut crossing that line at offset `d` (positive out of the material) removes
//!   [`ProcessSettings::depth_per_pass_um`] over the kerf `[d − w/2, d + w/2]`;
//! - the web is severed at the nearest offset `x ∈ [0, h]` where the cuts' depths add up to its
//!   thickness; what stands beyond falls away and a stub of `x` remains (`h` when it is nowhere
//!   severed: a web cut part way through still stands);
//! - a kerf reaching behind the edge (`d − w/2 < 0`) gouges the part by `w/2 − d`, the
//!   distance it cut the edge back into the material.

use trim_cell::ProcessSettings;
use trim_geom::kdtree::KdTree;
use trim_geom::{Point3, Vector3};

/// How far from an edge point (mm, along the face) a cut is looked for: beyond the longest
/// mark vector's half and the tallest web.
const SEARCH_MARGIN_MM: f64 = 1.0;

/// How far off the face (mm, along its normal) a landed cut still counts as on it.
const ON_FACE_MM: f64 = 0.3;

/// How far behind an edge (mm, into the material) a cut along it still counts as that edge's:
/// a trimming line lands within tenths of a millimetre of its edge or not near it at all; a
/// cut deeper in is another feature's.
const BEHIND_EDGE_MM: f64 = 0.5;

/// A cut counts at an edge point when it runs along the edge within this angle (a cut across
/// the edge near a corner trims the neighbouring edge, not this one), degrees.
const ALONG_EDGE_DEG: f64 = 45.0;

/// One trimming edge of the true part.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueEdge {
    /// The contour id the edge belongs to.
    pub contour: i64,
    /// Points along the edge, work-piece frame (mm).
    pub points: Vec<Point3>,
    /// At each point, the unit direction out of the material, in the face, across the edge.
    pub outward: Vec<Vector3>,
    /// At each point, how far the burr web reaches off the edge (mm; 0: clean).
    pub burr_height_mm: Vec<f64>,
    /// At each point, the web's thickness (mm; 0: clean).
    pub burr_thickness_mm: Vec<f64>,
}

/// A landed mark vector: the segment the beam drew on the part (work-piece frame). Its serde
/// form (`{"from": [x, y, z], "to": [x, y, z]}`, mm) is what `trimctl run --verify` keeps of
/// a run's cuts, so a resumed run can trim a fresh part by them again.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LandedCut {
    /// Where the vector started.
    pub from: Point3,
    /// Where it ended.
    pub to: Point3,
}

/// What the cuts left of one edge point.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct EdgeOutcome {
    /// The web standing after the cuts, mm off the edge (0: none).
    pub residual_mm: f64,
    /// How far a kerf cut the edge back into the material, mm (0: not at all).
    pub gouge_mm: f64,
    /// Cuts that crossed this point's line (each marking of a vector counts).
    pub cuts: u32,
}

/// What the cuts left of the part, per edge and per point (same order as the edges given).
#[derive(Debug, Clone, PartialEq)]
pub struct Ablation {
    /// Per edge: its contour id and each point's outcome.
    pub edges: Vec<(i64, Vec<EdgeOutcome>)>,
}

impl Ablation {
    /// The largest residual web and gouge over one contour, mm (`None`: no such contour).
    #[must_use]
    pub fn contour_max(&self, contour: i64) -> Option<(f64, f64)> {
        let (_, pts) = self.edges.iter().find(|(c, _)| *c == contour)?;
        Some(pts.iter().fold((0.0, 0.0), |(r, g), o| {
            (f64::max(r, o.residual_mm), f64::max(g, o.gouge_mm))
        }))
    }
}

/// Where segment `a → b` crosses the line through `e` along `m` in the face with normal `n`
/// (the plane through `e` spanned by `m` and `n`): the offset along `m`, when it crosses within
/// the segment and on the face.
fn crossing(
    e: &Point3,
    t: &Vector3,
    m: &Vector3,
    n: &Vector3,
    a: &Point3,
    b: &Point3,
) -> Option<f64> {
    let (sa, sb) = ((a - e).dot(t), (b - e).dot(t));
    if (sb - sa).abs() < (b - a).norm() * ALONG_EDGE_DEG.to_radians().cos() {
        return None;
    }
    // Half-open, so a line through a vector's joint crosses once: the start counts, the end
    // does not.
    if !((sa <= 0.0 && sb > 0.0) || (sa >= 0.0 && sb < 0.0)) {
        return None;
    }
    let lambda = sa / (sa - sb);
    let p = a + (b - a) * lambda;
    let q = p - e;
    let d = q.dot(m);
    (q.dot(n).abs() <= ON_FACE_MM && d >= -BEHIND_EDGE_MM).then_some(d)
}

/// The stub left of a web `height` tall and `thickness` thick by kerfs centred at `offsets`
/// (`w` wide, each removing `depth`): the nearest offset in `[0, height]` where the depths add
/// up to the thickness.
fn stub(offsets: &[f64], w: f64, depth: f64, height: f64, thickness: f64) -> f64 {
    if height <= 0.0 {
        return 0.0;
    }
    let removed_at = |x: f64| {
        depth
            * offsets
                .iter()
                .filter(|&&d| x >= d - w / 2.0 && x < d + w / 2.0)
                .count() as f64
    };
    // Depth is piecewise constant, changing only where a kerf begins: the nearest severing
    // point is 0 or one of those beginnings.
    let mut candidates: Vec<f64> = std::iter::once(0.0)
        .chain(
            offsets
                .iter()
                .map(|d| d - w / 2.0)
                .filter(|&x| x > 0.0 && x < height),
        )
        .collect();
    candidates.sort_by(f64::total_cmp);
    candidates
        .into_iter()
        .find(|&x| removed_at(x) >= thickness - 1e-12)
        .unwrap_or(height)
}

/// What `cuts` remove from `edges` with the ablation figures `process` and a kerf `kerf_mm` wide.
#[must_use]
pub fn ablate(
    edges: &[TrueEdge],
    cuts: &[LandedCut],
    process: &ProcessSettings,
    kerf_mm: f64,
) -> Ablation {
    let mids: Vec<Point3> = cuts
        .iter()
        .map(|c| nalgebra::center(&c.from, &c.to))
        .collect();
    let half_longest = cuts
        .iter()
        .map(|c| (c.to - c.from).norm() / 2.0)
        .fold(0.0, f64::max);
    let tallest = edges
        .iter()
        .flat_map(|e| e.burr_height_mm.iter().copied())
        .fold(0.0, f64::max);
    let radius = half_longest + tallest + kerf_mm + SEARCH_MARGIN_MM;
    let tree = KdTree::build(&mids);
    let depth = process.depth_per_pass_mm();
    let outcome_at = |edge: &TrueEdge, i: usize| {
        let pts = &edge.points;
        let e = pts[i];
        let (prev, next) = (pts[i.saturating_sub(1)], pts[(i + 1).min(pts.len() - 1)]);
        let m = edge.outward[i];
        let along = next - prev;
        let t = (along - m * along.dot(&m)).try_normalize(1e-12);
        let Some(t) = t else {
            return EdgeOutcome::default();
        };
        let n = m.cross(&t);
        let offsets: Vec<f64> = if mids.is_empty() {
            Vec::new()
        } else {
            tree.within_radius_unsorted(&e, radius)
                .iter()
                .filter_map(|nb| {
                    let c = &cuts[nb.index];
                    crossing(&e, &t, &m, &n, &c.from, &c.to)
                })
                .collect()
        };
        let gouge = offsets
            .iter()
            .map(|d| kerf_mm / 2.0 - d)
            .fold(0.0, f64::max);
        EdgeOutcome {
            residual_mm: stub(
                &offsets,
                kerf_mm,
                depth,
                edge.burr_height_mm[i],
                edge.burr_thickness_mm[i],
            ),
            gouge_mm: gouge,
            cuts: u32::try_from(offsets.len()).unwrap_or(u32::MAX),
        }
    };
    Ablation {
        edges: edges
            .iter()
            .map(|edge| {
                (
                    edge.contour,
                    (0..edge.points.len())
                        .map(|i| outcome_at(edge, i))
                        .collect(),
                )
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight edge along +x at y = 0, material at y < 0, a web `h` tall and `t` thick
    /// everywhere.
    fn edge(h: f64, t: f64) -> TrueEdge {
        let points: Vec<Point3> = (0..=40)
            .map(|i| Point3::new(0.05 * f64::from(i), 0.0, 0.0))
            .collect();
        let n = points.len();
        TrueEdge {
            contour: 3,
            points,
            outward: vec![Vector3::y(); n],
            burr_height_mm: vec![h; n],
            burr_thickness_mm: vec![t; n],
        }
    }

    /// A line along the edge (and 0.5 mm beyond its ends) at offset `y`, in vectors of 0.5 mm,
    /// marked `passes` times.
    fn line(y: f64, passes: usize) -> Vec<LandedCut> {
        let one: Vec<LandedCut> = (-1..5)
            .map(|k| LandedCut {
                from: Point3::new(0.5 * f64::from(k), y, 0.0),
                to: Point3::new(0.5 * f64::from(k + 1), y, 0.0),
            })
            .collect();
        one.iter()
            .cycle()
            .take(passes * one.len())
            .copied()
            .collect()
    }

    fn worst(a: &Ablation) -> (f64, f64) {
        a.contour_max(3).unwrap()
    }

    fn process(depth_um: f64) -> ProcessSettings {
        ProcessSettings {
            depth_per_pass_um: depth_um,
            kerf_width_um: None,
        }
    }

    #[test]
    fn a_cut_on_the_edge_through_the_whole_web_leaves_no_stub_and_gouges_half_the_kerf() {
        let a = ablate(&[edge(0.3, 0.05)], &line(0.0, 2), &process(40.0), 0.03);
        let (residual, gouge) = worst(&a);
        assert!(residual.abs() < 1e-12, "{residual}");
        assert!((gouge - 0.015).abs() < 1e-9, "{gouge}");
        assert!(a.edges[0].1.iter().all(|o| o.cuts == 2));
    }

    #[test]
    fn a_cut_outside_the_edge_leaves_the_stub_between_them() {
        // Landed 50 µm out: the kerf's near side is 35 µm out, the stub 35 µm tall; no gouge.
        let a = ablate(&[edge(0.3, 0.03)], &line(0.05, 1), &process(40.0), 0.03);
        let (residual, gouge) = worst(&a);
        assert!((residual - 0.035).abs() < 1e-9, "{residual}");
        assert!(gouge.abs() < 1e-12, "{gouge}");
    }

    #[test]
    fn too_few_passes_leave_the_web_standing_and_a_cut_inside_gouges() {
        // 100 µm thick, 40 µm a pass: two passes leave it whole, three sever it.
        assert!(
            (worst(&ablate(
                &[edge(0.3, 0.1)],
                &line(0.0, 2),
                &process(40.0),
                0.03
            ))
            .0 - 0.3)
                .abs()
                < 1e-12
        );
        assert!(
            worst(&ablate(
                &[edge(0.3, 0.1)],
                &line(0.0, 3),
                &process(40.0),
                0.03
            ))
            .0 < 1e-12
        );
        // Landed 20 µm inside the edge: cut back 35 µm.
        let (r, g) = worst(&ablate(
            &[edge(0.0, 0.0)],
            &line(-0.02, 1),
            &process(40.0),
            0.03,
        ));
        assert!(r.abs() < 1e-12 && (g - 0.035).abs() < 1e-9, "{r} {g}");
    }

    #[test]
    fn a_cut_beyond_the_web_or_off_the_face_removes_nothing() {
        let (r, g) = worst(&ablate(
            &[edge(0.2, 0.03)],
            &line(0.5, 1),
            &process(40.0),
            0.03,
        ));
        assert!((r - 0.2).abs() < 1e-12 && g.abs() < 1e-12, "{r} {g}");
        let mut lifted = line(0.0, 1);
        for c in &mut lifted {
            c.from.z += 1.0;
            c.to.z += 1.0;
        }
        let (r, _) = worst(&ablate(&[edge(0.2, 0.03)], &lifted, &process(40.0), 0.03));
        assert!((r - 0.2).abs() < 1e-12, "{r}");
        // No cuts at all: the part as it was.
        assert_eq!(
            worst(&ablate(&[edge(0.2, 0.03)], &[], &process(40.0), 0.03)),
            (0.2, 0.0)
        );
    }
}
