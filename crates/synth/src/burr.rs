//! Flash (burrs) on the untrimmed core: thin webs standing off the edges the contours follow.
//!
//! The model: a pressed core's flash forms where the die halves meet; the contours of this part
//! all follow the top face's edges, so the top face is taken as the parting plane. A burr is a
//! web in that plane, flush with the top face (its upper side continues the face), reaching
//! out of the material away from the edge (into a hole or slot, or beyond the outer boundary)
//! by its *height* and hanging its *thickness* below the face, over a *stretch* of the edge.
//! The web is deformed and placed with the part. The scanner samples its upper side, its
//! underside and its free edge (not its two end faces, each a height × thickness sliver) under
//! the part's visibility rule; it hides nothing (occlusion is the part's mesh alone).

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

/// Samples the burrs' surfaces uniformly in (arc length, height) and (arc length, thickness).
pub(crate) struct BurrSampler {
    webs: Vec<(Edge, Burr)>,
    areas: AreaTable,
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
            areas.push(web_area(b));
            webs.push((*edge, *b));
        }
        BurrSampler { webs, areas }
    }

    /// The sampled area (upper side, underside, free edge), mm².
    pub(crate) fn area(&self) -> f64 {
        self.areas.total()
    }

    /// One sample (domain point and normal). Only called when [`Self::area`] is positive.
    pub(crate) fn sample(&self, rng: &mut impl Rng) -> DomainSample {
        let (edge, b) = &self.webs[self.areas.pick(rng)];
        let length = b.end_mm - b.start_mm;
        let top = THICKNESS_MM / 2.0;
        let s = b.start_mm + length * rng.random_range(0.0..1.0);
        let (e, m) = edge.at(s);
        let face = length * b.height_mm;
        let piece = rng.random_range(0.0..web_area(b));
        if piece < 2.0 * face {
            let t = b.height_mm * rng.random_range(0.0..1.0);
            let (w, normal) = if piece < face {
                (top, 1.0)
            } else {
                (top - b.thickness_mm, -1.0)
            };
            DomainSample {
                point: Point3::new(e[0] + t * m[0], e[1] + t * m[1], w),
                normal: Vector3::new(0.0, 0.0, normal),
            }
        } else {
            let w = top - b.thickness_mm * rng.random_range(0.0..1.0);
            DomainSample {
                point: Point3::new(e[0] + b.height_mm * m[0], e[1] + b.height_mm * m[1], w),
                normal: Vector3::new(m[0], m[1], 0.0),
            }
        }
    }
}

/// Upper side + underside + free edge, mm².
fn web_area(b: &Burr) -> f64 {
    (b.end_mm - b.start_mm) * (2.0 * b.height_mm + b.thickness_mm)
}
