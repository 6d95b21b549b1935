//! The default method: tracks as iso-lines of the geodesic distance from a seed line.
//!
//! The distance is computed by fast marching (Kimmel & Sethian 1998) on the fitted height
//! field's grid, triangulated and lifted onto the surface: each update solves for the value at
//! a triangle's third vertex such that the linear interpolant over the (3D) triangle has a unit
//! gradient, and falls back to an edge (Dijkstra) update where the characteristic would leave
//! the triangle. The seed is the straight line (in plane coordinates) along the hatch direction
//! just outside the boundary; nodes near it start with their local distance to it. Every level
//! set of a distance function lies at geodesic distance `|ΔL|` from the others, so iso-lines at
//! `L₀ + k·pitch` are equally spaced across the surface by construction — unlike the paper's
//! slab method, whose step is measured on a normal section through each point and whose errors
//! accumulate from track to track.
//!
//! Iso-lines are extracted by marching triangles (a crossing belongs to a grid edge, so the
//! segments chain exactly) and clipped to the boundary polygon.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::{Matrix2, Vector2};
use trim_geom::{Point3, Vector3};

use super::polygon::Polygon;
use super::surface::Surface;

/// The seed line passes through the boundary's extreme point against the track-advance
/// direction; nodes behind it and within this many grid spacings ahead of it start with their
/// local (signed) distance to it, so a seed line with gaps in the scan around it still starts
/// a straight front.
const SEED_BAND_CELLS: f64 = 1.5;

/// A piece of an iso-line inside the boundary, plane coordinates (mm), running along the
/// hatch direction.
#[derive(Debug, Clone)]
pub(crate) struct IsoPiece {
    /// The index of the level (0 = nearest the seed).
    pub level: usize,
    /// The points, plane coordinates; the first and last lie on the boundary (or on the edge
    /// of the scanned support).
    pub points: Vec<[f64; 2]>,
}

/// The geodesic distance field over the surface grid (mm; `INFINITY` where not reached).
pub(crate) struct DistanceField {
    d: Vec<f64>,
    nx: usize,
    ny: usize,
}

#[derive(PartialEq)]
struct Entry(f64, usize);
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        // Min-heap on distance, ties by index (deterministic).
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

/// The two other vertices of each of the (up to six) grid triangles around node `(i, j)`.
/// Cells are split along the diagonal `(i, j)`–`(i+1, j+1)`.
fn triangles_around(i: usize, j: usize, nx: usize, ny: usize) -> Vec<(usize, usize)> {
    let (i, j, nx, ny) = (i as isize, j as isize, nx as isize, ny as isize);
    let id = |a: isize, b: isize| -> Option<usize> {
        (a >= 0 && b >= 0 && a < nx && b < ny).then(|| (b * nx + a) as usize)
    };
    let candidates = [
        // cell (i, j): T1 (i,j)(i+1,j)(i+1,j+1), T2 (i,j)(i+1,j+1)(i,j+1)
        ((i + 1, j), (i + 1, j + 1)),
        ((i + 1, j + 1), (i, j + 1)),
        // cell (i-1, j): T2 has (i-1,j)(i,j+1)(i-1,j+1)... node (i,j) is its (i+1, j) corner: T1
        ((i - 1, j), (i, j + 1)),
        // cell (i-1, j-1): node is the (i+1, j+1) corner of both triangles
        ((i - 1, j - 1), (i, j - 1)),
        ((i - 1, j - 1), (i - 1, j)),
        // cell (i, j-1): node is the (i, j+1) corner of T2
        ((i, j - 1), (i + 1, j)),
    ];
    candidates
        .iter()
        .filter_map(|&((a, b), (c, d))| Some((id(a, b)?, id(c, d)?)))
        .collect()
}

