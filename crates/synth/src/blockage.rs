//! Blockages on the untrimmed core: a film of material left over a hole or slot.
//!
//! The model follows the burrs' (see [`crate::burr`]): the film forms in the parting plane, so
//! it is flush with the top face (its upper side continues the face) and hangs its *thickness*
//! below it. It covers the part of the opening on one side of a straight free edge across it:
//! the opening's points `x` with `(x − centre)·direction ≤ offset` (all of it when the offset
//! reaches past the rim), a *covered share* of the opening's area. The film is deformed and
//! placed with the part; the scanner samples its upper side, its underside and its free edge
//! under the part's visibility rule, and it hides nothing (occlusion is the part's mesh alone).

use rand::Rng;
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{Point3, Vector3};

use crate::part::{AreaTable, Cutout, DomainSample, THICKNESS_MM};

/// Grid nodes per side over a cutout's bounding box when the film's free edge is placed for a
/// covered share (the share is then exact to about 1/(π/4·GRID²) of the opening).
const SHARE_GRID: usize = 200;

/// One blockage's ground truth, domain (design) measures in mm, before the deformation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Blockage {
    /// The id of the contour that rims the opening (template path and truth).
    pub contour: i64,
    /// The share of the opening's area the film covers, 0–1.
    pub covered_share: f64,
    /// The film's thickness below the top face, mm.
    pub thickness_mm: f64,
    /// The unit direction across the opening (domain `(u, v)` plane) the free edge is normal to.
    pub direction: [f64; 2],
    /// The free edge: the film covers the opening's points with `(x − centre)·direction ≤` this,
    /// mm.
    pub offset_mm: f64,
}

impl Blockage {
    /// Whether the film covers the domain-plane point `(u, v)` of `cutout`.
    #[must_use]
    pub fn covers(&self, cutout: &Cutout, u: f64, v: f64) -> bool {
        cutout.contains(u, v)
            && (u - cutout.u_mm) * self.direction[0] + (v - cutout.v_mm) * self.direction[1]
                <= self.offset_mm
    }
}

/// The blockage ranges to draw from and which share of the openings carry one.
pub(crate) struct BlockageRanges {
    pub(crate) fraction: f64,
    pub(crate) thickness_mm: [f64; 2],
    pub(crate) covered_share: [f64; 2],
}

