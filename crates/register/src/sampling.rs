//! Point selection for registration: unbiased voxel thinning and visibility culling of the CAD.

use rayon::prelude::*;
use trim_geom::{Point3, PointCloud, Vector3};

use crate::error::{RegisterError, Result};

/// Bits per axis of a packed voxel key: three fit a `u64`.
const PACKED_AXIS_BITS: u32 = 21;

/// Every point's voxel of `voxel_mm` with its index, sorted by voxel (lexicographic in
/// `(x, y, z)`), ties by index. The voxel is given as a `u64` that orders and compares as the
/// voxel does: packed offsets from the lowest voxel when every axis spans fewer than
/// 2^[`PACKED_AXIS_BITS`] voxels (16-byte items sort fast), else the voxel's rank.
fn sorted_voxels(points: &[Point3], voxel_mm: f64) -> Vec<(u64, usize)> {
    let key = |p: &Point3| {
        [
            (p.x / voxel_mm).floor() as i64,
            (p.y / voxel_mm).floor() as i64,
            (p.z / voxel_mm).floor() as i64,
        ]
    };
    let keys: Vec<[i64; 3]> = points.par_iter().map(key).collect();
    let (lo, hi) = keys
        .iter()
        .fold(([i64::MAX; 3], [i64::MIN; 3]), |(mut lo, mut hi), k| {
            for a in 0..3 {
                lo[a] = lo[a].min(k[a]);
                hi[a] = hi[a].max(k[a]);
            }
            (lo, hi)
        });
    let fits = (0..3).all(|a| {
        hi[a]
            .checked_sub(lo[a])
            .is_some_and(|span| span < 1 << PACKED_AXIS_BITS)
    });
    if fits {
        let mut packed: Vec<(u64, usize)> = keys
            .par_iter()
            .enumerate()
            .map(|(i, k)| {
                let off = [0, 1, 2].map(|a| (k[a] - lo[a]) as u64);
                (
                    (off[0] << (2 * PACKED_AXIS_BITS)) | (off[1] << PACKED_AXIS_BITS) | off[2],
                    i,
                )
            })
            .collect();
        packed.par_sort_unstable();
        return packed;
    }
    let mut keyed: Vec<([i64; 3], usize)> = keys.into_iter().zip(0..).collect();
    keyed.par_sort_unstable();
    let mut rank = 0u64;
    let mut out = Vec::with_capacity(keyed.len());
    for (n, &(k, i)) in keyed.iter().enumerate() {
        if n > 0 && keyed[n - 1].0 != k {
            rank += 1;
        }
        out.push((rank, i));
    }
    out
}

/// Keeps, per occupied voxel of `voxel_mm`, the one point nearest the voxel's centroid (ties to
/// the lower index). Unlike centroid down-sampling it never moves a point off the surface (no
/// bias at edges), and it is deterministic. Returns indices into `points` in voxel order, so
/// that consecutive points are neighbours in space (kd-tree queries in that order stay in
/// cache).
pub fn voxel_pick(points: &[Point3], voxel_mm: f64) -> Result<Vec<usize>> {
    check_voxel(voxel_mm)?;
    Ok(sorted_voxels(points, voxel_mm)
        .chunk_by(|a, b| a.0 == b.0)
        .map(|group| {
            let centroid: Vector3 = group
                .iter()
                .map(|&(_, i)| points[i].coords)
                .sum::<Vector3>()
                / group.len() as f64;
            group
                .iter()
                .map(|&(_, i)| ((points[i].coords - centroid).norm_squared(), i))
                .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
                .map_or(group[0].1, |b| b.1)
        })
        .collect())
}

/// Refuses a voxel size that is not finite and positive.
fn check_voxel(voxel_mm: f64) -> Result<()> {
    if voxel_mm.is_finite() && voxel_mm > 0.0 {
        Ok(())
    } else {
        Err(RegisterError::setting(
            "voxel_mm",
            format!("must be finite and > 0, got {voxel_mm}"),
        ))
    }
}

/// `0..points.len()` in the lexicographic order of their `voxel_mm` voxels (ties by index):
/// a deterministic spatially coherent order for kd-tree construction and queries.
#[must_use]
pub fn spatial_order(points: &[Point3], voxel_mm: f64) -> Vec<usize> {
    sorted_voxels(points, voxel_mm)
        .into_iter()
        .map(|(_, i)| i)
        .collect()
}