/// The value at `c` from known values at `a` and `b` on the triangle `a b c` (3D), or `None`
/// when the characteristic does not pass through the triangle.
fn triangle_update(c: &Point3, a: &Point3, da: f64, b: &Point3, db: f64) -> Option<f64> {
    let ea: Vector3 = a - c;
    let eb: Vector3 = b - c;
    let g = Matrix2::new(ea.dot(&ea), ea.dot(&eb), ea.dot(&eb), eb.dot(&eb));
    let q = g.try_inverse()?;
    let one = Vector2::new(1.0, 1.0);
    let w = Vector2::new(da, db);
    let qa = one.dot(&(q * one));
    let qb = one.dot(&(q * w));
    let qc = w.dot(&(q * w)) - 1.0;
    let disc = qb * qb - qa * qc;
    if disc < 0.0 || qa <= 0.0 {
        return None;
    }
    let d = (qb + disc.sqrt()) / qa;
    let delta = w - one * d;
    let coef = q * delta;
    (d >= da.max(db) && coef[0] <= 1e-12 && coef[1] <= 1e-12).then_some(d)
}

impl DistanceField {
    /// Fast marching from the seed line `across·st = c0` (plane coordinates), outward toward
    /// increasing `across·st`; values behind the line are negative.
    pub(crate) fn compute(surface: &Surface, across: [f64; 2], c0: f64) -> DistanceField {
        let (nx, ny) = surface.grid_size();
        let h = surface.grid_mm();
        let n = nx * ny;
        let pos: Vec<Option<Point3>> = (0..n).map(|k| surface.node_point(k % nx, k / nx)).collect();
        let mut d = vec![f64::INFINITY; n];
        let mut known = vec![false; n];
        let mut heap = BinaryHeap::new();
        let band = SEED_BAND_CELLS * h;
        for k in 0..n {
            if pos[k].is_none() {
                known[k] = true; // no support: never updated
                continue;
            }
            let st = surface.node_st(k % nx, k / nx);
            let c = st[0] * across[0] + st[1] * across[1];
            if c <= c0 + band {
                // Local distance to the line: (c − c0) / |∇c| in the surface metric,
                // |∇c|² = aᵀ g⁻¹ a with g⁻¹ = I − ∇f ∇fᵀ / (1 + |∇f|²).
                let grad = surface.height_gradient(st).map_or([0.0; 2], |(_, g)| g);
                let ga = grad[0] * across[0] + grad[1] * across[1];
                let g2 = grad[0] * grad[0] + grad[1] * grad[1];
                let norm = (1.0 - ga * ga / (1.0 + g2)).max(1e-12).sqrt();
                d[k] = (c - c0) / norm;
                known[k] = true;
                heap.push(Entry(d[k], k));
            }
        }
        // Known seeds propagate to their neighbours first.
        let seeds: Vec<usize> = heap.drain().map(|e| e.1).collect();
        let mut heap = BinaryHeap::new();
        let relax =
            |k: usize, d: &mut Vec<f64>, known: &Vec<bool>, heap: &mut BinaryHeap<Entry>| {
                let (i, j) = (k % nx, k / nx);
                let Some(pk) = pos[k] else { return };
                for (a, b) in triangles_around(i, j, nx, ny) {
                    for (y, z) in [(a, b), (b, a)] {
                        if known[y] {
                            continue;
                        }
                        let Some(py) = pos[y] else { continue };
                        let mut best = d[k] + (py - pk).norm();
                        if known[z]
                            && d[z].is_finite()
                            && let Some(pz) = pos[z]
                        {
                            if let Some(t) = triangle_update(&py, &pk, d[k], &pz, d[z]) {
                                best = best.min(t);
                            } else {
                                best = best.min(d[z] + (py - pz).norm());
                            }
                        }
                        if best < d[y] {
                            d[y] = best;
                            heap.push(Entry(best, y));
                        }
                    }
                }
            };
        for k in seeds {
            relax(k, &mut d, &known, &mut heap);
        }
        while let Some(Entry(v, k)) = heap.pop() {
            if known[k] || v > d[k] {
                continue;
            }
            known[k] = true;
            relax(k, &mut d, &known, &mut heap);
        }
        DistanceField { d, nx, ny }
    }

