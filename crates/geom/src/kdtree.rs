//! A static kd-tree over 3D points on kiddo: nearest, k nearest and radius queries.

use std::num::NonZero;

use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;

use crate::math::Point3;

/// Points per leaf bucket.
const BUCKET: usize = 32;

/// One query result: the index of the point in the slice the tree was built from, and the
/// squared distance to it (mm²).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Index into the points the tree was built from.
    pub index: usize,
    /// Squared Euclidean distance, mm².
    pub distance_sq: f64,
}

/// A kd-tree built once over a slice of points. Queries never panic: an empty tree answers
/// `None` or an empty list.
pub struct KdTree {
    tree: Option<ImmutableKdTree<f64, u32, 3, BUCKET>>,
    len: usize,
}

impl std::fmt::Debug for KdTree {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdTree").field("len", &self.len).finish()
    }
}

impl KdTree {
    /// Builds the tree. Points must be finite (as every [`crate::PointCloud`]'s are).
    ///
    /// # Panics
    /// Never for clouds of fewer than 2³² points; larger ones do not fit the `u32` indices.
    #[must_use]
    pub fn build(points: &[Point3]) -> KdTree {
        assert!(
            u32::try_from(points.len()).is_ok(),
            "kd-tree supports at most 2^32 points"
        );
        if points.is_empty() {
            return KdTree { tree: None, len: 0 };
        }
        let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        KdTree {
            tree: Some(ImmutableKdTree::new_from_slice(&coords)),
            len: points.len(),
        }
    }

    /// The number of points in the tree.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the tree is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The nearest point to `query`.
    #[must_use]
    pub fn nearest(&self, query: &Point3) -> Option<Neighbour> {
        let tree = self.tree.as_ref()?;
        let n = tree.nearest_one::<SquaredEuclidean>(&[query.x, query.y, query.z]);
        Some(Neighbour {
            index: n.item as usize,
            distance_sq: n.distance,
        })
    }

    /// The `k` nearest points, closest first (fewer if the tree holds fewer).
    #[must_use]
    pub fn knn(&self, query: &Point3, k: usize) -> Vec<Neighbour> {
        let (Some(tree), Some(k)) = (self.tree.as_ref(), NonZero::new(k)) else {
            return Vec::new();
        };
        tree.nearest_n::<SquaredEuclidean>(&[query.x, query.y, query.z], k)
            .into_iter()
            .map(|n| Neighbour {
                index: n.item as usize,
                distance_sq: n.distance,
            })
            .collect()
    }

    /// Every point within `radius_mm` of `query` (inclusive), closest first.
    #[must_use]
    pub fn within_radius(&self, query: &Point3, radius_mm: f64) -> Vec<Neighbour> {
        let mut found = self.within_radius_unsorted(query, radius_mm);
        found.sort_by(|a, b| {
            a.distance_sq
                .total_cmp(&b.distance_sq)
                .then(a.index.cmp(&b.index))
        });
        found
    }

    /// Every point within `radius_mm` of `query` (inclusive), in no particular order.
    #[must_use]
    pub fn within_radius_unsorted(&self, query: &Point3, radius_mm: f64) -> Vec<Neighbour> {
        let Some(tree) = self.tree.as_ref() else {
            return Vec::new();
        };
        if radius_mm.is_nan() || radius_mm < 0.0 {
            return Vec::new();
        }
        tree.within_unsorted::<SquaredEuclidean>(
            &[query.x, query.y, query.z],
            radius_mm * radius_mm,
        )
        .into_iter()
        .map(|n| Neighbour {
            index: n.item as usize,
            distance_sq: n.distance,
        })
        .collect()
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
                Point3::new(
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-5.0..5.0),
                )
            })
            .collect()
    }

    fn brute_sorted(points: &[Point3], q: &Point3) -> Vec<(f64, usize)> {
        let mut d: Vec<(f64, usize)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| ((p - q).norm_squared(), i))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        d
    }

    #[test]
    fn matches_brute_force() {
        let points = cloud(5000, 1);
        let tree = KdTree::build(&points);
        for q in cloud(200, 2) {
            let brute = brute_sorted(&points, &q);
            let n = tree.nearest(&q).unwrap();
            assert_eq!(n.distance_sq, brute[0].0);
            let k = tree.knn(&q, 8);
            let kd: Vec<f64> = k.iter().map(|n| n.distance_sq).collect();
            let bd: Vec<f64> = brute[..8].iter().map(|b| b.0).collect();
            assert_eq!(kd, bd);
            let r = tree.within_radius(&q, 3.0);
            let expected = brute.iter().filter(|b| b.0 <= 9.0).count();
            assert_eq!(r.len(), expected);
        }
    }

    #[test]
    fn empty_and_duplicates_do_not_panic() {
        let empty = KdTree::build(&[]);
        assert!(empty.nearest(&Point3::origin()).is_none());
        assert!(empty.knn(&Point3::origin(), 3).is_empty());
        let dup = KdTree::build(&vec![Point3::new(1.0, 1.0, 1.0); 1000]);
        assert_eq!(
            dup.within_radius(&Point3::new(1.0, 1.0, 1.0), 0.0).len(),
            1000
        );
        assert_eq!(dup.knn(&Point3::origin(), 5).len(), 5);
        assert!(dup.within_radius(&Point3::origin(), f64::NAN).is_empty());
    }
}
