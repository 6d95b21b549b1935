//! Normal estimation by PCA over the k nearest neighbours, consistently oriented.

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;

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
    let tree = KdTree::build(points);
    Ok(points
        .par_iter()
        .map(|p| {
            let neighbours = tree.knn(p, k);
            let n = pca_normal(neighbours.iter().map(|n| &points[n.index]));
            orient(n, p, orientation)
        })
        .collect())
}

/// The least-variance direction of a set of points (unit), or +Z for a degenerate set.
#[must_use]
pub fn pca_normal<'a>(points: impl Iterator<Item = &'a Point3> + Clone) -> Vector3 {
    let (sum, count) = points
        .clone()
        .fold((Vector3::zeros(), 0usize), |(s, c), p| {
            (s + p.coords, c + 1)
        });
    if count < MIN_NEIGHBOURS {
        return Vector3::z();
    }
    let mean = sum / count as f64;
    let cov = points.fold(Matrix3::zeros(), |acc, p| {
        let d = p.coords - mean;
        acc + d * d.transpose()
    });
    let eig = SymmetricEigen::new(cov);
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold(
            (0, f64::INFINITY),
            |best, (i, &v)| if v < best.1 { (i, v) } else { best },
        );
    let n = eig.eigenvectors.column(imin).into_owned();
    let norm = n.norm();
    if norm > 0.0 && norm.is_finite() {
        n / norm
    } else {
        Vector3::z()
    }
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
}
