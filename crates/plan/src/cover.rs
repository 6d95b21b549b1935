//! Pose selection as covering (`zoning.method = "cover"`, issue 15 part 1).
//!
//! A *pose* is a head axis `a` (unit, work-piece frame) plus a field centre `c`. It *covers* a
//! contour piece when every point `p` of the piece, with `d = (p − c)` projected across `a`:
//! - lies inside the field: `|d| ≤ R`, with R the field's inscribed circle radius less a margin
//!   for the lens height term (a circle, because the in-plane rotation of the field is fixed
//!   later by the machine pose);
//! - meets the incidence limit with the *real* ray at that field position: the angle between
//!   the point's feature vector and [`Lens::ray`] at `d` is within the limit (no fixed lens
//!   budget). This is the check validation makes, since the ray does not depend on the in-plane
//!   rotation or on the layer;
//! - fits the layer stack: the layers are cut along `a` afterwards, each point lies within ΔH/2
//!   of a focal plane by construction; the margin on R keeps the height-shifted galvo command
//!   inside the field.
//!
//! The procedure:
//! 1. **Atoms.** Contours are cut into pieces of at most [`ATOM_MAX_LENGTH_MM`] (equal lengths
//!    per contour, so short contours such as holes stay whole) whose feature vectors stay within
//!    half the limit of their mean; an atom that no pose covers alone is halved again. The pieces
//!    of a contour share their boundary points, as [`crate::piece`] does.
//! 2. **Fit.** For a set of points the pose is found by alternating: the centre is the centre of
//!    the smallest circle around the points across the axis; each point asks for the axis `a_p`
//!    whose ray would meet it head on (`f·a_p ∝ λ·n + d`, solved exactly for λ), and the axis
//!    becomes the centre of the smallest circle around the gnomonic projections of those (the
//!    minimax direction, Welzl's algorithm). To first order only the spread of `n + d/f` decides
//!    the incidence, so the centre is free for the field. A fit the machine cannot reach within
//!    its axis limits (checked at the centre) is refused. Growing poses fit only the points that
//!    can decide the fit (the extremes, [`PRUNE_DIRECTIONS`]); checks always use every point.
//! 3. **Candidates.** From every atom (for large inputs, from every atom not yet inside a few
//!    candidates) a pose is grown: the other atoms in order of how far they lie from it
//!    (normalised by the limit and by R) join while a refitted pose still covers every member.
//!    Each candidate then covers, exactly, every atom it covers.
//! 4. **Greedy set cover** over the candidates, then **local improvement**, until nothing
//!    changes: drop poses whose atoms others cover; merge a pair of poses when one refitted pose
//!    covers the atoms only they cover; remove a pose when each atom only it covers moves into a
//!    nearby pose refitted to keep its own atoms as well.
//! 5. **Assignment.** Along each contour an atom stays with the pose of the atom before it while
//!    that pose covers it, otherwise goes to the pose covering the longest run from it;
//!    consecutive atoms of a contour in one pose become one piece.
//! 6. **Lower bound.** A greedy set of atoms pairwise incompatible: no candidate covers both and
//!    the fit of the pair fails. Every pose covers at most one of them, so the pose count is at
//!    least its size. The incompatibility is decided by the fitter, so the bound holds for poses
//!    of that form (it is not a proof over every axis and centre).
//!
//! Atoms no reachable pose covers are covered again with the reach ignored, so they are grouped
//! into a few poses the planner marks unreachable, as it marks k-means zones.
//!
//! Figures (release build, 2 cores): the demo part (52 contours) 18 poses against k-means' 50,
//! lower bound 14, incidence ≤ 4.99° with the real ray; synthetic cores of 52/60 contours 13–15
//! poses against 20–24; 2,000 contours 19 poses against 82, planned in about 0.28 s (k-means
//! about 0.8–1.0 s).

use std::f64::consts::PI;

use rayon::prelude::*;

use trim_geom::{Path, Point3, UnitVector3, Vector3};

use crate::error::PlanError;
use crate::piece::{Piece, angle_rad, pieces_of};
use crate::scan_field::Lens;
use trim_cell::frame::paper_frame;

/// The longest atom (mm). Longer contours are cut into equal atoms no longer than this.
pub const ATOM_MAX_LENGTH_MM: f64 = 10.0;

/// The most atoms the path may be cut into, before the fits ([`ATOM_MAX_LENGTH_MM`] each: 50 m
/// of contour) and after them (where an atom no field holds is halved). The covering's work
/// grows faster than the atoms (at 20,000 a two-point line took 3 minutes; at 5,000 it takes at
/// most a few seconds), so a contour far longer than a part (a point 10⁴ mm off, or in the wrong
/// units) or a field far smaller than a lens's is refused naming it instead of planned for
/// minutes or cut into more pieces than memory holds. The demo core is 366 atoms.
pub const MAX_ATOMS: usize = 5_000;

/// An atom's feature vectors stay within this fraction of the limit of their mean.
pub const ATOM_SPREAD_FRACTION: f64 = 0.5;

/// How often an atom no pose covers alone is halved again.
pub const MAX_ATOM_SPLITS: usize = 8;

/// Atoms shorter than this (mm) are not cut further.
pub const MIN_ATOM_LENGTH_MM: f64 = 0.05;

/// Incidence kept below the limit by this much (radians) for the points validation adds by
/// interpolation at layer boundaries.
pub const INCIDENCE_MARGIN_RAD: f64 = 1e-4;

/// Field radius kept free (mm) besides the height term.
pub const FIELD_MARGIN_MM: f64 = 0.05;

/// Alternations of centre and axis in a fit.
pub const FIT_ITERATIONS: usize = 2;

/// Points per atom the fits use (evenly spaced, both ends included); the checks use all.
pub const REPRESENTATIVES: usize = 9;

/// Atoms farther than this (in units of the limit and of R) from a growing pose are not tried.
pub const GROW_REACH: f64 = 2.2;

/// Refits a growing pose may try before it stops.
pub const MAX_REFITS: usize = 24;

/// Above this many atoms, an atom already inside this many candidates is not grown from.
pub const SEED_ALL_BELOW: usize = 400;

