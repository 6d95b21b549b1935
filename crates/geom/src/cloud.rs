//! Point clouds: `f64` points in millimetres with optional unit normals.

use rayon::prelude::*;

use crate::error::{GeomError, Result};
use crate::math::{Point3, Similarity3, Vector3, is_finite_point, is_finite_vector, unit_or_none};
use crate::transform::check_transform;

/// Normals shorter than this are refused as undefined.
pub const MIN_NORMAL_NORM: f64 = 1e-12;

/// An axis-aligned bounding box, millimetres.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    /// The smallest x, y and z.
    pub min: Point3,
    /// The largest x, y and z.
    pub max: Point3,
}

impl Aabb {
    /// The box around `points`, or `None` when there are none.
    #[must_use]
    pub fn around<'a>(points: impl IntoIterator<Item = &'a Point3>) -> Option<Aabb> {
        let mut it = points.into_iter();
        let first = *it.next()?;
        let (min, max) = it.fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
        Some(Aabb { min, max })
    }

    /// The edge lengths along x, y and z.
    #[must_use]
    pub fn extent(&self) -> Vector3 {
        self.max - self.min
    }

    /// The length of the diagonal.
    #[must_use]
    pub fn diagonal(&self) -> f64 {
        self.extent().norm()
    }

    /// The centre.
    #[must_use]
    pub fn center(&self) -> Point3 {
        nalgebra::center(&self.min, &self.max)
    }

    /// How far `p` lies outside the box (0 inside; infinite when `p` is not finite). A point
    /// past about 1e154 from the box, whose squared distance overflows, is given its largest
    /// distance along one axis: it is that far at least.
    #[must_use]
    pub fn distance_outside(&self, p: &Point3) -> f64 {
        if !crate::math::is_finite_point(p) {
            return f64::INFINITY;
        }
        let mut sum2 = 0.0;
        let mut worst: f64 = 0.0;
        for axis in 0..3 {
            let d = (self.min[axis] - p[axis])
                .max(p[axis] - self.max[axis])
                .max(0.0);
            worst = worst.max(d);
            sum2 += d * d;
        }
        if sum2.is_finite() { sum2.sqrt() } else { worst }
    }
}

/// A point cloud. Points are finite; normals, when present, are unit length and one per point.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    points: Vec<Point3>,
    normals: Option<Vec<Vector3>>,
}

impl PointCloud {
    /// A cloud of points without normals. Refuses NaN or infinite coordinates.
    pub fn new(points: Vec<Point3>) -> Result<Self> {
        check_points(&points)?;
        Ok(PointCloud {
            points,
            normals: None,
        })
    }

    /// A cloud with one normal per point. Normals are normalised; NaN, infinite or zero normals
    /// are refused with their index.
    pub fn with_normals(points: Vec<Point3>, normals: Vec<Vector3>) -> Result<Self> {
        check_points(&points)?;
        let normals = check_normals(points.len(), normals)?;
        Ok(PointCloud {
            points,
            normals: Some(normals),
        })
    }

    /// The points, millimetres.
    #[must_use]
    pub fn points(&self) -> &[Point3] {
        &self.points
    }

    /// The unit normals, one per point, if the cloud has them.
    #[must_use]
    pub fn normals(&self) -> Option<&[Vector3]> {
        self.normals.as_deref()
    }

    /// Whether the cloud carries normals.
    #[must_use]
    pub fn has_normals(&self) -> bool {
        self.normals.is_some()
    }

    /// The number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The bounding box, or `None` for an empty cloud.
    #[must_use]
    pub fn bounds(&self) -> Option<Aabb> {
        Aabb::around(&self.points)
    }

    /// Sets (or replaces) the normals, with the checks of [`PointCloud::with_normals`].
    pub fn set_normals(&mut self, normals: Vec<Vector3>) -> Result<()> {
        self.normals = Some(check_normals(self.points.len(), normals)?);
        Ok(())
    }

    /// Drops the normals.
    pub fn clear_normals(&mut self) {
        self.normals = None;
    }

    /// Splits the cloud into its points and normals.
    #[must_use]
    pub fn into_parts(self) -> (Vec<Point3>, Option<Vec<Vector3>>) {
        (self.points, self.normals)
    }

    /// The cloud in frame `b`, given `b_from_a` for a cloud in frame `a`. Normals are rotated.
    /// Refuses a transform with a NaN or infinite entry (or a scale that is not finite and > 0)
    /// and a point that leaves the finite range on the way, so the result keeps the cloud's
    /// promise: finite points (a NaN point would otherwise land in voxel 0 downstream).
    pub fn transformed(&self, b_from_a: &Similarity3) -> Result<PointCloud> {
        check_transform(b_from_a)?;
        let points = self
            .points
            .par_iter()
            .map(|p| b_from_a * p)
            .collect::<Vec<_>>();
        if let Some(index) = points.iter().position(|p| !is_finite_point(p)) {
            return Err(GeomError::NonFinite {
                what: "transformed point",
                index,
            });
        }
        let rotation = b_from_a.isometry.rotation;
        let normals = self
            .normals
            .as_ref()
            .map(|ns| ns.par_iter().map(|n| rotation * n).collect());
        Ok(PointCloud { points, normals })
    }

