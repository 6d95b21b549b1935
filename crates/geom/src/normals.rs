//! Normal estimation by PCA over the k nearest neighbours, consistently oriented.

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;

use crate::cloud::Aabb;
use crate::error::{GeomError, Result};
use crate::kdtree::KdTree;
use crate::math::{Point3, Vector3};

/// The fewest neighbours that define a plane.
pub const MIN_NEIGHBOURS: usize = 3;

/// How estimated normals are oriented (PCA gives a direction only up to sign).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Orientation {
    /// Each normal points toward this viewpoint (the scanner position), mm.
    TowardViewpoint(Point3),
    /// Each normal has a non-negative component along this reference direction.
    AlongReference(Vector3),
}

/// Estimates one unit normal per point: the eigenvector of the smallest eigenvalue of the
/// covariance of the point's `k` nearest neighbours (itself included), flipped to `orientation`.
///
/// The most neighbours a normal is estimated over: more only blurs it (and `k = 2⁶³` asked for
/// an allocation that overflowed).
pub const MAX_NEIGHBOURS: usize = 10_000;

/// Refuses `k < 3` or `k >` [`MAX_NEIGHBOURS`], a cloud with fewer than 3 points, a zero
/// reference direction and a viewpoint that is not finite. A `k` larger than the cloud takes
/// every point.
///
/// A point whose neighbours span no plane (all at one place, or on one line) has no normal:
/// it gets +Z, oriented, and a warning (tracing; Python's `TrimWarning`) counts such points and
/// names the first. A cloud with no point whose neighbours span a plane is refused, and so is
/// one spanning more or less than [`EXTENT_RANGE_MM`] (not at one place), where the kd-tree's
/// squared distances overflow or vanish. Within that range the covariance is taken of the
/// offsets scaled by a power of two, so a cloud of 1e-100 mm has the normals of one of 1 mm.
pub fn estimate_normals(
    points: &[Point3],
    k: usize,
    orientation: Orientation,
) -> Result<Vec<Vector3>> {
    if !(MIN_NEIGHBOURS..=MAX_NEIGHBOURS).contains(&k) {
        return Err(GeomError::invalid(
            "k",
            format!("must be in [{MIN_NEIGHBOURS}, {MAX_NEIGHBOURS}] neighbours, got {k}"),
        ));
    }
    let k = k.min(points.len());
    if points.len() < MIN_NEIGHBOURS {
        return Err(GeomError::TooFewPoints {
            what: "normal estimation".into(),
            needed: MIN_NEIGHBOURS,
            got: points.len(),
        });
    }
    if let Orientation::AlongReference(r) = orientation
        && (!r.iter().all(|c| c.is_finite()) || r.norm() <= 0.0)
    {
        return Err(GeomError::invalid(
            "reference",
            "orientation reference must be a finite non-zero vector",
        ));
    }
    if let Orientation::TowardViewpoint(v) = orientation
        && !v.iter().all(|c| c.is_finite())
    {
        return Err(GeomError::invalid(
            "viewpoint",
            "the viewpoint must be finite",
        ));
    }
    check_extent(points)?;
    let tree = KdTree::build(points);
    let found: Vec<Option<Vector3>> = points
        .par_iter()
        .map(|p| {
            let neighbours = tree.knn(p, k);
            plane_normal(neighbours.iter().map(|n| &points[n.index]))
        })
        .collect();
    let undefined = found.iter().filter(|n| n.is_none()).count();
    if undefined == points.len() {
        return Err(GeomError::invalid(
            "points",
            format!(
                "no point's {k} nearest neighbours span a plane (the {} points are all at one \
                 place or on one line): a normal needs a surface",
                points.len()
            ),
        ));
    }
    if let Some(first) = found.iter().position(Option::is_none) {
        tracing::warn!(
            "normal estimation: {undefined} of {} points have {k} nearest neighbours that span \
             no plane (at one place or on one line; the first is point {first}): their normals \
             are +Z, arbitrary",
            points.len()
        );
    }
    Ok(found
        .into_iter()
        .zip(points)
        .map(|(n, p)| orient(n.unwrap_or_else(Vector3::z), p, orientation))
        .collect())
}

/// The widest and narrowest spread of a cloud whose neighbours a kd-tree finds: its squared
/// distances neither overflow nor underflow to zero (mm).
pub const EXTENT_RANGE_MM: (f64, f64) = (1e-150, 1e150);