/// See [`SEED_ALL_BELOW`].
pub const SEED_SKIP_COVERED: usize = 3;

/// Directions in which a growing pose keeps the extreme points of what it fits.
pub const PRUNE_DIRECTIONS: usize = 16;

/// A growing pose also keeps every point beyond this fraction of the largest distance.
pub const PRUNE_KEEP: f64 = 0.85;

/// The length of a 2-D vector (no `hypot`: its extra precision is slow and not needed here).
fn len2(v: [f64; 2]) -> f64 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

/// A point's in-plane position and its wanted axis in tangent coordinates.
type Coords = ([f64; 2], [f64; 2]);

/// One pose: the head axis and the field centre (work-piece frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoverPose {
    /// The head axis (from the part toward the lens).
    pub axis: UnitVector3,
    /// The field centre (on the optical axis).
    pub centre: Point3,
    x: Vector3,
    y: Vector3,
}

impl CoverPose {
    /// A pose from its axis and centre.
    #[must_use]
    pub fn new(axis: UnitVector3, centre: Point3) -> CoverPose {
        let f = paper_frame(&axis);
        CoverPose {
            axis,
            centre,
            x: f.x_axis(),
            y: f.y_axis(),
        }
    }

    fn in_plane(&self, p: &Point3) -> [f64; 2] {
        let d = p - self.centre;
        [d.dot(&self.x), d.dot(&self.y)]
    }
}

/// What the covering must respect.
pub struct CoverProblem<'a> {
    /// The incidence limit (radians).
    pub limit_rad: f64,
    /// The usable field radius (mm).
    pub field_radius_mm: f64,
    /// The lens (for the real ray).
    pub lens: Lens,
    /// A machine whose beam direction is fixed: every pose uses it.
    pub fixed_axis: Option<UnitVector3>,
    /// Whether the machine reaches a pose (axis, centre) within its limits.
    pub reachable: &'a (dyn Fn(&UnitVector3, &Point3) -> bool + Sync),
}

/// One zone of the covering: a pose and the pieces it processes.
#[derive(Debug, Clone, PartialEq)]
pub struct CoverZone {
    /// The head axis.
    pub axis: UnitVector3,
    /// The field centre: the zone origin.
    pub origin: Point3,
    /// The pieces (parts of contours sharing boundary points).
    pub pieces: Vec<Piece>,
}

/// Figures of a covering, for the report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CoverReport {
    /// Atoms the contours were cut into.
    pub atoms: usize,
    /// Candidate poses generated.
    pub candidates: usize,
    /// Poses after the greedy set cover.
    pub greedy_poses: usize,
    /// Poses after the local improvement (the zones).
    pub poses: usize,
    /// Pairs merged by the local improvement.
    pub merges: usize,
    /// Poses dropped as redundant.
    pub dropped: usize,
    /// Poses removed by moving their atoms into refitted neighbours.
    pub absorbed: usize,
    /// Atoms no reachable pose covers: grouped into poses without the reach, which the planner
    /// marks unreachable.
    pub uncovered_atoms: usize,
    /// The lower bound on the pose count (see the module docs).
    pub lower_bound: usize,
}

/// The covering: zones in the order of their first atom, and the report.
#[derive(Debug, Clone, PartialEq)]
pub struct Cover {
    /// The zones.
    pub zones: Vec<CoverZone>,
    /// The figures.
    pub report: CoverReport,
}

#[derive(Clone)]
struct Atom {
    piece: Piece,
    /// Index of its contour in the path; atoms of a contour are consecutive, in order.
    contour: usize,
    rep: Vec<(Point3, Vector3)>,
    centroid: Point3,
    mean: Vector3,
    /// The largest distance of a point from the centroid (mm).
    radius: f64,
}

impl Atom {
    fn new(piece: Piece, contour: usize) -> Atom {
        let n = piece.points.len();
        let k = REPRESENTATIVES.min(n);
        let mut idx: Vec<usize> = (0..k)
            .map(|i| {
                if k <= 1 {
                    0
                } else {
                    (i * (n - 1) + (k - 1) / 2) / (k - 1)
                }
            })
            .collect();
        idx.dedup();
        let rep = idx
            .iter()
            .map(|&i| (piece.points[i], piece.features[i]))
            .collect();
        let centroid = piece.centroid();
        let radius = piece
            .points
            .iter()
            .map(|p| (p - centroid).norm())
            .fold(0.0, f64::max);
        let mean = piece.feature().into_inner();
        Atom {
            piece,
            contour,
            rep,
            centroid,
            mean,
            radius,
        }
    }
}

