//! Voxel down-sampling: one point per occupied voxel, the centroid of the points in it.

use std::collections::BTreeMap;

use crate::cloud::PointCloud;
use crate::error::{GeomError, Result};
use crate::math::{Point3, Vector3};

/// The largest voxel index along an axis: 2^52, below which every integer is exact in f64.
const MAX_VOXEL_INDEX: f64 = 4_503_599_627_370_496.0;

/// Down-samples `cloud` on a grid of `voxel_mm` cubes anchored at the origin. Each occupied voxel
/// gives the centroid of its points (and, with normals, their normalised mean; a voxel whose
/// normals cancel keeps its first point's normal). Output order is by voxel index, so the result
/// is deterministic.
pub fn voxel_downsample(cloud: &PointCloud, voxel_mm: f64) -> Result<PointCloud> {
    if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
        return Err(GeomError::invalid(
            "voxel_mm",
            format!("voxel size must be finite and > 0, got {voxel_mm}"),
        ));
    }
    // A voxel index beyond 2^52 is not exact in f64, and beyond i64 it saturates: points far
    // apart would share a voxel and be merged without a word.
    if let Some((i, m)) = cloud
        .points()
        .iter()
        .map(|p| p.coords.amax())
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|&(_, m)| m / voxel_mm > MAX_VOXEL_INDEX)
    {
        return Err(GeomError::invalid(
            "voxel_mm",
            format!(
                "voxel size {} mm is too fine for the cloud: point {i}, at a coordinate of {} mm, \
                 would be voxel {} along that axis (at most 2^52); use a voxel of at least {} mm",
                crate::Num(voxel_mm),
                crate::Num(m),
                crate::Num((m / voxel_mm).floor()),
                crate::Num(m / MAX_VOXEL_INDEX),
            ),
        ));
    }
    let mut cells: BTreeMap<[i64; 3], (Vector3, Vector3, Vector3, usize)> = BTreeMap::new();
    let normals = cloud.normals();
    for (i, p) in cloud.points().iter().enumerate() {
        let key = [
            (p.x / voxel_mm).floor() as i64,
            (p.y / voxel_mm).floor() as i64,
            (p.z / voxel_mm).floor() as i64,
        ];
        let n = normals.map_or(Vector3::zeros(), |ns| ns[i]);
        let cell = cells
            .entry(key)
            .or_insert((Vector3::zeros(), Vector3::zeros(), n, 0));
        cell.0 += p.coords;
        cell.1 += n;
        cell.3 += 1;
    }
    let mut points = Vec::with_capacity(cells.len());
    let mut out_normals = Vec::with_capacity(cells.len());
    for (sum, nsum, first_n, count) in cells.into_values() {
        points.push(Point3::from(sum / count as f64));
        let norm = nsum.norm();
        out_normals.push(if norm > 1e-9 { nsum / norm } else { first_n });
    }
    if normals.is_some() {
        PointCloud::with_normals(points, out_normals)
    } else {
        PointCloud::new(points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_voxel_too_fine_for_the_coordinates_is_refused_not_merging_far_points() {
        // 1e-19 mm merged 400 distinct points into 33: the i64 voxel keys saturated.
        let points: Vec<Point3> = (0..400)
            .map(|i| Point3::new(f64::from(i % 20), f64::from(i / 20), 1.0))
            .collect();
        let c = PointCloud::new(points).unwrap();
        for tiny in [1e-19, 1e-300] {
            let e = voxel_downsample(&c, tiny).unwrap_err().to_string();
            assert!(
                e.contains("voxel_mm") && e.contains("too fine") && e.contains("point 399"),
                "{e}"
            );
        }
        // At the finest a 19 mm cloud takes, every point keeps its own voxel.
        assert_eq!(voxel_downsample(&c, 1e-12).unwrap().len(), 400);
    }

    #[test]
    fn one_point_per_voxel_at_the_centroid() {
        let c = PointCloud::new(vec![
            Point3::new(0.1, 0.1, 0.1),
            Point3::new(0.3, 0.3, 0.3),
            Point3::new(1.5, 0.1, 0.1),
        ])
        .unwrap();
        let d = voxel_downsample(&c, 1.0).unwrap();
        assert_eq!(d.len(), 2);
        assert!((d.points()[0] - Point3::new(0.2, 0.2, 0.2)).norm() < 1e-12);
        assert!(voxel_downsample(&c, 0.0).is_err());
        assert!(voxel_downsample(&c, f64::NAN).is_err());
    }
}
