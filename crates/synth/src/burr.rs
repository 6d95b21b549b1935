//! Flash (burrs) on the untrimmed core: thin webs standing off the edges the contours follow.
//!
//! The model: a pressed core's flash forms where the die halves meet; the contours of this part
//! all follow the top face's edges, so the top face is taken as the parting plane. A burr is a
//! web in that plane, flush with the top face (its upper side continues the face), reaching
//! out of the material away from the edge (into a hole or slot, or beyond the outer boundary)
//! by its *height* and hanging its *thickness* below the face, over a *stretch* of the edge.
//! The web is deformed and placed with the part. The scanner samples its upper side, its
//! underside and its free edge by their true area (a web off a hole's rim narrows toward its
//! free edge; not its two end faces, each a height × thickness sliver) under the part's
//! visibility rule; it hides nothing (occlusion is the part's mesh alone).

use rand::Rng;
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{Point3, Vector3};

use crate::part::{AreaTable, DomainSample, Edge, THICKNESS_MM, contour_segments};

/// One burr's ground truth: where it stands and how big it is, domain (design) measures in
/// mm, before the deformation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Burr {
    /// The id of the contour whose edge it stands off (template path and truth).
    pub contour: i64,
    /// Start of the stretch along the contour, mm of arc length from its first point (in the
    /// design's `(u, v)` plane, as the contour's points are spaced).
    pub start_mm: f64,
    /// End of the stretch along the contour, mm (`start_mm < end_mm ≤` the contour's length).
    pub end_mm: f64,
    /// The first contour point within the stretch (index into the contour's points).
    pub first_point: usize,
    /// The last contour point within the stretch (inclusive).
    pub last_point: usize,
    /// How far the web reaches out of the material from the edge, in the top face's plane, mm.
    pub height_mm: f64,
    /// The web's thickness below the top face, mm.
    pub thickness_mm: f64,
}

/// The burr ranges to draw from (mm) and which share of the contours carry them.
pub(crate) struct BurrRanges {
    pub(crate) fraction: f64,
    pub(crate) height_mm: [f64; 2],
    pub(crate) thickness_mm: [f64; 2],
    pub(crate) length_mm: [f64; 2],
}