impl CoverProblem<'_> {
    /// The cosine of the incidence limit less its margin.
    fn cos_limit(&self) -> f64 {
        (self.limit_rad - INCIDENCE_MARGIN_RAD).cos()
    }

    /// Whether `pose` covers point `p` with feature `n`; `cos_limit` from [`Self::cos_limit`].
    fn covers_point(&self, pose: &CoverPose, p: &Point3, n: &Vector3, cos_limit: f64) -> bool {
        let uv = pose.in_plane(p);
        if uv[0] * uv[0] + uv[1] * uv[1] > self.field_radius_mm * self.field_radius_mm {
            return false;
        }
        let ray = self.lens.ray(&pose.x, &pose.y, &pose.axis, uv);
        // Near the limit the exact angle decides; far inside or outside the cosine does.
        let c = n.dot(&ray);
        if (c - cos_limit).abs() > 1e-9 {
            return c > cos_limit;
        }
        angle_rad(n, &ray) <= self.limit_rad - INCIDENCE_MARGIN_RAD
    }

    fn covers_atom(&self, pose: &CoverPose, atom: &Atom) -> bool {
        // Cheap refusal: the whole atom is outside the field.
        let uv = pose.in_plane(&atom.centroid);
        if len2(uv) - atom.radius > self.field_radius_mm {
            return false;
        }
        let cos_limit = self.cos_limit();
        atom.piece
            .points
            .iter()
            .zip(&atom.piece.features)
            .all(|(p, n)| self.covers_point(pose, p, n, cos_limit))
    }

    fn covers_rep(&self, pose: &CoverPose, rep: &[(Point3, Vector3)]) -> bool {
        let cos_limit = self.cos_limit();
        rep.iter()
            .all(|(p, n)| self.covers_point(pose, p, n, cos_limit))
    }

    /// The axis whose ray at in-plane offset `d` meets feature `n` head on.
    fn ideal_axis(&self, n: &Vector3, d: &Vector3) -> Vector3 {
        if self.lens.telecentric {
            return *n;
        }
        let f = self.lens.focal_length_mm;
        let nd = n.dot(d);
        let disc = nd * nd - d.norm_squared() + f * f;
        if disc <= 0.0 {
            return *n;
        }
        let lambda = -nd + disc.sqrt();
        (n * lambda + d).normalize()
    }

    /// How far an atom lies from a pose: the larger of its axis distance over the limit and its
    /// in-plane distance over R.
    /// The in-plane part of [`Self::distance`] (never more than it: a cheap first filter).
    fn radial(&self, pose: &CoverPose, atom: &Atom) -> f64 {
        len2(pose.in_plane(&atom.centroid)) / self.field_radius_mm
    }

    fn distance(&self, pose: &CoverPose, atom: &Atom) -> f64 {
        let uv = pose.in_plane(&atom.centroid);
        let d = pose.x * uv[0] + pose.y * uv[1];
        let wanted = self.ideal_axis(&atom.mean, &d);
        let angular = angle_rad(&wanted, &pose.axis) / self.limit_rad;
        let radial = len2(uv) / self.field_radius_mm;
        angular.max(radial)
    }

    /// The pose fitted to a set of points (see the module docs), `None` when unreachable.
    fn fit(&self, pts: &[(Point3, Vector3)], start: Option<&UnitVector3>) -> Option<CoverPose> {
        if pts.is_empty() {
            return None;
        }
        let mut axis = match (self.fixed_axis, start) {
            (Some(a), _) => a,
            (None, Some(a)) => *a,
            (None, None) => {
                let normals: Vec<Vector3> = pts.iter().map(|p| p.1).collect();
                let sum: Vector3 = normals.iter().sum();
                let mean = if sum.norm() > 1e-12 {
                    UnitVector3::new_normalize(sum)
                } else {
                    UnitVector3::new_normalize(normals[0])
                };
                minimax_axis(&mean, &normals)
            }
        };
        let mut pose = centred(axis, pts);
        if self.fixed_axis.is_none() {
            let mut wanted = Vec::with_capacity(pts.len());
            for _ in 0..FIT_ITERATIONS {
                wanted.clear();
                for (p, n) in pts {
                    let uv = pose.in_plane(p);
                    let d = pose.x * uv[0] + pose.y * uv[1];
                    wanted.push(self.ideal_axis(n, &d));
                }
                let next = minimax_axis(&axis, &wanted);
                let moved = angle_rad(&next, &axis);
                axis = next;
                pose = centred(axis, pts);
                if moved < 1e-9 {
                    break;
                }
            }
        }
        (self.reachable)(&pose.axis, &pose.centre).then_some(pose)
    }

    /// The points that can decide a fit near `pose`: the extremes of the in-plane positions
    /// and of the wanted axes (tangent coordinates) in [`PRUNE_DIRECTIONS`] directions, and
    /// every point within [`PRUNE_KEEP`] of the largest distance of either. The fit of the rest
    /// is nearly the fit of all; the checks always use all points.
    fn prune(&self, pose: &CoverPose, pts: &[(Point3, Vector3)]) -> Vec<(Point3, Vector3)> {
        if pts.len() <= 4 * PRUNE_DIRECTIONS {
            return pts.to_vec();
        }
        let coords: Vec<Coords> = pts
            .iter()
            .map(|(p, n)| {
                let uv = pose.in_plane(p);
                let d = pose.x * uv[0] + pose.y * uv[1];
                let w = self.ideal_axis(n, &d);
                (uv, [w.dot(&pose.x), w.dot(&pose.y)])
            })
            .collect();
        let mut keep = vec![false; pts.len()];
        let (mut max_q, mut max_g): (f64, f64) = (0.0, 0.0);
        for (q, g) in &coords {
            max_q = max_q.max(len2(*q));
            max_g = max_g.max(len2(*g));
        }
        for (i, (q, g)) in coords.iter().enumerate() {
            if len2(*q) >= PRUNE_KEEP * max_q || len2(*g) >= PRUNE_KEEP * max_g {
                keep[i] = true;
            }
        }
        // The extremes in every direction, in one pass (the first index wins a tie; the
        // coordinates are finite).
        let dirs: [(f64, f64); PRUNE_DIRECTIONS] = std::array::from_fn(|k| {
            let t = std::f64::consts::TAU * k as f64 / PRUNE_DIRECTIONS as f64;
            let (s, c) = t.sin_cos();
            (c, s)
        });
        let mut best_q = [(f64::NEG_INFINITY, 0usize); PRUNE_DIRECTIONS];
        let mut best_g = [(f64::NEG_INFINITY, 0usize); PRUNE_DIRECTIONS];
        for (i, (q, g)) in coords.iter().enumerate() {
            for (k, &(c, s)) in dirs.iter().enumerate() {
                let vq = q[0] * c + q[1] * s;
                if vq > best_q[k].0 {
                    best_q[k] = (vq, i);
                }
                let vg = g[0] * c + g[1] * s;
                if vg > best_g[k].0 {
                    best_g[k] = (vg, i);
                }
            }
        }
        for (q, g) in best_q.iter().zip(&best_g) {
            keep[q.1] = true;
            keep[g.1] = true;
        }
        pts.iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(p, _)| *p)
            .collect()
    }

    /// Grows a pose from a seed atom over the atoms near it.
    fn grow(&self, atoms: &[Atom], seed: usize) -> Option<(CoverPose, Vec<usize>)> {
        let mut pts = atoms[seed].rep.clone();
        let mut pose = self.fit(&pts, None)?;
        if !self.covers_rep(&pose, &pts) {
            return None;
        }
        let mut near: Vec<(f64, usize)> = atoms
            .iter()
            .enumerate()
            .filter(|(j, a)| *j != seed && self.radial(&pose, a) <= GROW_REACH)
            .map(|(j, a)| (self.distance(&pose, a), j))
            .filter(|(d, _)| *d <= GROW_REACH)
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut members = vec![seed];
        let mut refits = 0;
        // Pruned when the points double, so pruning costs O(1) per point.
        let mut pruned_len = 4 * PRUNE_DIRECTIONS;
        for (_, j) in near {
            if self.covers_rep(&pose, &atoms[j].rep) {
                members.push(j);
                pts.extend_from_slice(&atoms[j].rep);
                if pts.len() > 2 * pruned_len {
                    pts = self.prune(&pose, &pts);
                    pruned_len = pts.len().max(4 * PRUNE_DIRECTIONS);
                }
                continue;
            }
            if refits >= MAX_REFITS {
                continue;
            }
            refits += 1;
            let mut trial = pts.clone();
            trial.extend_from_slice(&atoms[j].rep);
            if let Some(next) = self.fit(&trial, Some(&pose.axis))
                && self.covers_rep(&next, &trial)
            {
                pose = next;
                pts = self.prune(&pose, &trial);
                pruned_len = pts.len().max(4 * PRUNE_DIRECTIONS);
                members.push(j);
            }
        }
        Some((pose, members))
    }

    /// Every atom a pose covers (all points checked).
    fn coverage(&self, atoms: &[Atom], pose: &CoverPose) -> Vec<usize> {
        (0..atoms.len())
            .filter(|&j| self.covers_atom(pose, &atoms[j]))
            .collect()
    }

    /// The pose refitted to a set of atoms, if it covers all of them.
    fn fit_atoms(
        &self,
        atoms: &[Atom],
        set: &[usize],
        start: Option<&UnitVector3>,
    ) -> Option<CoverPose> {
        let mut pts: Vec<(Point3, Vector3)> =
            set.iter().flat_map(|&j| atoms[j].rep.clone()).collect();
        let mut tries: Vec<Option<&UnitVector3>> = vec![None];
        if let Some(a) = start {
            tries.insert(0, start);
            pts = self.prune(&centred(*a, &pts), &pts);
        }
        for s in tries {
            if let Some(pose) = self.fit(&pts, s)
                && set.iter().all(|&j| self.covers_atom(&pose, &atoms[j]))
            {
                return Some(pose);
            }
        }
        None
    }
}

