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

/// The grid step (domain plane, mm) on which a film's remains are kept ([`Film`]): a quarter
/// of the paper's kerf (41 µm), so a strip two kerfs leave between them shows from about 10 µm
/// wide; a narrower strip may be missed or read a cell wide.
pub const FILM_GRID_MM: f64 = 0.01;

/// A blockage film as it stands: the blockage's truth and, on a grid of [`FILM_GRID_MM`] over
/// its opening's box (domain plane), the depth removed from its top so far. Where the depth
/// removed reaches the film's thickness the film is cleared there; elsewhere it stands, thinned
/// from the top. An untouched film keeps no grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Film {
    /// The film's truth as drawn.
    pub blockage: Blockage,
    cutout: Cutout,
    /// The grid's lower corner, domain mm.
    lo: [f64; 2],
    cols: usize,
    rows: usize,
    /// Per cell (row-major, `j·cols + i`), the depth removed from the top, mm; empty while
    /// untouched.
    removed_mm: Vec<f64>,
}

impl Film {
    /// The film of `blockage` as drawn (nothing removed), or `None` when its contour rims no
    /// opening of the part.
    #[must_use]
    pub fn new(blockage: &Blockage) -> Option<Film> {
        let cutout = usize::try_from(blockage.contour - 1)
            .ok()
            .and_then(|i| crate::part::cutouts().get(i).copied())?;
        let (hu, hv) = (cutout.radius_mm, cutout.radius_mm + cutout.half_length_mm);
        let cols = (2.0 * hu / FILM_GRID_MM).ceil() as usize;
        let rows = (2.0 * hv / FILM_GRID_MM).ceil() as usize;
        Some(Film {
            blockage: *blockage,
            cutout,
            lo: [cutout.u_mm - hu, cutout.v_mm - hv],
            cols,
            rows,
            removed_mm: Vec::new(),
        })
    }

    /// The films of `blockages` as drawn (a blockage whose contour rims no opening is left out).
    #[must_use]
    pub fn of(blockages: &[Blockage]) -> Vec<Film> {
        blockages.iter().filter_map(Film::new).collect()
    }

    /// The contour id that rims the film's opening.
    #[must_use]
    pub fn contour(&self) -> i64 {
        self.blockage.contour
    }

    /// The grid's columns (along `u`) and rows (along `v`).
    #[must_use]
    pub fn grid(&self) -> (usize, usize) {
        (self.cols, self.rows)
    }

    /// The centre of cell `(i, j)`, domain mm.
    #[must_use]
    pub fn cell_centre(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.lo[0] + (i as f64 + 0.5) * FILM_GRID_MM,
            self.lo[1] + (j as f64 + 0.5) * FILM_GRID_MM,
        ]
    }

    /// The cells whose centres may lie within `[u0, u1] × [v0, v1]` (domain mm), as column and
    /// row ranges (empty where the box misses the grid).
    #[must_use]
    pub fn cells_in(
        &self,
        [u0, u1]: [f64; 2],
        [v0, v1]: [f64; 2],
    ) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        let range = |lo: f64, a: f64, b: f64, n: usize| {
            let first = ((a - lo) / FILM_GRID_MM - 0.5).ceil().max(0.0);
            let last = ((b - lo) / FILM_GRID_MM - 0.5).floor();
            if !(first.is_finite() && last.is_finite()) || last < first {
                return 0..0;
            }
            (first as usize).min(n)..((last as usize).saturating_add(1)).min(n)
        };
        (
            range(self.lo[0], u0, u1, self.cols),
            range(self.lo[1], v0, v1, self.rows),
        )
    }

    /// Whether the film as drawn covers cell `(i, j)` (at its centre).
    #[must_use]
    pub fn covers_cell(&self, i: usize, j: usize) -> bool {
        let [u, v] = self.cell_centre(i, j);
        self.blockage.covers(&self.cutout, u, v)
    }

    /// Removes `depth_mm` more from the top of cell `(i, j)`.
    pub fn remove(&mut self, i: usize, j: usize, depth_mm: f64) {
        if i >= self.cols || j >= self.rows || depth_mm <= 0.0 {
            return;
        }
        if self.removed_mm.is_empty() {
            self.removed_mm = vec![0.0; self.cols * self.rows];
        }
        self.removed_mm[j * self.cols + i] += depth_mm;
    }

    /// The depth removed from the top at the domain point `(u, v)`, mm (at most the thickness).
    #[must_use]
    pub fn removed_at(&self, u: f64, v: f64) -> f64 {
        if self.removed_mm.is_empty() {
            return 0.0;
        }
        let cell = |x: f64, lo: f64, n: usize| {
            let k = ((x - lo) / FILM_GRID_MM).floor();
            (k >= 0.0 && k < n as f64).then_some(k as usize)
        };
        match (
            cell(u, self.lo[0], self.cols),
            cell(v, self.lo[1], self.rows),
        ) {
            (Some(i), Some(j)) => {
                self.removed_mm[j * self.cols + i].min(self.blockage.thickness_mm)
            }
            _ => 0.0,
        }
    }

    /// The thickness left at the domain point `(u, v)`, mm (0 where the film never was or is
    /// cleared).
    #[must_use]
    pub fn remaining_at(&self, u: f64, v: f64) -> f64 {
        if !self.blockage.covers(&self.cutout, u, v) {
            return 0.0;
        }
        let left = self.blockage.thickness_mm - self.removed_at(u, v);
        if left > CLEARED_BELOW_MM { left } else { 0.0 }
    }

    /// The share of the film as drawn that still stands (cells by their centres; exactly 1 while
    /// untouched).
    #[must_use]
    pub fn standing_share(&self) -> f64 {
        if self.removed_mm.is_empty() {
            return 1.0;
        }
        let (mut drawn, mut standing) = (0usize, 0usize);
        for j in 0..self.rows {
            for i in 0..self.cols {
                if self.covers_cell(i, j) {
                    drawn += 1;
                    let [u, v] = self.cell_centre(i, j);
                    if self.remaining_at(u, v) > 0.0 {
                        standing += 1;
                    }
                }
            }
        }
        if drawn == 0 {
            0.0
        } else {
            standing as f64 / drawn as f64
        }
    }

    /// The share of the opening the film still covers (its drawn share times the share standing).
    #[must_use]
    pub fn covered_share(&self) -> f64 {
        self.blockage.covered_share * self.standing_share()
    }
}