    /// The distance at plane coordinates `st`, interpolated linearly on the grid triangle.
    pub(crate) fn at(&self, surface: &Surface, st: [f64; 2]) -> Option<f64> {
        let h = surface.grid_mm();
        let o = surface.node_st(0, 0);
        let gx = (st[0] - o[0]) / h;
        let gy = (st[1] - o[1]) / h;
        if !(gx >= 0.0 && gy >= 0.0) {
            return None;
        }
        let i = (gx.floor() as usize).min(self.nx - 2);
        let j = (gy.floor() as usize).min(self.ny - 2);
        let (fx, fy) = (gx - i as f64, gy - j as f64);
        if fx > 1.0 + 1e-9 || fy > 1.0 + 1e-9 {
            return None;
        }
        let v = |a: usize, b: usize| self.d[b * self.nx + a];
        let (d00, d11) = (v(i, j), v(i + 1, j + 1));
        let value = if fx >= fy {
            let d10 = v(i + 1, j);
            d00 + fx * (d10 - d00) + fy * (d11 - d10)
        } else {
            let d01 = v(i, j + 1);
            d00 + fy * (d01 - d00) + fx * (d11 - d01)
        };
        value.is_finite().then_some(value)
    }

    /// The iso-lines at `levels` (ascending), chained into polylines (plane coordinates).
    pub(crate) fn iso_lines(
        &self,
        surface: &Surface,
        levels: &[f64],
    ) -> Vec<(usize, Vec<[f64; 2]>)> {
        let (nx, ny) = (self.nx, self.ny);
        let nl = levels.len() as u64;
        if nl == 0 || nx < 2 || ny < 2 {
            return Vec::new();
        }
        let key = |edge: u64, level: usize| edge * nl + level as u64;
        let mut points: HashMap<u64, [f64; 2], Fast> = HashMap::default();
        let mut links: HashMap<u64, [u64; 2], Fast> = HashMap::default();
        let mut link = |a: u64, b: u64| {
            for (x, y) in [(a, b), (b, a)] {
                let e = links.entry(x).or_insert([u64::MAX; 2]);
                if e[0] == u64::MAX {
                    e[0] = y;
                } else {
                    e[1] = y;
                }
            }
        };
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let k00 = j * nx + i;
                let (k10, k01, k11) = (k00 + 1, k00 + nx, k00 + nx + 1);
                // Edges: horizontal 3k, vertical 3k+1, diagonal 3k+2 (k its lower-left node).
                let e_bottom = 3 * k00 as u64;
                let e_right = 3 * k10 as u64 + 1;
                let e_diag = 3 * k00 as u64 + 2;
                let e_top = 3 * k01 as u64;
                let e_left = 3 * k00 as u64 + 1;
                let tris = [
                    [
                        (k00, k10, e_bottom),
                        (k10, k11, e_right),
                        (k11, k00, e_diag),
                    ],
                    [(k00, k11, e_diag), (k11, k01, e_top), (k01, k00, e_left)],
                ];
                for tri in tris {
                    let ds = [self.d[tri[0].0], self.d[tri[1].0], self.d[tri[2].0]];
                    if !ds.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    let lo = ds.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi = ds.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    let first = levels.partition_point(|&l| l <= lo);
                    for (li, &level) in levels.iter().enumerate().skip(first) {
                        if level > hi {
                            break;
                        }
                        let mut ends = [0u64; 2];
                        let mut n_ends = 0;
                        for &(a, b, e) in &tri {
                            let (da, db) = (self.d[a], self.d[b]);
                            if (da >= level) != (db >= level) && n_ends < 2 {
                                let u = (level - da) / (db - da);
                                let (pa, pb) = (
                                    surface.node_st(a % nx, a / nx),
                                    surface.node_st(b % nx, b / nx),
                                );
                                let kk = key(e, li);
                                points.entry(kk).or_insert([
                                    pa[0] + u * (pb[0] - pa[0]),
                                    pa[1] + u * (pb[1] - pa[1]),
                                ]);
                                ends[n_ends] = kk;
                                n_ends += 1;
                            }
                        }
                        if n_ends == 2 {
                            link(ends[0], ends[1]);
                        }
                    }
                }
            }
        }
        // Chain: open chains from their ends first, then closed loops. Sorted starts keep the
        // result independent of hash order.
        let mut starts: Vec<u64> = links
            .iter()
            .filter(|(_, v)| v[1] == u64::MAX)
            .map(|(k, _)| *k)
            .collect();
        starts.sort_unstable();
        let mut rest: Vec<u64> = links.keys().copied().collect();
        rest.sort_unstable();
        starts.extend(rest);
        let mut visited: HashMap<u64, (), Fast> = HashMap::default();
        let mut out = Vec::new();
        for s in starts {
            if visited.contains_key(&s) {
                continue;
            }
            let mut chain = Vec::new();
            let (mut prev, mut cur) = (u64::MAX, s);
            loop {
                visited.insert(cur, ());
                if let Some(p) = points.get(&cur) {
                    chain.push(*p);
                }
                let Some(next) = links.get(&cur) else { break };
                let n = if next[0] != prev && !visited.contains_key(&next[0]) {
                    next[0]
                } else if next[1] != u64::MAX && next[1] != prev && !visited.contains_key(&next[1])
                {
                    next[1]
                } else {
                    // Close a loop back onto its start.
                    if next.contains(&s)
                        && chain.len() > 2
                        && let Some(p) = points.get(&s)
                    {
                        chain.push(*p);
                    }
                    break;
                };
                prev = cur;
                cur = n;
            }
            if chain.len() >= 2 {
                out.push(((s % nl) as usize, chain));
            }
        }
        out
    }
}