/// The pose with `axis` centred on the smallest circle around the points across it.
fn centred(axis: UnitVector3, pts: &[(Point3, Vector3)]) -> CoverPose {
    let probe = CoverPose::new(axis, Point3::origin());
    let uv: Vec<[f64; 2]> = pts.iter().map(|(p, _)| probe.in_plane(p)).collect();
    let along = pts.iter().map(|(p, _)| p.coords.dot(&axis)).sum::<f64>() / pts.len() as f64;
    let (c, _) = min_circle(&uv);
    let centre = Point3::from(probe.x * c[0] + probe.y * c[1] + axis.into_inner() * along);
    CoverPose::new(axis, centre)
}

/// The direction that minimises the largest angle to unit vectors near `around`: the centre of
/// the smallest circle around their gnomonic projections on the plane across `around`, twice
/// (the second pass about the first result, where the projection is nearly isometric).
fn minimax_axis(around: &UnitVector3, dirs: &[Vector3]) -> UnitVector3 {
    let mut axis = *around;
    for _ in 0..2 {
        let probe = CoverPose::new(axis, Point3::origin());
        let z = axis.into_inner();
        let g: Vec<[f64; 2]> = dirs
            .iter()
            .filter(|d| d.dot(&z) > 1e-6)
            .map(|d| {
                let w = d.dot(&z);
                [d.dot(&probe.x) / w, d.dot(&probe.y) / w]
            })
            .collect();
        if g.is_empty() {
            break;
        }
        let (c, _) = min_circle(&g);
        axis = UnitVector3::new_normalize(z + probe.x * c[0] + probe.y * c[1]);
    }
    axis
}

/// The smallest circle around 2-D points (centre, radius): the incremental algorithm of Welzl's
/// bounds, the points visited in a fixed pseudo-random order (expected linear time).
fn min_circle(pts: &[[f64; 2]]) -> ([f64; 2], f64) {
    const EPS: f64 = 1e-12;
    let n = pts.len();
    if n == 0 {
        return ([0.0; 2], 0.0);
    }
    // A deterministic shuffle (splitmix64).
    let mut p = pts.to_vec();
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15 ^ n as u64;
    for i in (1..n).rev() {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        p.swap(i, (z % (i as u64 + 1)) as usize);
    }
    // Circles as (centre, squared radius): no square roots in the loops.
    let dist2 = |a: &[f64; 2], b: &[f64; 2]| {
        let (x, y) = (a[0] - b[0], a[1] - b[1]);
        x * x + y * y
    };
    let two = |a: &[f64; 2], b: &[f64; 2]| {
        let c = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
        (c, dist2(&c, a))
    };
    let three = |a: &[f64; 2], b: &[f64; 2], c: &[f64; 2]| {
        let (bx, by) = (b[0] - a[0], b[1] - a[1]);
        let (cx, cy) = (c[0] - a[0], c[1] - a[1]);
        let d = 2.0 * (bx * cy - by * cx);
        if d.abs() < EPS {
            // Collinear: the circle on the farthest pair.
            let cands = [two(a, b), two(a, c), two(b, c)];
            return cands
                .into_iter()
                .max_by(|x, y| x.1.total_cmp(&y.1))
                .unwrap_or(two(a, b));
        }
        let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
        let ux = (cy * b2 - by * c2) / d;
        let uy = (bx * c2 - cx * b2) / d;
        ([a[0] + ux, a[1] + uy], ux * ux + uy * uy)
    };
    let outside =
        |c: &([f64; 2], f64), q: &[f64; 2]| dist2(&c.0, q) > c.1 * (1.0 + 1e-12) + EPS * EPS;
    let mut circle = (p[0], 0.0);
    for i in 1..n {
        if !outside(&circle, &p[i]) {
            continue;
        }
        circle = (p[i], 0.0);
        for j in 0..i {
            if !outside(&circle, &p[j]) {
                continue;
            }
            circle = two(&p[i], &p[j]);
            for k in 0..j {
                if outside(&circle, &p[k]) {
                    circle = three(&p[i], &p[j], &p[k]);
                }
            }
        }
    }
    (circle.0, circle.1.sqrt())
}