/// A film thinner than this (mm) is gone: the depths removed add up in floating point.
const CLEARED_BELOW_MM: f64 = 1e-9;

/// Samples the films' surfaces where they stand: upper side (thinned where a cut took some of
/// it) and underside uniformly over the area standing, the free edge uniformly in (length,
/// thickness) where it stands. The walls a cut leaves inside a film are not sampled (they are a
/// film's thickness tall, 50–200 µm, and inspection reads a film by its faces). An untouched
/// film is sampled with exactly the draws it was before films could be cut.
pub(crate) struct BlockageSampler {
    films: Vec<(Film, f64, Option<Segment2>)>,
    areas: AreaTable,
}

impl BlockageSampler {
    /// The films as they stand.
    pub(crate) fn new(films: &[Film]) -> Self {
        let mut kept = Vec::with_capacity(films.len());
        let mut areas = AreaTable::default();
        for f in films {
            let (c, b) = (&f.cutout, &f.blockage);
            let face = b.covered_share * opening_area(c) * f.standing_share();
            let edge = free_edge(c, b);
            let edge_len = edge.map_or(0.0, |(a, e)| (e[0] - a[0]).hypot(e[1] - a[1]));
            let area = 2.0 * face + edge_len * b.thickness_mm * edge_standing_share(f, edge);
            if area <= 0.0 {
                continue;
            }
            areas.push(area);
            kept.push((f.clone(), face, edge));
        }
        BlockageSampler { films: kept, areas }
    }

    /// The sampled area (upper side, underside, free edge), mm².
    pub(crate) fn area(&self) -> f64 {
        self.areas.total()
    }

    /// One sample (domain point and normal). Only called when [`Self::area`] is positive.
    pub(crate) fn sample(&self, rng: &mut impl Rng) -> DomainSample {
        let i = self.areas.pick(rng);
        let (f, face, edge) = &self.films[i];
        let (c, b) = (&f.cutout, &f.blockage);
        let top = THICKNESS_MM / 2.0;
        let piece = rng.random_range(0.0..self.areas.area_of(i));
        if let Some((a, e)) = edge.filter(|_| piece >= 2.0 * face) {
            loop {
                let s = rng.random_range(0.0..1.0);
                let (u, v) = (a[0] + s * (e[0] - a[0]), a[1] + s * (e[1] - a[1]));
                let removed = f.removed_at(u, v);
                let w = top - removed - (b.thickness_mm - removed) * rng.random_range(0.0..1.0);
                if f.removed_mm.is_empty() || edge_stands(f, u, v) {
                    return DomainSample {
                        point: Point3::new(u, v, w),
                        normal: Vector3::new(b.direction[0], b.direction[1], 0.0),
                    };
                }
            }
        }
        let (hu, hv) = (c.radius_mm, c.radius_mm + c.half_length_mm);
        let (u, v) = loop {
            let u = c.u_mm + rng.random_range(-hu..hu);
            let v = c.v_mm + rng.random_range(-hv..hv);
            if b.covers(c, u, v) && f.remaining_at(u, v) > 0.0 {
                break (u, v);
            }
        };
        let (w, normal) = if piece < *face {
            (top - f.removed_at(u, v), 1.0)
        } else {
            (top - b.thickness_mm, -1.0)
        };
        DomainSample {
            point: Point3::new(u, v, w),
            normal: Vector3::new(0.0, 0.0, normal),
        }
    }
}

/// The share of a film's free edge that still stands (exactly 1 while untouched; 0 without a
/// free edge), at points a grid step apart.
fn edge_standing_share(f: &Film, edge: Option<Segment2>) -> f64 {
    let Some((a, e)) = edge else {
        return 0.0;
    };
    if f.removed_mm.is_empty() {
        return 1.0;
    }
    let len = (e[0] - a[0]).hypot(e[1] - a[1]);
    let n = ((len / FILM_GRID_MM).ceil() as usize).max(1);
    let standing = (0..n)
        .filter(|k| {
            let s = (*k as f64 + 0.5) / n as f64;
            edge_stands(f, a[0] + s * (e[0] - a[0]), a[1] + s * (e[1] - a[1]))
        })
        .count();
    standing as f64 / n as f64
}

/// Whether the film stands at the free-edge point `(u, v)`: read a hair inside the film, since
/// the point lies on the edge itself.
fn edge_stands(f: &Film, u: f64, v: f64) -> bool {
    const INSIDE_MM: f64 = 1e-6;
    let [du, dv] = f.blockage.direction;
    f.remaining_at(u - INSIDE_MM * du, v - INSIDE_MM * dv) > 0.0
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
