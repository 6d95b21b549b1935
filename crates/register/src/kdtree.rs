//! A static 3-D kd-tree for registration's queries: the nearest point and the `k` nearest points
//! *within a maximum distance*, optionally warm-started from a known candidate.
//!
//! Registration asks almost only bounded questions ("the nearest target point, if within
//! `d_max`"), and from one ICP iteration to the next each query moves little. A bounded search
//! prunes every cell farther than `d_max` (or than a warm-start candidate) from the start, which
//! an unbounded nearest-neighbour search followed by a distance filter cannot.
//!
//! Answers are exact and unique: among the points within the bound, the least `(d², index)`
//! (lexicographic), so ties between equidistant points go to the lower index whatever the search
//! order, the warm start or the thread count. Cells are pruned with the incremental distance to
//! the cell (Arya & Mount 1993), and the tree is balanced by median splits on the widest axis
//! with a fixed rule, so the build is deterministic too.

use trim_geom::Point3;

/// Points per leaf.
const LEAF: usize = 12;

/// Subtrees at least this large are built in parallel.
const PARALLEL_BUILD: usize = 4096;

/// One answer: the index of the point in the slice the tree was built from and the squared
/// distance to it (squared length unit of the points, mm² for CAD and scans).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Index into the points the tree was built from.
    pub index: usize,
    /// Squared Euclidean distance.
    pub distance_sq: f64,
}

/// A kd-tree over a slice of finite points. The tree shape is implicit: the node covering
/// `[lo, hi)` of the reordered points splits at `mid = (lo + hi) / 2`, its children are `2k` and
/// `2k + 1` (root `1`), and ranges of at most [`LEAF`] points are leaves.
#[derive(Clone)]
pub struct KdTree {
    /// The points' coordinates by axis (x, y, z), reordered so that every node's points are
    /// contiguous; by axis so that a leaf's distances vectorise.
    coords: [Vec<f64>; 3],
    /// `index[i]`: the caller's index of `points[i]`.
    index: Vec<u32>,
    /// Per node: the split axis.
    axis: Vec<u8>,
    /// Per node: the split coordinate (left points ≤ it ≤ right points along `axis`).
    split: Vec<f64>,
}

impl std::fmt::Debug for KdTree {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdTree")
            .field("len", &self.index.len())
            .finish()
    }
}

fn node_slots(n: usize) -> usize {
    // Depth of the implicit tree: halve until a range fits a leaf.
    let mut slots = 2;
    let mut size = n;
    while size > LEAF {
        size = size.div_ceil(2);
        slots *= 2;
    }
    slots
}