/// A piece cut at the given arc lengths (mm, increasing, inside the piece); the cut points are
/// shared by neighbours. Cuts at (or within 1e-9 of a segment from) a vertex cut there.
fn cut_at(p: &Piece, cuts: &[f64]) -> Vec<Piece> {
    const AT_VERTEX: f64 = 1e-9;
    let last = p.points.len() - 1;
    let mut pts: Vec<(Point3, Vector3, f64)> = vec![(p.points[0], p.features[0], p.source[0])];
    let mut breaks: Vec<usize> = Vec::new();
    let mut walked = 0.0;
    let mut k = 0;
    for i in 0..last {
        let seg = (p.points[i + 1] - p.points[i]).norm();
        let mut break_at_end = false;
        while k < cuts.len() && cuts[k] <= walked + seg {
            let t = if seg > 0.0 {
                ((cuts[k] - walked) / seg).clamp(0.0, 1.0)
            } else {
                1.0
            };
            k += 1;
            if t <= AT_VERTEX {
                if pts.len() > 1 && breaks.last() != Some(&(pts.len() - 1)) {
                    breaks.push(pts.len() - 1);
                }
            } else if t >= 1.0 - AT_VERTEX {
                break_at_end = true;
            } else {
                let point = p.points[i] + (p.points[i + 1] - p.points[i]) * t;
                let feature = (p.features[i] * (1.0 - t) + p.features[i + 1] * t).normalize();
                let source = p.source[i] + (p.source[i + 1] - p.source[i]) * t;
                pts.push((point, feature, source));
                breaks.push(pts.len() - 1);
            }
        }
        walked += seg;
        pts.push((p.points[i + 1], p.features[i + 1], p.source[i + 1]));
        if break_at_end && i + 1 < last && breaks.last() != Some(&(pts.len() - 1)) {
            breaks.push(pts.len() - 1);
        }
    }
    let mut out = Vec::with_capacity(breaks.len() + 1);
    let mut from = 0;
    for b in breaks.into_iter().chain(std::iter::once(pts.len() - 1)) {
        if b <= from {
            continue;
        }
        let part = &pts[from..=b];
        out.push(Piece {
            contour: p.contour,
            points: part.iter().map(|q| q.0).collect(),
            features: part.iter().map(|q| q.1).collect(),
            source: part.iter().map(|q| q.2).collect(),
        });
        from = b;
    }
    out
}

/// Cuts a piece into `n` parts of equal length.
fn cut_equal(p: &Piece, n: usize) -> Vec<Piece> {
    if n <= 1 {
        return vec![p.clone()];
    }
    let len = p.length_mm();
    let cuts: Vec<f64> = (1..n).map(|k| len * k as f64 / n as f64).collect();
    cut_at(p, &cuts)
}

fn spread_rad(p: &Piece) -> f64 {
    let mean = p.feature().into_inner();
    p.features
        .iter()
        .map(|f| angle_rad(f, &mean))
        .fold(0.0, f64::max)
}

/// Contour pieces into atoms (see the module docs, step 1). Refuses a path that would be cut
/// into more than [`MAX_ATOMS`] atoms, naming the contour that takes it past and its point
/// farthest from its first.
fn atomize(whole: &[Piece], limit_rad: f64) -> Result<Vec<(Piece, usize)>, PlanError> {
    let mut out = Vec::new();
    let mut total = 0usize;
    for (c, p) in whole.iter().enumerate() {
        let length_mm = p.length_mm();
        // Saturates: an infinite (or overflowing) length is usize::MAX atoms.
        let n = (length_mm / ATOM_MAX_LENGTH_MM).ceil().max(1.0) as usize;
        total = total.saturating_add(n);
        if total > MAX_ATOMS {
            let (point, distance_mm) = p
                .points
                .iter()
                .map(|q| (q - p.points[0]).norm())
                .enumerate()
                .fold(
                    (0, 0.0),
                    |best, (i, d)| if d > best.1 { (i, d) } else { best },
                );
            return Err(PlanError::TooManyAtoms {
                contour: p.contour,
                length_mm,
                point: p.source[point].floor() as usize,
                distance_mm,
                atoms: n,
                atom_mm: ATOM_MAX_LENGTH_MM,
                total,
                max: MAX_ATOMS,
            });
        }
        let mut stack: Vec<Piece> = cut_equal(p, n).into_iter().rev().collect();
        while let Some(q) = stack.pop() {
            if spread_rad(&q) > ATOM_SPREAD_FRACTION * limit_rad
                && q.length_mm() >= 2.0 * MIN_ATOM_LENGTH_MM
            {
                let parts = cut_equal(&q, 2);
                if parts.len() == 2 {
                    stack.extend(parts.into_iter().rev());
                    continue;
                }
            }
            out.push((q, c));
        }
    }
    Ok(out)
}

/// What [`select`] chose.
struct Selection {
    chosen: Vec<(CoverPose, Vec<usize>)>,
    candidates: Vec<(CoverPose, Vec<usize>)>,
    greedy_poses: usize,
    merges: usize,
    dropped: usize,
    absorbed: usize,
    /// Atoms no candidate covers (no pose chosen for them).
    uncovered: Vec<usize>,
}

/// [`CoverProblem::fit_atoms`] remembered: the local improvement retries the same pairs and
/// sets after every change, and a fit is a pure function of its atoms and start axis.
#[derive(Default)]
struct FitCache {
    fits: std::sync::Mutex<std::collections::HashMap<FitKey, Option<CoverPose>>>,
}

/// A fit's atoms and start axis (its bits).
type FitKey = (Vec<usize>, Option<[u64; 3]>);