/// Draws the blockages: `round(fraction × cutouts)` openings (a seeded subset), each with a
/// thickness and a covered share uniform in their ranges and a direction uniform in angle.
/// Contour ids are the cutout's index + 1 (the template path's order). Sorted by contour id.
pub(crate) fn draw_blockages(
    ranges: &BlockageRanges,
    cutouts: &[Cutout],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<Blockage> {
    let n_blocked = ((ranges.fraction * cutouts.len() as f64).round() as usize).min(cutouts.len());
    let mut order: Vec<usize> = (0..cutouts.len()).collect();
    for i in 0..n_blocked {
        let j = rng.random_range(i..order.len());
        order.swap(i, j);
    }
    let mut chosen = order[..n_blocked].to_vec();
    chosen.sort_unstable();
    let uniform = |rng: &mut Xoshiro256PlusPlus, [lo, hi]: [f64; 2]| rng.random_range(lo..=hi);
    chosen
        .into_iter()
        .map(|k| {
            let c = &cutouts[k];
            let thickness_mm = uniform(rng, ranges.thickness_mm);
            let share = uniform(rng, ranges.covered_share);
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let direction = [angle.cos(), angle.sin()];
            let (offset_mm, covered_share) = edge_for_share(c, direction, share);
            Blockage {
                contour: i64::try_from(k + 1).unwrap_or(i64::MAX),
                covered_share,
                thickness_mm,
                direction,
                offset_mm,
            }
        })
        .collect()
}

/// The free edge's offset that covers `share` of the opening, and the share it covers on the
/// grid (the truth recorded): the `share` quantile of the projections of a regular grid of the
/// opening's points onto `direction`.
fn edge_for_share(c: &Cutout, direction: [f64; 2], share: f64) -> (f64, f64) {
    let (hu, hv) = (c.radius_mm, c.radius_mm + c.half_length_mm);
    let mut projections = Vec::with_capacity(SHARE_GRID * SHARE_GRID);
    for i in 0..SHARE_GRID {
        for j in 0..SHARE_GRID {
            let du = -hu + 2.0 * hu * (i as f64 + 0.5) / SHARE_GRID as f64;
            let dv = -hv + 2.0 * hv * (j as f64 + 0.5) / SHARE_GRID as f64;
            if c.contains(c.u_mm + du, c.v_mm + dv) {
                projections.push(du * direction[0] + dv * direction[1]);
            }
        }
    }
    projections.sort_by(f64::total_cmp);
    let n = projections.len();
    if n == 0 || share >= 1.0 {
        // Past the rim: the whole opening.
        return (hu.max(hv) + 1.0, 1.0);
    }
    let k = ((share * n as f64).round() as usize).clamp(1, n);
    (projections[k - 1], k as f64 / n as f64)
}

/// A straight segment in the domain plane: its two ends, mm.
type Segment2 = ([f64; 2], [f64; 2]);

/// Samples the films' surfaces: upper side and underside uniformly over the covered area, the
/// free edge uniformly in (length, thickness).
pub(crate) struct BlockageSampler {
    films: Vec<(Cutout, Blockage, f64, Option<Segment2>)>,
    areas: AreaTable,
}

impl BlockageSampler {
    /// The films of `blockages` over `cutouts` (contour id = index + 1).
    pub(crate) fn new(cutouts: &[Cutout], blockages: &[Blockage]) -> Self {
        let mut films = Vec::with_capacity(blockages.len());
        let mut areas = AreaTable::default();
        for b in blockages {
            let Some(c) = usize::try_from(b.contour - 1)
                .ok()
                .and_then(|i| cutouts.get(i))
            else {
                continue;
            };
            let face = b.covered_share * opening_area(c);
            let edge = free_edge(c, b);
            let edge_len = edge.map_or(0.0, |(a, e)| (e[0] - a[0]).hypot(e[1] - a[1]));
            areas.push(2.0 * face + edge_len * b.thickness_mm);
            films.push((*c, *b, face, edge));
        }
        BlockageSampler { films, areas }
    }

    /// The sampled area (upper side, underside, free edge), mm².
    pub(crate) fn area(&self) -> f64 {
        self.areas.total()
    }

    /// One sample (domain point and normal). Only called when [`Self::area`] is positive.
    pub(crate) fn sample(&self, rng: &mut impl Rng) -> DomainSample {
        let i = self.areas.pick(rng);
        let (c, b, face, edge) = &self.films[i];
        let top = THICKNESS_MM / 2.0;
        let piece = rng.random_range(0.0..self.areas.area_of(i));
        if let Some((a, e)) = edge.filter(|_| piece >= 2.0 * face) {
            let s = rng.random_range(0.0..1.0);
            let w = top - b.thickness_mm * rng.random_range(0.0..1.0);
            return DomainSample {
                point: Point3::new(a[0] + s * (e[0] - a[0]), a[1] + s * (e[1] - a[1]), w),
                normal: Vector3::new(b.direction[0], b.direction[1], 0.0),
            };
        }
        let (hu, hv) = (c.radius_mm, c.radius_mm + c.half_length_mm);
        let (u, v) = loop {
            let u = c.u_mm + rng.random_range(-hu..hu);
            let v = c.v_mm + rng.random_range(-hv..hv);
            if b.covers(c, u, v) {
                break (u, v);
            }
        };
        let (w, normal) = if piece < *face {
            (top, 1.0)
        } else {
            (top - b.thickness_mm, -1.0)
        };
        DomainSample {
            point: Point3::new(u, v, w),
            normal: Vector3::new(0.0, 0.0, normal),
        }
    }
}

/// The opening's area, mm².
fn opening_area(c: &Cutout) -> f64 {
    std::f64::consts::PI * c.radius_mm * c.radius_mm + 4.0 * c.half_length_mm * c.radius_mm
}

/// The film's free edge across the opening (its two ends on the rim), or none when the film
/// covers the whole opening.
fn free_edge(c: &Cutout, b: &Blockage) -> Option<Segment2> {
    let [du, dv] = b.direction;
    let foot = [c.u_mm + b.offset_mm * du, c.v_mm + b.offset_mm * dv];
    if !c.contains(foot[0], foot[1]) {
        return None;
    }
    let along = [-dv, du];
    let reach = c.radius_mm + c.half_length_mm;
    // Bisection for the rim crossing on each side of the foot (the opening is convex).
    let end = |sign: f64| {
        let (mut inside, mut outside) = (0.0, reach + 1e-9);
        for _ in 0..60 {
            let mid = 0.5 * (inside + outside);
            if c.contains(
                foot[0] + sign * mid * along[0],
                foot[1] + sign * mid * along[1],
            ) {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        [
            foot[0] + sign * inside * along[0],
            foot[1] + sign * inside * along[1],
        ]
    };
    Some((end(-1.0), end(1.0)))
}