#[inline]
fn dist_sq(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

/// Whether `(d, i)` precedes `(best_d, best_i)` lexicographically.
#[inline]
fn better(d: f64, i: u32, best_d: f64, best_i: u32) -> bool {
    d < best_d || (d == best_d && i < best_i)
}

impl KdTree {
    /// Builds the tree (median splits, in parallel for large clouds; the same tree on any number
    /// of threads).
    ///
    /// # Panics
    /// Never for fewer than 2³² points; larger clouds do not fit the `u32` indices.
    #[must_use]
    pub fn build(points: &[Point3]) -> KdTree {
        assert!(
            u32::try_from(points.len()).is_ok(),
            "kd-tree supports at most 2^32 points"
        );
        let mut items: Vec<([f64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| ([p.x, p.y, p.z], i as u32))
            .collect();
        let slots = node_slots(items.len());
        let mut axis = vec![0u8; slots];
        let mut split = vec![0.0; slots];
        let mut nodes = Vec::new();
        build_node(&mut items, 1, &mut nodes);
        for (k, a, s) in nodes {
            axis[k] = a;
            split[k] = s;
        }
        let coords = [0, 1, 2].map(|a| items.iter().map(|(p, _)| p[a]).collect());
        let index = items.iter().map(|&(_, i)| i).collect();
        KdTree {
            coords,
            index,
            axis,
            split,
        }
    }

    /// The number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether the tree holds no point.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The nearest point within `max_distance_sq` (inclusive) of `query`, if any.
    #[must_use]
    pub fn nearest_within(&self, query: &Point3, max_distance_sq: f64) -> Option<Neighbour> {
        self.nearest_from(query, max_distance_sq, None, &mut Scratch::default())
    }

    /// As [`KdTree::nearest_within`], starting from the candidate `hint` (an index into the
    /// points the tree was built from, and that point, e.g. the previous ICP iteration's match):
    /// when it lies within the bound, only cells nearer than it are searched. The answer does
    /// not depend on the hint. `scratch` is reused across queries (one per thread).
    #[must_use]
    pub fn nearest_from(
        &self,
        query: &Point3,
        max_distance_sq: f64,
        hint: Option<(usize, &Point3)>,
        scratch: &mut Scratch,
    ) -> Option<Neighbour> {
        if self.index.is_empty() || max_distance_sq.is_nan() || max_distance_sq < 0.0 {
            return None;
        }
        let q = [query.x, query.y, query.z];
        let mut best = Nearest {
            distance_sq: max_distance_sq,
            index: u32::MAX,
        };
        if let Some((i, p)) = hint {
            let d = dist_sq(&q, &[p.x, p.y, p.z]);
            if let Ok(i) = u32::try_from(i)
                && d <= max_distance_sq
            {
                best = Nearest {
                    distance_sq: d,
                    index: i,
                };
            }
        }
        self.search(&q, &mut best, &mut scratch.stack);
        (best.index != u32::MAX).then_some(Neighbour {
            index: best.index as usize,
            distance_sq: best.distance_sq,
        })
    }

    /// The `k` nearest points within `max_distance_sq` (inclusive) of `query`, nearest first
    /// (ties by index); fewer than `k` if fewer lie within the bound. The answer lives in
    /// `scratch`, which is reused across queries (one per thread).
    pub fn knn_within<'s>(
        &self,
        query: &Point3,
        k: usize,
        max_distance_sq: f64,
        scratch: &'s mut Scratch,
    ) -> &'s [Neighbour] {
        scratch.found.clear();
        if k == 0 || self.index.is_empty() || max_distance_sq.is_nan() || max_distance_sq < 0.0 {
            return &scratch.found;
        }
        let q = [query.x, query.y, query.z];
        let mut found = Nearests {
            k,
            bound: max_distance_sq,
            found: &mut scratch.found,
        };
        self.search(&q, &mut found, &mut scratch.stack);
        &scratch.found
    }

    /// Whether any point lies within `max_distance_sq` (inclusive) of `query`: the answer of
    /// `nearest_within(..).is_some()`, but the search stops at the first point found instead of
    /// looking on for a nearer one (a coverage test asks no more).
    pub fn any_within(&self, query: &Point3, max_distance_sq: f64, scratch: &mut Scratch) -> bool {
        if self.index.is_empty() || max_distance_sq.is_nan() || max_distance_sq < 0.0 {
            return false;
        }
        let q = [query.x, query.y, query.z];
        let mut any = Any {
            max_distance_sq,
            found: false,
        };
        self.search(&q, &mut any, &mut scratch.stack);
        any.found
    }

    /// Every point within `max_distance_sq` (inclusive) of `query`, in no particular order
    /// (for gathering a neighbourhood, where [`KdTree::knn_within`]'s sorted insert would cost
    /// the square of its size). The answer lives in `scratch`.
    pub fn within<'s>(
        &self,
        query: &Point3,
        max_distance_sq: f64,
        scratch: &'s mut Scratch,
    ) -> &'s [Neighbour] {
        scratch.found.clear();
        if self.index.is_empty() || max_distance_sq.is_nan() || max_distance_sq < 0.0 {
            return &scratch.found;
        }
        let q = [query.x, query.y, query.z];
        let mut all = Within {
            max_distance_sq,
            found: &mut scratch.found,
        };
        self.search(&q, &mut all, &mut scratch.stack);
        &scratch.found
    }

    /// Depth-first search: descend to the query's leaf, stacking the far children whose cells
    /// (incremental distance, Arya & Mount 1993) lie within the visitor's bound; then the stacked
    /// cells still within the (shrunk) bound.
    fn search<V: Visitor>(&self, q: &[f64; 3], visitor: &mut V, stack: &mut Vec<Cell>) {
        stack.clear();
        stack.push(Cell {
            node: 1,
            lo: 0,
            // At most 2³² − 1 points (see `build`).
            hi: self.index.len() as u32,
            distance_sq: 0.0,
            offset: [0.0; 3],
        });
        while let Some(cell) = stack.pop() {
            let Cell {
                node,
                lo,
                hi,
                distance_sq,
                offset,
            } = cell;
            let (mut node, mut lo, mut hi) = (node as usize, lo as usize, hi as usize);
            if distance_sq > visitor.bound() {
                continue;
            }
            while hi - lo > LEAF {
                let mid = (lo + hi) / 2;
                let a = usize::from(self.axis[node]);
                let diff = q[a] - self.split[node];
                let far_sq = distance_sq - offset[a] * offset[a] + diff * diff;
                let (near, far) = if diff < 0.0 {
                    ((2 * node, lo, mid), (2 * node + 1, mid, hi))
                } else {
                    ((2 * node + 1, mid, hi), (2 * node, lo, mid))
                };
                if far_sq <= visitor.bound() {
                    let mut far_offset = offset;
                    far_offset[a] = diff;
                    stack.push(Cell {
                        node: far.0 as u32,
                        lo: far.1 as u32,
                        hi: far.2 as u32,
                        distance_sq: far_sq,
                        offset: far_offset,
                    });
                }
                (node, lo, hi) = near;
            }
            let mut d = [0.0; LEAF];
            let n = self.leaf_distances(q, lo, hi, &mut d);
            visitor.visit(&d[..n], &self.index[lo..hi]);
            if visitor.done() {
                return;
            }
        }
    }

    /// The squared distances from `q` to the leaf `[lo, hi)`'s points into `out`; returns their
    /// number.
    #[inline]
    fn leaf_distances(&self, q: &[f64; 3], lo: usize, hi: usize, out: &mut [f64; LEAF]) -> usize {
        let n = (hi - lo).min(LEAF);
        let (xs, ys, zs) = (
            &self.coords[0][lo..lo + n],
            &self.coords[1][lo..lo + n],
            &self.coords[2][lo..lo + n],
        );
        for k in 0..n {
            let (dx, dy, dz) = (xs[k] - q[0], ys[k] - q[1], zs[k] - q[2]);
            out[k] = dx * dx + dy * dy + dz * dz;
        }
        n
    }
}