impl FitCache {
    fn fit_atoms(
        &self,
        problem: &CoverProblem<'_>,
        atoms: &[Atom],
        set: &[usize],
        start: Option<&UnitVector3>,
    ) -> Option<CoverPose> {
        let key = (
            set.to_vec(),
            start.map(|a| [a.x.to_bits(), a.y.to_bits(), a.z.to_bits()]),
        );
        let lock = || {
            self.fits
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        if let Some(found) = lock().get(&key) {
            return *found;
        }
        let fit = problem.fit_atoms(atoms, set, start);
        lock().insert(key, fit);
        fit
    }
}

/// The first item, in order, for which `f` gives `Some`, with its index: the items are tried
/// in windows as wide as the thread pool, each window in parallel, so the answer is the one a
/// sequential search gives (a window's later items are work thrown away).
fn first_in_order<T: Sync, R: Send>(
    items: &[T],
    f: impl Fn(&T) -> Option<R> + Sync,
) -> Option<(usize, R)> {
    let width = rayon::current_num_threads().max(1);
    for (w, window) in items.chunks(width).enumerate() {
        let found = window
            .par_iter()
            .map(&f)
            .enumerate()
            .find_map_first(|(i, r)| r.map(|r| (w * width + i, r)));
        if found.is_some() {
            return found;
        }
    }
    None
}

/// Steps 3 and 4 of the module docs on a set of atoms.
fn select(problem: &CoverProblem<'_>, atoms: &[Atom]) -> Selection {
    let n = atoms.len();
    // (3) candidates.
    let mut candidates: Vec<(CoverPose, Vec<usize>)> = Vec::new();
    let mut inside = vec![0usize; n];
    let skipped =
        |inside: &[usize], seed: usize| n > SEED_ALL_BELOW && inside[seed] >= SEED_SKIP_COVERED;
    let grown = |seed: usize| {
        let (pose, _) = problem.grow(atoms, seed)?;
        let covered = problem.coverage(atoms, &pose);
        (!covered.is_empty()).then_some((pose, covered))
    };
    // Seeds are grown a window at a time (one per thread) in parallel and kept in order, each
    // only if the candidates kept before it leave it unskipped: the same candidates as one at a
    // time. Wider windows lose more to seeds that turn out skipped.
    let width = rayon::current_num_threads().max(1);
    let mut next = 0;
    // A cancelled plan stops growing and improving; `cover` reports it when this returns.
    while next < n && !trim_geom::cancel::is_cancelled() {
        let mut window = Vec::with_capacity(width);
        while next < n && window.len() < width {
            if !skipped(&inside, next) {
                window.push(next);
            }
            next += 1;
        }
        let results: Vec<_> = window.par_iter().map(|&seed| grown(seed)).collect();
        for (&seed, result) in window.iter().zip(results) {
            if skipped(&inside, seed) {
                continue;
            }
            let Some((pose, covered)) = result else {
                continue;
            };
            for &j in &covered {
                inside[j] += 1;
            }
            candidates.push((pose, covered));
        }
    }
    candidates.sort_by(|a, b| a.1.cmp(&b.1));
    candidates.dedup_by(|a, b| a.1 == b.1);

    // (4) greedy set cover.
    let mut covered = vec![false; n];
    let mut chosen: Vec<(CoverPose, Vec<usize>)> = Vec::new();
    loop {
        let best = candidates
            .iter()
            .enumerate()
            .map(|(i, c)| (c.1.iter().filter(|&&j| !covered[j]).count(), c.1.len(), i))
            .filter(|g| g.0 > 0)
            .max_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)).then(b.2.cmp(&a.2)));
        let Some((_, _, i)) = best else { break };
        for &j in &candidates[i].1 {
            covered[j] = true;
        }
        chosen.push(candidates[i].clone());
    }
    let uncovered: Vec<usize> = (0..n).filter(|&j| !covered[j]).collect();
    let greedy_poses = chosen.len();

    // (4) local improvement.
    let (mut merges, mut dropped, mut absorbed) = (0, 0, 0);
    let cache = FitCache::default();
    while !trim_geom::cancel::is_cancelled() {
        dropped += drop_redundant(&mut chosen, n);
        if merge_one(problem, atoms, &mut chosen, &cache) {
            merges += 1;
        } else if absorb_one(problem, atoms, &mut chosen, &cache) {
            absorbed += 1;
        } else {
            break;
        }
    }

    Selection {
        chosen,
        candidates,
        greedy_poses,
        merges,
        dropped,
        absorbed,
        uncovered,
    }
}