/// Where the scanner looked from, in the frame of the cloud it is applied to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum View {
    /// A scanner at this point (perspective), mm.
    From(Point3),
    /// A scanner infinitely far along this direction (orthographic): it looks along `−dir`.
    Along(Vector3),
}

/// The indices of the CAD points whose outward normal faces the scanner:
/// `n · v ≥ min_cos` with `v` the unit direction to the scanner. Back faces (the far side of a
/// slab, walls turned away) cannot be in the scan, and matching scan points to them is what
/// sends the paper's local fits astray. Refuses a CAD cloud without normals.
pub fn facing_indices(cad: &PointCloud, view: View, min_cos: f64) -> Result<Vec<usize>> {
    let normals = cad.normals().ok_or(RegisterError::MissingNormals {
        which: "CAD",
        method: "visibility culling",
    })?;
    Ok(cad
        .points()
        .par_iter()
        .zip(normals.par_iter())
        .enumerate()
        .filter_map(|(i, (p, n))| {
            let v = match view {
                View::From(eye) => eye - p,
                View::Along(d) => d,
            };
            let norm = v.norm();
            (norm > 0.0 && n.dot(&v) / norm >= min_cos).then_some(i)
        })
        .collect())
}

/// Voxel centroids of the voxels holding at least `min_count` points (deterministic, in voxel
/// order). Isolated outliers sit alone in their voxels and drop out, which plain centroid
/// down-sampling would keep (at coarse voxels they can outnumber the surface).
pub fn dense_voxel_centroids(
    points: &[Point3],
    voxel_mm: f64,
    min_count: usize,
) -> Result<Vec<Point3>> {
    VoxelPyramid::new(points, voxel_mm)?.dense_centroids(voxel_mm, min_count)
}

/// A scan's voxel sums at a base voxel size, from one sort of its points: the dense voxel
/// centroids ([`dense_voxel_centroids`]) at the base size and at every power-of-two multiple of
/// it come from these sums (a voxel of `2ᵐ b` is exactly the union of its `b` voxels: dividing
/// by a power of two is exact in floating point), and those at any other size from the points.
/// The coarse registration's pyramid (2, 1 and 0.5 mm) sorts the 500 000 points once, not three
/// times.
#[derive(Debug, Clone)]
pub struct VoxelPyramid<'a> {
    points: &'a [Point3],
    base_mm: f64,
    /// Base voxels in voxel order: integer coordinates, coordinate sum, point count.
    voxels: Vec<([i64; 3], Vector3, usize)>,
}

impl<'a> VoxelPyramid<'a> {
    /// The sums of `points` at `base_mm`.
    pub fn new(points: &'a [Point3], base_mm: f64) -> Result<Self> {
        check_voxel(base_mm)?;
        let voxels = sorted_voxels(points, base_mm)
            .chunk_by(|a, b| a.0 == b.0)
            .map(|group| {
                let p = points[group[0].1];
                let key = [p.x, p.y, p.z].map(|v| (v / base_mm).floor() as i64);
                let sum: Vector3 = group.iter().map(|&(_, i)| points[i].coords).sum();
                (key, sum, group.len())
            })
            .collect();
        Ok(VoxelPyramid {
            points,
            base_mm,
            voxels,
        })
    }

    /// [`dense_voxel_centroids`] of the points at `voxel_mm`: from the base sums when `voxel_mm`
    /// is a power-of-two multiple of the base (the same voxels in the same order; a multiple
    /// above 1 may differ in the last bits, as its sums are taken in another order), else from
    /// the points.
    pub fn dense_centroids(&self, voxel_mm: f64, min_count: usize) -> Result<Vec<Point3>> {
        Ok(self
            .dense_counted(voxel_mm, min_count)?
            .into_iter()
            .map(|(p, _)| p)
            .collect())
    }