/// Refuses a cloud that spans more than [`EXTENT_RANGE_MM`] allows, or less without being at
/// one place: its squared distances would be infinite or zero, so any neighbours would do.
fn check_extent(points: &[Point3]) -> Result<()> {
    let extent = Aabb::around(points).map_or(0.0, |b| b.extent().amax());
    let (narrowest, widest) = EXTENT_RANGE_MM;
    if extent > widest || !extent.is_finite() || (extent > 0.0 && extent < narrowest) {
        return Err(GeomError::invalid(
            "points",
            format!(
                "the cloud spans {} mm along an axis: normals are estimated over clouds \
                 spanning {narrowest:e} to {widest:e} mm (their squared distances overflow or \
                 vanish beyond that); are the coordinates in mm?",
                crate::Num(extent)
            ),
        ));
    }
    Ok(())
}

/// The least-variance direction of a set of points (unit), or +Z for a degenerate set (see
/// [`plane_normal`]).
#[must_use]
pub fn pca_normal<'a>(points: impl Iterator<Item = &'a Point3> + Clone) -> Vector3 {
    plane_normal(points).unwrap_or_else(Vector3::z)
}

/// A plane's spread across it below this share of its spread along it (variances: a
/// millionth in distance) is no plane: the points lie on one line.
const LINE_SPREAD: f64 = 1e-12;

/// The least-variance direction of a set of points (unit), or `None` when the points span no
/// plane: fewer than 3, all at one place, or on one line (the middle variance under
/// [`LINE_SPREAD`] of the largest). The offsets from the mean are scaled by a power of two
/// (exact) so that their products neither overflow nor underflow.
#[must_use]
pub fn plane_normal<'a>(points: impl Iterator<Item = &'a Point3> + Clone) -> Option<Vector3> {
    let (sum, count) = points
        .clone()
        .fold((Vector3::zeros(), 0usize), |(s, c), p| {
            (s + p.coords, c + 1)
        });
    if count < MIN_NEIGHBOURS {
        return None;
    }
    let mean = sum / count as f64;
    let largest = points
        .clone()
        .map(|p| (p.coords - mean).amax())
        .fold(0.0_f64, f64::max);
    if !(largest.is_finite() && largest > 0.0) {
        return None;
    }
    // 2^-e with 2^e near the largest offset: the scaled offsets are near 1, and the scaling is
    // exact, so ordinary clouds keep their normals to the bit.
    let scale = 2f64.powi(-largest.log2().round() as i32);
    let cov = points.fold(Matrix3::zeros(), |acc, p| {
        let d = (p.coords - mean) * scale;
        acc + d * d.transpose()
    });
    let eig = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let (least, middle, most) = (
        eig.eigenvalues[order[0]],
        eig.eigenvalues[order[1]],
        eig.eigenvalues[order[2]],
    );
    if !(least.is_finite() && most.is_finite()) || middle <= LINE_SPREAD * most {
        return None;
    }
    let n = eig.eigenvectors.column(order[0]).into_owned();
    let norm = n.norm();
    (norm > 0.0 && norm.is_finite()).then(|| n / norm)
}