/// Plans the covering of a path (see the module docs).
pub fn cover(path: &Path, problem: &CoverProblem<'_>) -> Result<Cover, PlanError> {
    let whole = pieces_of(path, PI, PI)?;
    let always = |_: &UnitVector3, _: &Point3| true;
    let unlimited = CoverProblem {
        limit_rad: problem.limit_rad,
        field_radius_mm: problem.field_radius_mm,
        lens: problem.lens,
        fixed_axis: problem.fixed_axis,
        reachable: &always,
    };
    // Each piece is atomized on its own (in parallel), the atoms kept in path order.
    let atomized = |(piece, c): (Piece, usize)| -> Vec<Atom> {
        let mut out = Vec::new();
        // An atom no pose covers alone is halved again.
        let mut stack = vec![(piece, 0usize)];
        while let Some((q, depth)) = stack.pop() {
            let atom = Atom::new(q, c);
            // Whether it fits geometrically: the reach is not the piece's size.
            let alone = unlimited
                .fit(&atom.rep, None)
                .is_some_and(|pose| unlimited.covers_atom(&pose, &atom));
            if alone
                || depth >= MAX_ATOM_SPLITS
                || atom.piece.length_mm() < 2.0 * MIN_ATOM_LENGTH_MM
            {
                out.push(atom);
                continue;
            }
            let parts = cut_equal(&atom.piece, 2);
            if parts.len() != 2 {
                out.push(atom);
                continue;
            }
            for part in parts.into_iter().rev() {
                stack.push((part, depth + 1));
            }
        }
        out
    };
    let atoms: Vec<Atom> = atomize(&whole, problem.limit_rad)?
        .into_par_iter()
        .map(atomized)
        .collect::<Vec<_>>()
        .into_iter()
        .flatten()
        .collect();
    let n = atoms.len();
    if n > MAX_ATOMS {
        return Err(PlanError::TooManyFieldPieces {
            pieces: n,
            field_radius_mm: problem.field_radius_mm,
            max: MAX_ATOMS,
        });
    }
    crate::error::check_cancel()?;
    let mut sel = select(problem, &atoms);
    crate::error::check_cancel()?;
    // (6) lower bound, over the atoms some reachable pose covers.
    let lower_bound = lower_bound(problem, &atoms, &sel.candidates);
    // Atoms no reachable pose covers: covered again without the reach, so they are grouped;
    // the planner marks those zones unreachable.
    let uncovered = std::mem::take(&mut sel.uncovered);
    if !uncovered.is_empty() {
        let rest: Vec<Atom> = uncovered.iter().map(|&j| atoms[j].clone()).collect();
        let more = select(&unlimited, &rest);
        crate::error::check_cancel()?;
        for (pose, c) in more.chosen {
            sel.chosen
                .push((pose, c.iter().map(|&k| uncovered[k]).collect()));
        }
        for k in more.uncovered {
            // No pose covers it at all: a pose of its own (validation reports what fails).
            let a = &rest[k];
            let pose = centred(UnitVector3::new_normalize(a.mean), &a.rep);
            sel.chosen.push((pose, vec![uncovered[k]]));
        }
    }
    let Selection {
        chosen,
        candidates,
        greedy_poses,
        merges,
        dropped,
        absorbed,
        ..
    } = sel;

    // (5) assignment.
    let owner = assign(&atoms, &chosen, n);
    let mut zones: Vec<(usize, CoverZone)> = chosen
        .iter()
        .map(|(pose, _)| {
            (
                usize::MAX,
                CoverZone {
                    axis: pose.axis,
                    origin: pose.centre,
                    pieces: Vec::new(),
                },
            )
        })
        .collect();
    let mut j = 0;
    while j < n {
        let z = owner[j];
        let mut piece = atoms[j].piece.clone();
        let mut k = j + 1;
        while k < n && owner[k] == z && atoms[k].contour == atoms[j].contour {
            piece.points.extend_from_slice(&atoms[k].piece.points[1..]);
            piece
                .features
                .extend_from_slice(&atoms[k].piece.features[1..]);
            piece.source.extend_from_slice(&atoms[k].piece.source[1..]);
            k += 1;
        }
        zones[z].0 = zones[z].0.min(j);
        zones[z].1.pieces.push(piece);
        j = k;
    }
    zones.retain(|z| !z.1.pieces.is_empty());
    zones.sort_by_key(|z| z.0);
    let zones: Vec<CoverZone> = zones.into_iter().map(|z| z.1).collect();
    Ok(Cover {
        report: CoverReport {
            atoms: n,
            candidates: candidates.len(),
            greedy_poses,
            poses: zones.len(),
            merges,
            dropped,
            absorbed,
            uncovered_atoms: uncovered.len(),
            lower_bound,
        },
        zones,
    })
}

/// Drops poses every atom of which another chosen pose covers, fewest atoms first.
fn drop_redundant(chosen: &mut Vec<(CoverPose, Vec<usize>)>, n: usize) -> usize {
    let mut count = vec![0usize; n];
    for (_, c) in chosen.iter() {
        for &j in c {
            count[j] += 1;
        }
    }
    let mut order: Vec<usize> = (0..chosen.len()).collect();
    order.sort_by_key(|&i| (chosen[i].1.len(), i));
    let mut keep = vec![true; chosen.len()];
    let mut dropped = 0;
    for i in order {
        if chosen[i].1.iter().all(|&j| count[j] >= 2) {
            for &j in &chosen[i].1 {
                count[j] -= 1;
            }
            keep[i] = false;
            dropped += 1;
        }
    }
    let mut it = keep.iter();
    chosen.retain(|_| *it.next().unwrap_or(&true));
    dropped
}

/// Replaces one pair of chosen poses by one pose covering the atoms only they cover; whether it
/// found one. Pairs are tried closest first.
fn merge_one(
    problem: &CoverProblem<'_>,
    atoms: &[Atom],
    chosen: &mut Vec<(CoverPose, Vec<usize>)>,
    cache: &FitCache,
) -> bool {
    let n = atoms.len();
    let mut count = vec![0usize; n];
    for (_, c) in chosen.iter() {
        for &j in c {
            count[j] += 1;
        }
    }
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for a in 0..chosen.len() {
        for b in a + 1..chosen.len() {
            let (pa, pb) = (&chosen[a].0, &chosen[b].0);
            let angular = angle_rad(&pa.axis, &pb.axis) / problem.limit_rad;
            let uv = pa.in_plane(&pb.centre);
            let radial = len2(uv) / problem.field_radius_mm;
            let d = angular.max(radial);
            if d <= 2.0 * GROW_REACH {
                pairs.push((d, a, b));
            }
        }
    }
    pairs.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.cmp(&q.1)).then(p.2.cmp(&q.2)));
    let tried = |&(_, a, b): &(f64, usize, usize)| {
        // Atoms only a or b covers.
        let mut needed: Vec<usize> = chosen[a]
            .1
            .iter()
            .chain(&chosen[b].1)
            .copied()
            .filter(|&j| {
                let in_a = chosen[a].1.binary_search(&j).is_ok();
                let in_b = chosen[b].1.binary_search(&j).is_ok();
                count[j] == usize::from(in_a) + usize::from(in_b)
            })
            .collect();
        needed.sort_unstable();
        needed.dedup();
        if needed.is_empty() {
            return None;
        }
        let start = UnitVector3::new_normalize(
            chosen[a].0.axis.into_inner() + chosen[b].0.axis.into_inner(),
        );
        cache.fit_atoms(problem, atoms, &needed, Some(&start))
    };
    let Some((i, pose)) = first_in_order(&pairs, tried) else {
        return false;
    };
    let (_, a, b) = pairs[i];
    let covered = problem.coverage(atoms, &pose);
    let (hi, lo) = (a.max(b), a.min(b));
    chosen.remove(hi);
    chosen[lo] = (pose, covered);
    true
}