/// Per-thread buffers of the queries: the stack of pending cells and the k-NN answer.
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    stack: Vec<Cell>,
    found: Vec<Neighbour>,
}

/// A pending cell of [`KdTree::search`]: node, point range, squared distance from the query to
/// the cell, and the per-axis offsets that make it up.
#[derive(Debug, Clone, Copy)]
struct Cell {
    node: u32,
    lo: u32,
    hi: u32,
    distance_sq: f64,
    offset: [f64; 3],
}

/// What a search collects: it reads leaves' distances and says how far to look.
trait Visitor {
    /// Cells farther than this (squared) are skipped; equal ones are searched (ties).
    fn bound(&self) -> f64;
    /// A leaf's squared distances and point indices.
    fn visit(&mut self, distance_sq: &[f64], index: &[u32]);
    /// Whether the answer is known: the search stops.
    #[inline]
    fn done(&self) -> bool {
        false
    }
}

/// Whether any point lies within the bound.
struct Any {
    max_distance_sq: f64,
    found: bool,
}

impl Visitor for Any {
    #[inline]
    fn bound(&self) -> f64 {
        self.max_distance_sq
    }

    #[inline]
    fn visit(&mut self, distance_sq: &[f64], _index: &[u32]) {
        self.found = self.found || distance_sq.iter().any(|&d| d <= self.max_distance_sq);
    }