fn orient(n: Vector3, p: &Point3, orientation: Orientation) -> Vector3 {
    let reference = match orientation {
        Orientation::TowardViewpoint(v) => v - p,
        Orientation::AlongReference(r) => r,
    };
    if n.dot(&reference) < 0.0 { -n } else { n }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_are_oriented_toward_viewpoint() {
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (x, y) = (f64::from(i) * 0.5, f64::from(j) * 0.5);
                // plane z = 0.2 x
                pts.push(Point3::new(x, y, 0.2 * x));
            }
        }
        let ns = estimate_normals(
            &pts,
            8,
            Orientation::TowardViewpoint(Point3::new(0.0, 0.0, 100.0)),
        )
        .unwrap();
        let expected = Vector3::new(-0.2, 0.0, 1.0).normalize();
        for n in &ns {
            assert!((n - expected).norm() < 1e-9, "{n:?}");
        }
        let down = estimate_normals(&pts, 8, Orientation::AlongReference(-Vector3::z())).unwrap();
        assert!((down[0] + expected).norm() < 1e-9);
    }

    #[test]
    fn refuses_bad_arguments() {
        let pts = vec![Point3::origin(); 10];
        assert!(estimate_normals(&pts, 2, Orientation::AlongReference(Vector3::z())).is_err());
        assert!(estimate_normals(&pts[..2], 5, Orientation::AlongReference(Vector3::z())).is_err());
        assert!(estimate_normals(&pts, 5, Orientation::AlongReference(Vector3::zeros())).is_err());
        let e = estimate_normals(&pts, 1 << 63, Orientation::AlongReference(Vector3::z()))
            .unwrap_err()
            .to_string();
        assert!(e.contains('k') && e.contains("10000"), "{e}");
        let nan = Point3::new(f64::NAN, 0.0, 0.0);
        assert!(estimate_normals(&pts, 5, Orientation::TowardViewpoint(nan)).is_err());
        // A k larger than the cloud takes every point.
        let plane: Vec<Point3> = (0..5)
            .flat_map(|i| (0..5).map(move |j| Point3::new(f64::from(i), f64::from(j), 0.0)))
            .collect();
        let normals =
            estimate_normals(&plane, 500, Orientation::AlongReference(Vector3::z())).unwrap();
        assert!(normals.iter().all(|n| (n - Vector3::z()).norm() < 1e-9));
    }

    /// A tilted plane's 12×12 grid scaled by `s` about a point at `offset` (mm).
    fn tilted_plane(s: f64, offset: f64) -> Vec<Point3> {
        (0..12)
            .flat_map(|i| {
                (0..12).map(move |j| {
                    let (x, y) = (f64::from(i), f64::from(j));
                    Point3::new(
                        offset + s * x,
                        offset + s * y,
                        offset + s * (0.3 * x - 0.1 * y),
                    )
                })
            })
            .collect()
    }

    #[test]
    fn a_cloud_of_any_size_a_kd_tree_can_search_has_its_normals_and_a_larger_one_is_refused() {
        let up = Orientation::AlongReference(Vector3::z());
        let expected = Vector3::new(-0.3, 0.1, 1.0).normalize();
        for (s, offset) in [
            (1.0, 0.0),
            (1e100, 0.0),
            (1e-100, 0.0),
            (1e-100, 1e-95),
            (1e120, 1e125),
        ] {
            let normals = estimate_normals(&tilted_plane(s, offset), 8, up)
                .unwrap_or_else(|e| panic!("scale {s:e}, offset {offset:e}: {e}"));
            for n in &normals {
                assert!(
                    (n - expected).norm() < 1e-9,
                    "scale {s:e}, offset {offset:e}: {n:?}"
                );
            }
        }
        for s in [1e300, 1e-300] {
            let e = estimate_normals(&tilted_plane(s, 0.0), 8, up)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("the cloud spans") && e.contains("1e150"),
                "scale {s:e}: {e}"
            );
        }
    }

    #[test]
    fn points_whose_neighbours_span_no_plane_have_no_normal_and_a_cloud_of_them_is_refused() {
        let up = Orientation::AlongReference(Vector3::z());
        for (what, cloud) in [
            ("one place", vec![Point3::new(1.0, 2.0, 3.0); 100]),
            (
                "one line",
                (0..100)
                    .map(|i| Point3::new(f64::from(i), 2.0 * f64::from(i), 0.5))
                    .collect(),
            ),
        ] {
            let e = estimate_normals(&cloud, 8, up).unwrap_err().to_string();
            assert!(
                e.contains("span a plane") && e.contains("100 points"),
                "{what}: {e}"
            );
            assert_eq!(plane_normal(cloud.iter()), None, "{what}");
            assert_eq!(pca_normal(cloud.iter()), Vector3::z(), "{what}");
        }
        // A plane with 9 copies of one point: the copies' 8 neighbours are copies, so they have
        // no normal (+Z); every other point keeps its own.
        let mut cloud = tilted_plane(1.0, 0.0);
        cloud.extend(std::iter::repeat_n(Point3::new(50.0, 50.0, 50.0), 9));
        let normals = estimate_normals(&cloud, 8, up).unwrap();
        let expected = Vector3::new(-0.3, 0.1, 1.0).normalize();
        assert!(normals[..144].iter().all(|n| (n - expected).norm() < 1e-9));
        assert!(normals[144..].iter().all(|n| *n == Vector3::z()));
    }
}