    /// [`Self::dense_centroids`] with each voxel's point count.
    pub fn dense_counted(&self, voxel_mm: f64, min_count: usize) -> Result<Vec<(Point3, usize)>> {
        let ratio = voxel_mm / self.base_mm;
        let m = ratio.round();
        let power_of_two = m >= 1.0 && m <= f64::from(1u32 << 20) && (m as u64).is_power_of_two();
        if !(power_of_two && (ratio - m).abs() <= 1e-12 * m) {
            return VoxelPyramid::new(self.points, voxel_mm)?.dense_counted(voxel_mm, min_count);
        }
        let m = m as i64;
        let mut coarse: Vec<([i64; 3], usize)> = self
            .voxels
            .iter()
            .enumerate()
            .map(|(i, (k, _, _))| (k.map(|v| v.div_euclid(m)), i))
            .collect();
        if m > 1 {
            coarse.sort_unstable();
        }
        Ok(coarse
            .chunk_by(|a, b| a.0 == b.0)
            .filter_map(|group| {
                let (sum, count) = group.iter().fold((Vector3::zeros(), 0), |(s, c), &(_, i)| {
                    (s + self.voxels[i].1, c + self.voxels[i].2)
                });
                (count >= min_count).then(|| (Point3::from(sum / count as f64), count))
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pyramid_gives_the_direct_centroids() {
        // A noisy sheet with negative coordinates (floor, not truncation) and sparse corners.
        let pts: Vec<Point3> = (0..20_000)
            .map(|i| {
                let f = f64::from(i);
                Point3::new(
                    (f * 0.618_034).fract() * 13.0 - 6.3,
                    (f * 0.414_214).fract() * 7.0 - 3.1,
                    (f * 0.732_051).fract() * 0.2 - 1.05,
                )
            })
            .collect();
        let pyramid = VoxelPyramid::new(&pts, 0.5).unwrap();
        for (voxel, min) in [(0.5, 3), (1.0, 3), (2.0, 3), (4.0, 1), (0.75, 3)] {
            let direct = dense_voxel_centroids(&pts, voxel, min).unwrap();
            let derived = pyramid.dense_centroids(voxel, min).unwrap();
            assert_eq!(direct.len(), derived.len(), "voxel {voxel}");
            for (a, b) in direct.iter().zip(&derived) {
                assert!((a - b).norm() < 1e-12, "voxel {voxel}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn picks_one_point_per_voxel_on_the_surface() {
        let pts: Vec<Point3> = (0..1000)
            .map(|i| Point3::new(f64::from(i) * 0.01, 0.0, 0.0))
            .collect();
        let idx = voxel_pick(&pts, 1.0).unwrap();
        assert_eq!(idx.len(), 10);
        let mut idx = idx;
        idx.sort_unstable();
        // Every picked point is an input point near a voxel centre.
        for (k, &i) in idx.iter().enumerate() {
            assert!(
                (pts[i].x - (k as f64 + 0.495)).abs() < 0.011,
                "{}",
                pts[i].x
            );
        }
        assert!(voxel_pick(&pts, 0.0).is_err());
    }

    #[test]
    fn sorted_voxels_order_as_the_voxel_keys_do() {
        for (spread, voxel) in [(50.0, 0.7), (1e6, 1e-3)] {
            let pts: Vec<Point3> = (0..5000)
                .map(|i| {
                    let t = f64::from(i);
                    Point3::new(
                        spread * (t * 0.37).sin(),
                        spread * (t * 0.11).cos(),
                        ((t * 0.05).sin() * 3.0).round(),
                    )
                })
                .collect();
            let mut reference: Vec<([i64; 3], usize)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    (
                        [
                            (p.x / voxel).floor() as i64,
                            (p.y / voxel).floor() as i64,
                            (p.z / voxel).floor() as i64,
                        ],
                        i,
                    )
                })
                .collect();
            reference.sort_unstable();
            let got = sorted_voxels(&pts, voxel);
            assert_eq!(got.len(), reference.len());
            for n in 0..got.len() {
                assert_eq!(got[n].1, reference[n].1);
                if n > 0 {
                    assert_eq!(
                        got[n].0 == got[n - 1].0,
                        reference[n].0 == reference[n - 1].0
                    );
                }
            }
        }
    }

    #[test]
    fn culls_back_faces() {
        let cad = PointCloud::with_normals(
            vec![Point3::origin(), Point3::origin(), Point3::origin()],
            vec![Vector3::z(), -Vector3::z(), Vector3::x()],
        )
        .unwrap();
        let up = facing_indices(&cad, View::Along(Vector3::z()), -0.1).unwrap();
        assert_eq!(up, vec![0, 2]);
        let eye = facing_indices(&cad, View::From(Point3::new(0.0, 0.0, -10.0)), 0.5).unwrap();
        assert_eq!(eye, vec![1]);
    }
}