/// Draws the burrs: `round(fraction × contours)` contours (a seeded subset), each with one or
/// two stretches (in its first and second half when two), length, height and thickness uniform
/// in their ranges (a stretch is at most its half or the whole edge). Sorted by contour id.
pub(crate) fn draw_burrs(
    ranges: &BurrRanges,
    edges: &[Edge],
    spacing_mm: f64,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<Burr> {
    let n_burred = ((ranges.fraction * edges.len() as f64).round() as usize).min(edges.len());
    let mut order: Vec<usize> = (0..edges.len()).collect();
    for i in 0..n_burred {
        let j = rng.random_range(i..order.len());
        order.swap(i, j);
    }
    let mut chosen = order[..n_burred].to_vec();
    chosen.sort_unstable();
    let uniform = |rng: &mut Xoshiro256PlusPlus, [lo, hi]: [f64; 2]| rng.random_range(lo..=hi);
    let mut burrs = Vec::new();
    for k in chosen {
        let edge = &edges[k];
        let len = edge.length();
        let n = contour_segments(edge, spacing_mm);
        let stretches = if rng.random_bool(0.5) { 1 } else { 2 };
        let sector = len / f64::from(stretches);
        for j in 0..stretches {
            let length = uniform(rng, ranges.length_mm).min(sector);
            let start_mm = f64::from(j) * sector + rng.random_range(0.0..=sector - length);
            let end_mm = (start_mm + length).min(len);
            let height_mm = uniform(rng, ranges.height_mm);
            let thickness_mm = uniform(rng, ranges.thickness_mm);
            // Contour point k sits at arc length len·k/n.
            let first_point = ((start_mm / len * n as f64).ceil() as usize).min(n);
            let last_point = ((end_mm / len * n as f64).floor() as usize).clamp(first_point, n);
            burrs.push(Burr {
                contour: i64::try_from(k + 1).unwrap_or(i64::MAX),
                start_mm,
                end_mm,
                first_point,
                last_point,
                height_mm,
                thickness_mm,
            });
        }
    }
    burrs
}

/// Samples the burrs' surfaces by area. A proposal is drawn uniformly over each web's strip
/// (arc length × reach for its two sides, arc length × depth for its free edge; the webs
/// picked by their strips' areas), and a proposal off an arc of curvature `κ` stands for only
/// `1 − κt` of the strip's area at reach `t` (the free edge's `1 − κh`): a web reaching into a
/// hole narrows toward its free edge. Such a proposal is *kept* with that probability, decided
/// by the draw that chose its side (uniform within the side, independent of the point), so a
/// proposal takes the same draws whether kept or not and a seed's scan is the strip's scan less
/// the proposals an area-true web does not have. What is kept is uniform over the web's true
/// area, at the density of the rest of the part (the strips' areas are what the scanner's
/// draws are shared by; what the thinning removes is their excess over the true area).
pub(crate) struct BurrSampler {
    webs: Vec<(Edge, Burr)>,
    areas: AreaTable,
}

/// A proposal on a web, and whether the web's true area holds it.
pub(crate) struct WebProposal {
    pub(crate) sample: DomainSample,
    pub(crate) kept: bool,
}

impl BurrSampler {
    /// The webs of `burrs` on `edges` (contour id = index + 1).
    pub(crate) fn new(edges: &[Edge], burrs: &[Burr]) -> Self {
        let mut webs = Vec::with_capacity(burrs.len());
        let mut areas = AreaTable::default();
        for b in burrs {
            let Some(edge) = usize::try_from(b.contour - 1)
                .ok()
                .and_then(|i| edges.get(i))
            else {
                continue;
            };
            areas.push(strip_area(b));
            webs.push((*edge, *b));
        }
        BurrSampler { webs, areas }
    }

    /// The proposals' area (each web's strip: upper side, underside, free edge), mm².
    pub(crate) fn area(&self) -> f64 {
        self.areas.total()
    }

    /// One proposal (domain point and normal) and whether it is kept. Only called when
    /// [`Self::area`] is positive.
    pub(crate) fn sample(&self, rng: &mut impl Rng) -> WebProposal {
        let (edge, b) = &self.webs[self.areas.pick(rng)];
        let length = b.end_mm - b.start_mm;
        let top = THICKNESS_MM / 2.0;
        let s = b.start_mm + length * rng.random_range(0.0..1.0);
        let (e, m) = edge.at(s);
        let face = length * b.height_mm;
        let piece = rng.random_range(0.0..strip_area(b));
        // The share of the strip's area the proposal stands for, and a uniform draw within its
        // side (the position of `piece` there) that keeps it.
        let narrowing = |reach: f64| {
            if edge.on_arc(s) {
                1.0 - edge.arc_curvature() * reach
            } else {
                1.0
            }
        };
        if piece < 2.0 * face {
            let t = b.height_mm * rng.random_range(0.0..1.0);
            let (w, normal, within) = if piece < face {
                (top, 1.0, piece / face)
            } else {
                (top - b.thickness_mm, -1.0, (piece - face) / face)
            };
            WebProposal {
                sample: DomainSample {
                    point: Point3::new(e[0] + t * m[0], e[1] + t * m[1], w),
                    normal: Vector3::new(0.0, 0.0, normal),
                },
                kept: within < narrowing(t),
            }
        } else {
            let w = top - b.thickness_mm * rng.random_range(0.0..1.0);
            let edge_area = length * b.thickness_mm;
            WebProposal {
                sample: DomainSample {
                    point: Point3::new(e[0] + b.height_mm * m[0], e[1] + b.height_mm * m[1], w),
                    normal: Vector3::new(m[0], m[1], 0.0),
                },
                kept: (piece - 2.0 * face) / edge_area < narrowing(b.height_mm),
            }
        }
    }
}

/// The strip a web's proposals are drawn over (upper side + underside + free edge), mm².
fn strip_area(b: &Burr) -> f64 {
    (b.end_mm - b.start_mm) * (2.0 * b.height_mm + b.thickness_mm)
}

/// A web's true areas, mm²: each of its two sides (`face`) and its free edge. Over the
/// stretch's straight part a strip; over its arcs (curvature κ) a strip narrowing as `1 − κt`:
/// `h − κh²/2` per mm of foot for a side, `thickness · (1 − κh)` for the free edge.
#[cfg(test)]
fn true_area(edge: &Edge, b: &Burr) -> (f64, f64) {
    let length = b.end_mm - b.start_mm;
    let arc = edge.arc_length_within(b.start_mm, b.end_mm);
    let kappa = edge.arc_curvature();
    let h = b.height_mm;
    (
        h * length - kappa * h * h / 2.0 * arc,
        b.thickness_mm * (length - kappa * h * arc),
    )
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;
    use crate::part::Cutout;

    fn web(edge: &Edge, height_mm: f64) -> Burr {
        Burr {
            contour: 1,
            start_mm: 0.0,
            end_mm: edge.length(),
            first_point: 0,
            last_point: 0,
            height_mm,
            thickness_mm: 0.05,
        }
    }

    fn hole(radius_mm: f64, half_length_mm: f64) -> Edge {
        Edge::Rim(Cutout {
            u_mm: 0.0,
            v_mm: 0.0,
            radius_mm,
            half_length_mm,
        })
    }

    /// A web all round a round hole is an annulus: what the sampler keeps is uniform over it
    /// (its sides' area `π(r² − (r − h)²)`, not the strip's `2πr·h`), so its points thin toward
    /// the free edge as `1 − t/r`, at the density of a strip off a straight edge.
    #[test]
    fn a_web_into_a_hole_is_sampled_by_its_true_area() {
        let (r, h) = (1.2, 0.6);
        let rim = hole(r, 0.0);
        let b = web(&rim, h);
        let pi = std::f64::consts::PI;
        let annulus = pi * (r * r - (r - h) * (r - h));
        let (face, free) = true_area(&rim, &b);
        assert!((face - annulus).abs() < 1e-9, "{face} vs {annulus}");
        assert!((free - 2.0 * pi * (r - h) * b.thickness_mm).abs() < 1e-9);

        let sampler = BurrSampler::new(&[rim], &[b]);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let draws = 60_000;
        let (mut upper, mut outer_half, mut free_kept, mut kept) = (0usize, 0usize, 0usize, 0);
        for _ in 0..draws {
            let p = sampler.sample(&mut rng);
            let reach = r - p.sample.point.x.hypot(p.sample.point.y);
            assert!((-1e-12..=h + 1e-12).contains(&reach), "{reach}");
            if !p.kept {
                continue;
            }
            kept += 1;
            if p.sample.normal.z > 0.5 {
                upper += 1;
                if reach > h / 2.0 {
                    outer_half += 1;
                }
            } else if p.sample.normal.z.abs() < 0.5 {
                free_kept += 1;
            }
        }
        // The kept share is the true area over the strip's (2σ of a binomial share over 60k
        // draws is under 0.005).
        let share = kept as f64 / draws as f64;
        let expected = (2.0 * face + free) / sampler.area();
        assert!((share - expected).abs() < 0.008, "{share} vs {expected}");
        // Beyond half the reach lie radii r−h … r−h/2 of the annulus.
        let inner = r - h / 2.0;
        let expected = (inner * inner - (r - h) * (r - h)) / (r * r - (r - h) * (r - h));
        let outer = outer_half as f64 / upper as f64;
        assert!((outer - expected).abs() < 0.012, "{outer} vs {expected}");
        // A strip would put half there.
        assert!(expected < 0.42);
        // The sides and the free edge in proportion to their true areas.
        let edge_share = free_kept as f64 / kept as f64;
        let expected = free / (2.0 * face + free);
        assert!(
            (edge_share - expected).abs() < 0.006,
            "{edge_share} vs {expected}"
        );
    }

    /// Off a straight edge, and off a slot's straight sides, the web is a strip: every
    /// proposal is kept (the draws and the scan as before arcs were taken).
    #[test]
    fn a_web_off_a_straight_edge_keeps_every_proposal() {
        let slot = hole(1.0, 5.0);
        assert!(!slot.on_arc(3.0) && slot.on_arc(11.0) && slot.on_arc(slot.length() - 0.1));
        let side = Burr {
            end_mm: 9.0,
            ..web(&slot, 0.4)
        };
        let segment = Edge::Segment([0.0, 0.0], [10.0, 0.0]);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        for (edge, b) in [(segment, web(&segment, 0.4)), (slot, side)] {
            let (face, free) = true_area(&edge, &b);
            assert!((2.0 * face + free - strip_area(&b)).abs() < 1e-12);
            let sampler = BurrSampler::new(&[edge], &[b]);
            assert!((0..2000).all(|_| sampler.sample(&mut rng).kept));
        }
        // A slot's round end is half an annulus.
        let round = Burr {
            start_mm: 10.0,
            end_mm: 10.0 + std::f64::consts::PI,
            ..web(&slot, 0.4)
        };
        let (face, _) = true_area(&slot, &round);
        let half_annulus = std::f64::consts::PI / 2.0 * (1.0 - 0.6 * 0.6);
        assert!(
            (face - half_annulus).abs() < 1e-9,
            "{face} vs {half_annulus}"
        );
    }
}