/// Clips a polyline to the polygon: the pieces inside, with exact crossing points as ends.
pub(crate) fn clip(polygon: &Polygon, line: &[[f64; 2]]) -> Vec<Vec<[f64; 2]>> {
    let mut pieces = Vec::new();
    let Some(first) = line.first() else {
        return pieces;
    };
    let mut inside = polygon.contains(*first);
    let mut current: Vec<[f64; 2]> = if inside { vec![*first] } else { Vec::new() };
    for w in line.windows(2) {
        let (a, b) = (w[0], w[1]);
        for u in polygon.crossings(a, b) {
            let p = [a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])];
            current.push(p);
            if inside {
                pieces.push(std::mem::take(&mut current));
            } else {
                current = vec![p];
            }
            inside = !inside;
        }
        if inside {
            current.push(b);
        }
    }
    if inside && current.len() >= 2 {
        pieces.push(current);
    }
    pieces.retain(|p| {
        p.len() >= 2
            && p.windows(2)
                .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
                .sum::<f64>()
                > 1e-9
    });
    pieces
}

/// The seed offset `c0` for a polygon: its extreme point against `across`.
pub(crate) fn seed_offset(polygon: &Polygon, across: [f64; 2]) -> f64 {
    polygon
        .vertices()
        .iter()
        .map(|v| v[0] * across[0] + v[1] * across[1])
        .fold(f64::INFINITY, f64::min)
}

/// A multiply-shift hasher for `u64` keys (the std SipHash is needlessly slow here).
#[derive(Default)]
pub(crate) struct FastHasher(u64);

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (v ^ (v >> 29)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }
}

type Fast = BuildHasherDefault<FastHasher>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_update_is_exact_for_a_plane_wave() {
        // Plane wave along +x: d = x.
        let a = Point3::new(0.0, 0.0, 0.0);
        let b = Point3::new(0.0, 1.0, 0.0);
        let c = Point3::new(1.0, 0.5, 0.0);
        let d = triangle_update(&c, &a, 0.0, &b, 0.0).unwrap();
        assert!((d - 1.0).abs() < 1e-12);
        // Oblique wave d = (x + y)/√2 on a right triangle.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let c = Point3::new(1.0, 1.0, 0.0);
        let a = Point3::new(1.0, 0.0, 0.0);
        let b = Point3::new(0.0, 1.0, 0.0);
        let d = triangle_update(&c, &a, s, &b, s).unwrap();
        assert!((d - 2.0 * s).abs() < 1e-12);
    }
}