/// How many chosen poses cover each atom.
fn cover_counts(chosen: &[(CoverPose, Vec<usize>)], n: usize) -> Vec<usize> {
    let mut count = vec![0usize; n];
    for (_, c) in chosen {
        for &j in c {
            count[j] += 1;
        }
    }
    count
}

/// Removes one chosen pose by moving each atom only it covers into a nearby pose refitted to
/// keep its own needed atoms too; whether it found one. Poses with the fewest needed atoms are
/// tried first; the result is checked to cover every atom.
fn absorb_one(
    problem: &CoverProblem<'_>,
    atoms: &[Atom],
    chosen: &mut Vec<(CoverPose, Vec<usize>)>,
    cache: &FitCache,
) -> bool {
    const TRY_POSES: usize = 4;
    let n = atoms.len();
    let count = cover_counts(chosen, n);
    let needed = |q: usize| -> Vec<usize> {
        chosen[q]
            .1
            .iter()
            .copied()
            .filter(|&j| count[j] == 1)
            .collect()
    };
    let mut order: Vec<(usize, usize)> = (0..chosen.len()).map(|p| (needed(p).len(), p)).collect();
    order.sort_unstable();
    let without = |&(_, p): &(usize, usize)| -> Option<Vec<(CoverPose, Vec<usize>)>> {
        let mut sets: std::collections::BTreeMap<usize, (CoverPose, Vec<usize>)> =
            std::collections::BTreeMap::new();
        for j in needed(p) {
            let current = |q: usize| sets.get(&q).map_or(chosen[q].0, |s| s.0);
            let mut qs: Vec<(f64, usize)> = (0..chosen.len())
                .filter(|&q| q != p && problem.radial(&current(q), &atoms[j]) <= GROW_REACH)
                .map(|q| (problem.distance(&current(q), &atoms[j]), q))
                .filter(|(d, _)| *d <= GROW_REACH)
                .collect();
            qs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut placed = false;
            for &(_, q) in qs.iter().take(TRY_POSES) {
                let pose = current(q);
                let mut set = sets.get(&q).map_or_else(|| needed(q), |s| s.1.clone());
                set.push(j);
                if problem.covers_atom(&pose, &atoms[j]) {
                    sets.insert(q, (pose, set));
                    placed = true;
                    break;
                }
                if let Some(next) = cache.fit_atoms(problem, atoms, &set, Some(&pose.axis)) {
                    sets.insert(q, (next, set));
                    placed = true;
                    break;
                }
            }
            if !placed {
                return None;
            }
        }
        let mut next = chosen.clone();
        for (q, (pose, _)) in sets {
            next[q] = (pose, problem.coverage(atoms, &pose));
        }
        next.remove(p);
        cover_counts(&next, n)
            .iter()
            .all(|&c| c > 0)
            .then_some(next)
    };
    match first_in_order(&order, without) {
        Some((_, next)) => {
            *chosen = next;
            true
        }
        None => false,
    }
}

/// Each atom's chosen pose (see the module docs, step 5).
fn assign(atoms: &[Atom], chosen: &[(CoverPose, Vec<usize>)], n: usize) -> Vec<usize> {
    let mut covers: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (z, (_, c)) in chosen.iter().enumerate() {
        for &j in c {
            covers[j].push(z);
        }
    }
    let mut owner = vec![usize::MAX; n];
    let mut j = 0;
    while j < n {
        let c = atoms[j].contour;
        let mut end = j;
        while end < n && atoms[end].contour == c {
            end += 1;
        }
        // Walk the contour: at each atom, the pose covering the longest run from here (the
        // current one if it still covers).
        let mut k = j;
        let mut current: Option<usize> = None;
        while k < end {
            let run = |z: usize| (k..end).take_while(|&i| covers[i].contains(&z)).count();
            let pick = match current {
                Some(z) if covers[k].contains(&z) => z,
                _ => covers[k]
                    .iter()
                    .copied()
                    .max_by(|a, b| run(*a).cmp(&run(*b)).then(b.cmp(a)))
                    .unwrap_or(0),
            };
            owner[k] = pick;
            current = Some(pick);
            k += 1;
        }
        j = end;
    }
    owner
}

/// The lower bound (see the module docs, step 6).
fn lower_bound(
    problem: &CoverProblem<'_>,
    atoms: &[Atom],
    candidates: &[(CoverPose, Vec<usize>)],
) -> usize {
    let n = atoms.len();
    let mut in_candidates: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (i, (_, c)) in candidates.iter().enumerate() {
        for &j in c {
            in_candidates[j].push(i);
        }
    }
    let together = |a: usize, b: usize| {
        let (x, y) = (&in_candidates[a], &in_candidates[b]);
        x.iter().any(|i| y.binary_search(i).is_ok())
    };
    // Atoms in few candidates are the hardest to combine: try them first.
    let mut order: Vec<usize> = (0..n).filter(|&j| !in_candidates[j].is_empty()).collect();
    order.sort_by_key(|&j| (in_candidates[j].len(), j));
    let mut set: Vec<usize> = Vec::new();
    for j in order {
        // The cheap test on every member first, the pair fits only then.
        let independent = !set.iter().any(|&k| together(j, k))
            && set
                .par_iter()
                .all(|&k| problem.fit_atoms(atoms, &[j, k], None).is_none());
        if independent {
            set.push(j);
        }
    }
    set.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_contour_of_astronomical_length_is_refused_not_a_capacity_overflow() {
        // Two points 1e300 mm apart: 1e299 atoms, refused by count instead of allocated; 2e5 mm
        // (20,000 atoms) planned for 3 minutes before the cap was 5,000.
        for far in [1e300, 1e6, 2e5] {
            let piece = Piece {
                contour: 7,
                points: vec![
                    Point3::origin(),
                    Point3::new(1.0, 0.0, 0.0),
                    Point3::new(far, 0.0, 0.0),
                ],
                features: vec![Vector3::z(); 3],
                source: vec![0.0, 1.0, 2.0],
            };
            let e = atomize(&[piece], 5f64.to_radians())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("contour 7:") && e.contains("its point 2") && e.contains("the 5000 "),
                "{e}"
            );
        }
    }
}