    /// The sub-cloud of the given indices, in their order. Out-of-range indices are refused.
    pub fn select(&self, indices: &[usize]) -> Result<PointCloud> {
        if let Some(&bad) = indices.iter().find(|&&i| i >= self.points.len()) {
            return Err(GeomError::invalid(
                "indices",
                format!(
                    "index {bad} is out of range for {} points",
                    self.points.len()
                ),
            ));
        }
        Ok(PointCloud {
            points: indices.iter().map(|&i| self.points[i]).collect(),
            normals: self
                .normals
                .as_ref()
                .map(|ns| indices.iter().map(|&i| ns[i]).collect()),
        })
    }
}

fn check_points(points: &[Point3]) -> Result<()> {
    match points.iter().position(|p| !is_finite_point(p)) {
        Some(index) => Err(GeomError::NonFinite {
            what: "point",
            index,
        }),
        None => Ok(()),
    }
}

fn check_normals(n_points: usize, mut normals: Vec<Vector3>) -> Result<Vec<Vector3>> {
    if normals.len() != n_points {
        return Err(GeomError::LengthMismatch {
            what: "normals",
            expected: n_points,
            got: normals.len(),
        });
    }
    for (index, n) in normals.iter_mut().enumerate() {
        *n = match unit_or_none(n, MIN_NORMAL_NORM) {
            Some(unit) => unit,
            None if !is_finite_vector(n) => {
                return Err(GeomError::NonFinite {
                    what: "normal",
                    index,
                });
            }
            None => {
                return Err(GeomError::ZeroVector {
                    what: "normal",
                    index,
                });
            }
        };
    }
    Ok(normals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_nan_points_with_their_index() {
        let err =
            PointCloud::new(vec![Point3::origin(), Point3::new(f64::NAN, 0.0, 0.0)]).unwrap_err();
        assert!(matches!(
            err,
            GeomError::NonFinite {
                what: "point",
                index: 1
            }
        ));
    }

    #[test]
    fn normalises_normals_and_refuses_zero_ones() {
        let c = PointCloud::with_normals(vec![Point3::origin()], vec![Vector3::new(0.0, 0.0, 2.0)])
            .unwrap();
        assert!((c.normals().unwrap()[0].norm() - 1.0).abs() < 1e-15);
        let zero = PointCloud::with_normals(vec![Point3::origin()], vec![Vector3::zeros()]);
        assert_eq!(
            zero.unwrap_err().to_string(),
            "normal 0 is zero: it gives no direction"
        );
        let nan = PointCloud::with_normals(
            vec![Point3::origin()],
            vec![Vector3::new(f64::NAN, 0.0, 1.0)],
        );
        assert_eq!(nan.unwrap_err().to_string(), "normal 0 is not finite");
        assert!(PointCloud::with_normals(vec![Point3::origin()], vec![]).is_err());
        let huge = PointCloud::with_normals(
            vec![Point3::origin()],
            vec![Vector3::new(1e308, 0.0, 1e308)],
        )
        .unwrap();
        assert!(
            (huge.normals().unwrap()[0] - Vector3::new(1.0, 0.0, 1.0).normalize()).norm() < 1e-15
        );
    }

    #[test]
    fn transform_moves_points_and_rotates_normals() {
        let c = PointCloud::with_normals(
            vec![Point3::new(1.0, 0.0, 0.0)],
            vec![Vector3::new(1.0, 0.0, 0.0)],
        )
        .unwrap();
        let b_from_a = Similarity3::new(
            Vector3::new(0.0, 0.0, 5.0),
            Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            2.0,
        );
        let t = c.transformed(&b_from_a).unwrap();
        assert!((t.points()[0] - Point3::new(0.0, 2.0, 5.0)).norm() < 1e-12);
        assert!((t.normals().unwrap()[0] - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn transform_refuses_non_finite_transforms_and_overflowing_points() {
        let c = PointCloud::new(vec![Point3::origin(), Point3::new(1e300, 0.0, 0.0)]).unwrap();
        for bad in [
            Similarity3::new(Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros(), 1.0),
            Similarity3::new(Vector3::zeros(), Vector3::new(0.0, f64::INFINITY, 0.0), 1.0),
            Similarity3::new(Vector3::zeros(), Vector3::zeros(), f64::NAN),
        ] {
            let e = c.transformed(&bad).unwrap_err();
            assert!(
                matches!(
                    e,
                    GeomError::InvalidArgument {
                        name: "b_from_a",
                        ..
                    }
                ),
                "{e}"
            );
        }
        // Finite, but it carries point 1 past f64::MAX.
        let e = c
            .transformed(&Similarity3::new(Vector3::zeros(), Vector3::zeros(), 1e10))
            .unwrap_err();
        assert!(
            matches!(
                e,
                GeomError::NonFinite {
                    what: "transformed point",
                    index: 1
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn bounds_and_select() {
        let c = PointCloud::new(vec![
            Point3::new(1.0, -2.0, 3.0),
            Point3::new(-1.0, 4.0, 0.0),
        ])
        .unwrap();
        let b = c.bounds().unwrap();
        assert_eq!(b.min, Point3::new(-1.0, -2.0, 0.0));
        assert_eq!(b.max, Point3::new(1.0, 4.0, 3.0));
        assert_eq!(
            c.select(&[1]).unwrap().points()[0],
            Point3::new(-1.0, 4.0, 0.0)
        );
        assert!(c.select(&[2]).is_err());
        assert!(PointCloud::default().bounds().is_none());
    }
}