    #[inline]
    fn done(&self) -> bool {
        self.found
    }
}

/// The least `(d², index)` within the bound (`index == u32::MAX`: none yet).
struct Nearest {
    distance_sq: f64,
    index: u32,
}

impl Visitor for Nearest {
    #[inline]
    fn bound(&self) -> f64 {
        self.distance_sq
    }

    #[inline]
    fn visit(&mut self, distance_sq: &[f64], index: &[u32]) {
        for (&d, &i) in distance_sq.iter().zip(index) {
            if d <= self.distance_sq && better(d, i, self.distance_sq, self.index) {
                self.distance_sq = d;
                self.index = i;
            }
        }
    }
}

/// The `k` least `(d², index)` within the bound, sorted.
struct Nearests<'a> {
    k: usize,
    /// The search's bound: the maximum distance until `k` are found, then the `k`-th's
    /// distance (kept here, not read from `found`: every cell and point is tested against it).
    bound: f64,
    found: &'a mut Vec<Neighbour>,
}

impl Visitor for Nearests<'_> {
    #[inline]
    fn bound(&self) -> f64 {
        self.bound
    }

    #[inline]
    fn visit(&mut self, distance_sq: &[f64], index: &[u32]) {
        for (&d, &i) in distance_sq.iter().zip(index) {
            // Beyond the bound: neither within the maximum distance nor better than the k-th.
            if d > self.bound {
                continue;
            }
            if self.found.len() == self.k {
                let worst = self.found[self.k - 1];
                if !better(d, i, worst.distance_sq, worst.index as u32) {
                    continue;
                }
                self.found.pop();
            }
            // Sorted insert (k is small).
            let at = self
                .found
                .iter()
                .position(|f| better(d, i, f.distance_sq, f.index as u32))
                .unwrap_or(self.found.len());
            self.found.insert(
                at,
                Neighbour {
                    index: i as usize,
                    distance_sq: d,
                },
            );
            if self.found.len() == self.k {
                self.bound = self.found[self.k - 1].distance_sq;
            }
        }
    }
}

/// Every point within the bound, unordered.
struct Within<'a> {
    max_distance_sq: f64,
    found: &'a mut Vec<Neighbour>,
}

impl Visitor for Within<'_> {
    #[inline]
    fn bound(&self) -> f64 {
        self.max_distance_sq
    }

    fn visit(&mut self, distance_sq: &[f64], index: &[u32]) {
        for (&d, &i) in distance_sq.iter().zip(index) {
            if d <= self.max_distance_sq {
                self.found.push(Neighbour {
                    index: i as usize,
                    distance_sq: d,
                });
            }
        }
    }
}

/// Splits `items` (the node `node`'s range) at its median along the widest axis, recursively;
/// records `(node, axis, split)`.
fn build_node(items: &mut [([f64; 3], u32)], node: usize, out: &mut Vec<(usize, u8, f64)>) {
    let n = items.len();
    if n <= LEAF {
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (p, _) in items.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let mut axis = 0;
    for a in 1..3 {
        if hi[a] - lo[a] > hi[axis] - lo[axis] {
            axis = a;
        }
    }
    let mid = n / 2;
    // Deterministic: the selection's result depends only on the input order, itself fixed.
    items.select_nth_unstable_by(mid, |x, y| x.0[axis].total_cmp(&y.0[axis]));
    out.push((node, axis as u8, items[mid].0[axis]));
    let (left, right) = items.split_at_mut(mid);
    if n >= PARALLEL_BUILD {
        let (mut l_out, mut r_out) = (Vec::new(), Vec::new());
        rayon::join(
            || build_node(left, 2 * node, &mut l_out),
            || build_node(right, 2 * node + 1, &mut r_out),
        );
        out.extend(l_out);
        out.extend(r_out);
    } else {
        build_node(left, 2 * node, out);
        build_node(right, 2 * node + 1, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn cloud(n: usize, seed: u64) -> Vec<Point3> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                // Rounded coordinates: many exact distance ties.
                Point3::new(
                    (rng.random_range(-50.0f64..50.0) * 4.0).round() / 4.0,
                    (rng.random_range(-50.0f64..50.0) * 4.0).round() / 4.0,
                    (rng.random_range(-5.0f64..5.0) * 4.0).round() / 4.0,
                )
            })
            .collect()
    }

    fn brute(points: &[Point3], q: &Point3, max_sq: f64) -> Vec<(f64, usize)> {
        let qa = [q.x, q.y, q.z];
        let mut d: Vec<(f64, usize)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (dist_sq(&qa, &[p.x, p.y, p.z]), i))
            .filter(|&(d, _)| d <= max_sq)
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        d
    }

    #[test]
    fn matches_brute_force_with_ties_and_hints() {
        let points = cloud(3000, 7);
        let tree = KdTree::build(&points);
        assert_eq!(tree.len(), 3000);
        let queries = cloud(400, 8);
        let mut scratch = Scratch::default();
        for (n, q) in queries.iter().enumerate() {
            for max_sq in [0.0, 0.3, 4.0, 1e9] {
                let truth = brute(&points, q, max_sq);
                let got = tree.nearest_within(q, max_sq);
                assert_eq!(
                    got.map(|g| (g.distance_sq, g.index)),
                    truth.first().copied()
                );
                // Any hint gives the same answer.
                let h = (n * 7) % points.len();
                let hinted = tree.nearest_from(q, max_sq, Some((h, &points[h])), &mut scratch);
                assert_eq!(hinted, got);
                for k in [1, 6, 11] {
                    let out = tree.knn_within(q, k, max_sq, &mut scratch);
                    let want: Vec<(f64, usize)> = truth.iter().take(k).copied().collect();
                    let have: Vec<(f64, usize)> =
                        out.iter().map(|g| (g.distance_sq, g.index)).collect();
                    assert_eq!(have, want);
                }
                // Whether there is any: the same as whether there is a nearest.
                assert_eq!(tree.any_within(q, max_sq, &mut scratch), !truth.is_empty());
                // The whole neighbourhood, unordered: the same set.
                let mut all: Vec<(f64, usize)> = tree
                    .within(q, max_sq, &mut scratch)
                    .iter()
                    .map(|g| (g.distance_sq, g.index))
                    .collect();
                all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                assert_eq!(all, truth);
            }
        }
    }

    #[test]
    fn empty_and_tiny_trees() {
        let empty = KdTree::build(&[]);
        assert!(empty.is_empty());
        assert!(empty.nearest_within(&Point3::origin(), 1.0).is_none());
        let one = KdTree::build(&[Point3::new(1.0, 0.0, 0.0)]);
        assert_eq!(
            one.nearest_within(&Point3::origin(), 1.0).map(|n| n.index),
            Some(0)
        );
        assert!(one.nearest_within(&Point3::origin(), 0.5).is_none());
        assert!(one.nearest_within(&Point3::origin(), f64::NAN).is_none());
        let mut scratch = Scratch::default();
        assert!(!empty.any_within(&Point3::origin(), 1.0, &mut scratch));
        assert!(one.any_within(&Point3::origin(), 1.0, &mut scratch));
        assert!(!one.any_within(&Point3::origin(), 0.5, &mut scratch));
        assert!(!one.any_within(&Point3::origin(), f64::NAN, &mut scratch));
        assert!(
            empty
                .within(&Point3::origin(), 1.0, &mut scratch)
                .is_empty()
        );
        assert!(
            one.within(&Point3::origin(), f64::NAN, &mut scratch)
                .is_empty()
        );
        assert_eq!(one.within(&Point3::origin(), 1.0, &mut scratch).len(), 1);
    }

    #[test]
    fn same_tree_on_one_and_many_threads() {
        let points = cloud(40_000, 3);
        let many = KdTree::build(&points);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| KdTree::build(&points));
        assert_eq!(many.index, one.index);
        assert_eq!(many.axis, one.axis);
        assert_eq!(
            many.split.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            one.split.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}
