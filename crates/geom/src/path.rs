//! Trimming paths: contours of points with feature vectors (DESIGN.md "Path CSV").
//!
//! A contour's feature vector is the ideal laser-axis direction. The path CSV gives one per row;
//! the contract keeps it constant within a contour, but a CAM export may vary it along the
//! contour, so each point keeps its own and [`Contour::feature`] is their normalised mean.

use std::collections::HashSet;

use crate::cloud::Aabb;
use crate::error::{GeomError, Result};
use crate::math::{Point3, Similarity3, UnitVector3, Vector3, is_finite_point, unit_or_none};
use crate::transform::check_transform;

/// A contour id, as in the path CSV's `contour` column.
pub type ContourId = i64;

/// Feature vectors shorter than this are refused.
pub const MIN_FEATURE_NORM: f64 = 1e-9;

/// A contour point with a coordinate beyond this (mm, 100 m) is refused: no machine's work
/// space is larger, and such a point (a path in micrometres, a stray value) made the planner
/// and the registration size their grids by it (a capacity overflow, or hours of work).
pub const MAX_COORDINATE_MM: f64 = 1e5;

/// A contour shorter than this (mm, summed over its segments) has zero length and is refused.
pub const MIN_CONTOUR_LENGTH_MM: f64 = 1e-9;

/// One contour: at least two points in path order, each with a unit feature vector.
#[derive(Debug, Clone, PartialEq)]
pub struct Contour {
    id: ContourId,
    points: Vec<Point3>,
    features: Vec<Vector3>,
}

impl Contour {
    /// A contour whose points all share one feature vector.
    pub fn new(id: ContourId, points: Vec<Point3>, feature: Vector3) -> Result<Self> {
        let features = vec![feature; points.len()];
        Contour::with_features(id, points, features)
    }

    /// A contour with one feature vector per point. Checks: at least two points, all finite,
    /// non-zero length, one non-zero finite feature per point (normalised here).
    pub fn with_features(
        id: ContourId,
        points: Vec<Point3>,
        mut features: Vec<Vector3>,
    ) -> Result<Self> {
        let bad = |message: String| GeomError::InvalidContour {
            contour: id,
            message,
        };
        if points.len() < 2 {
            return Err(bad(format!(
                "needs at least 2 points, got {}",
                points.len()
            )));
        }
        if features.len() != points.len() {
            return Err(bad(format!(
                "{} feature vectors for {} points",
                features.len(),
                points.len()
            )));
        }
        if let Some(i) = points.iter().position(|p| !is_finite_point(p)) {
            return Err(bad(format!("point {i} is not finite")));
        }
        if let Some((i, p)) = points
            .iter()
            .enumerate()
            .find(|(_, p)| p.coords.amax() > MAX_COORDINATE_MM)
        {
            return Err(bad(format!(
                "point {i} at ({:.6e}, {:.6e}, {:.6e}) mm lies beyond ±{MAX_COORDINATE_MM} mm (100 m): no machine reaches that far (a path in µm, or in another frame?)",
                p.x, p.y, p.z
            )));
        }
        for (i, f) in features.iter_mut().enumerate() {
            *f = unit_or_none(f, MIN_FEATURE_NORM)
                .ok_or_else(|| bad(format!("feature vector at point {i} is zero or not finite")))?;
        }
        let contour = Contour {
            id,
            points,
            features,
        };
        if contour.length() < MIN_CONTOUR_LENGTH_MM {
            return Err(bad("has zero length (all points coincide)".into()));
        }
        if contour.features.iter().sum::<Vector3>().norm() < MIN_FEATURE_NORM {
            return Err(bad("feature vectors cancel out: no mean direction".into()));
        }
        Ok(contour)
    }

    /// The id from the input path.
    #[must_use]
    pub fn id(&self) -> ContourId {
        self.id
    }

    /// The points in path order, millimetres.
    #[must_use]
    pub fn points(&self) -> &[Point3] {
        &self.points
    }

    /// The unit feature vector of each point.
    #[must_use]
    pub fn features(&self) -> &[Vector3] {
        &self.features
    }

    /// The contour's feature vector: the normalised mean of its points' feature vectors.
    #[must_use]
    pub fn feature(&self) -> UnitVector3 {
        UnitVector3::new_normalize(self.features.iter().sum())
    }

    /// The polyline length, millimetres.
    #[must_use]
    pub fn length(&self) -> f64 {
        self.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    /// The mean of the points (the centroid of the vertices).
    #[must_use]
    pub fn centroid(&self) -> Point3 {
        let sum: Vector3 = self.points.iter().map(|p| p.coords).sum();
        Point3::from(sum / self.points.len() as f64)
    }

    /// The largest angle (radians) between any point's feature vector and the contour's feature.
    #[must_use]
    pub fn feature_spread_rad(&self) -> f64 {
        let axis = self.feature();
        self.features
            .iter()
            .map(|f| f.dot(&axis).clamp(-1.0, 1.0).acos())
            .fold(0.0, f64::max)
    }

    /// The contour in frame `b`, given `b_from_a`. Feature vectors are rotated. Refuses a
    /// non-finite transform, and a point that leaves the finite range, naming the contour.
    pub fn transformed(&self, b_from_a: &Similarity3) -> Result<Contour> {
        check_transform(b_from_a).map_err(|e| GeomError::InvalidContour {
            contour: self.id,
            message: e.to_string(),
        })?;
        let rotation = b_from_a.isometry.rotation;
        let points: Vec<Point3> = self.points.iter().map(|p| b_from_a * p).collect();
        if let Some(i) = points.iter().position(|p| !is_finite_point(p)) {
            return Err(GeomError::InvalidContour {
                contour: self.id,
                message: format!("point {i} is not finite after the transform"),
            });
        }
        Ok(Contour {
            id: self.id,
            points,
            features: self.features.iter().map(|f| rotation * f).collect(),
        })
    }

    /// A copy with new point positions (same count, same features), e.g. after registration.
    pub fn with_points(&self, points: Vec<Point3>) -> Result<Contour> {
        Contour::with_features(self.id, points, self.features.clone())
    }
}

/// A trimming path: contours with unique ids, in input order.
#[derive(Debug, Clone, PartialEq)]
pub struct Path {
    contours: Vec<Contour>,
}

impl Path {
    /// A path of the given contours. Refuses an empty path and repeated ids.
    pub fn new(contours: Vec<Contour>) -> Result<Self> {
        if contours.is_empty() {
            return Err(GeomError::TooFewPoints {
                what: "path".into(),
                needed: 2,
                got: 0,
            });
        }
        let mut seen = HashSet::with_capacity(contours.len());
        for c in &contours {
            if !seen.insert(c.id) {
                return Err(GeomError::InvalidContour {
                    contour: c.id,
                    message: "id appears more than once".into(),
                });
            }
        }
        Ok(Path { contours })
    }

    /// The contours in input order.
    #[must_use]
    pub fn contours(&self) -> &[Contour] {
        &self.contours
    }

    /// Takes the contours out.
    #[must_use]
    pub fn into_contours(self) -> Vec<Contour> {
        self.contours
    }

    /// The contour with this id.
    #[must_use]
    pub fn get(&self, id: ContourId) -> Option<&Contour> {
        self.contours.iter().find(|c| c.id == id)
    }

    /// The number of contours.
    #[must_use]
    pub fn len(&self) -> usize {
        self.contours.len()
    }

    /// Always false: a path has at least one contour.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.contours.is_empty()
    }

    /// The total number of points.
    #[must_use]
    pub fn num_points(&self) -> usize {
        self.contours.iter().map(|c| c.points.len()).sum()
    }

    /// All points, contour after contour.
    pub fn points(&self) -> impl Iterator<Item = &Point3> {
        self.contours.iter().flat_map(|c| c.points.iter())
    }

    /// The bounding box of all points.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::around(self.points()).unwrap_or(Aabb {
            min: Point3::origin(),
            max: Point3::origin(),
        })
    }

    /// The path in frame `b`, given `b_from_a`; refuses what [`Contour::transformed`] refuses.
    pub fn transformed(&self, b_from_a: &Similarity3) -> Result<Path> {
        Ok(Path {
            contours: self
                .contours
                .iter()
                .map(|c| c.transformed(b_from_a))
                .collect::<Result<_>>()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn z() -> Vector3 {
        Vector3::z()
    }

    #[test]
    fn refuses_one_point_and_zero_length_contours() {
        let e = Contour::new(7, vec![Point3::origin()], z()).unwrap_err();
        assert!(e.to_string().contains("contour 7"), "{e}");
        let e = Contour::new(8, vec![Point3::origin(); 3], z()).unwrap_err();
        assert!(e.to_string().contains("zero length"), "{e}");
        let e = Contour::new(
            9,
            vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)],
            Vector3::zeros(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("feature"), "{e}");
        let huge = Contour::new(
            4,
            vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)],
            Vector3::new(0.0, 1e308, 1e308),
        )
        .unwrap();
        assert!((huge.features()[0] - Vector3::new(0.0, 1.0, 1.0).normalize()).norm() < 1e-15);
    }

    #[test]
    fn refuses_a_point_beyond_a_hundred_metres_naming_it() {
        let far = |x: f64| Contour::new(3, vec![Point3::origin(), Point3::new(x, 0.0, 0.0)], z());
        assert!(far(99_999.0).is_ok());
        for x in [1.000_01e5, -2e6, 1e300] {
            let e = far(x).unwrap_err().to_string();
            assert!(
                e.contains("contour 3") && e.contains("point 1") && e.contains("100 m"),
                "{e}"
            );
        }
    }

    #[test]
    fn feature_is_mean_and_spread_is_largest_angle() {
        let a = 10f64.to_radians();
        let c = Contour::with_features(
            1,
            vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)],
            vec![
                Vector3::new(a.sin(), 0.0, a.cos()),
                Vector3::new(-a.sin(), 0.0, a.cos()),
            ],
        )
        .unwrap();
        assert!((c.feature().into_inner() - Vector3::z()).norm() < 1e-12);
        assert!((c.feature_spread_rad() - a).abs() < 1e-12);
        assert!((c.length() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn path_refuses_duplicate_ids_and_empty() {
        let c = Contour::new(1, vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)], z()).unwrap();
        assert!(Path::new(vec![c.clone(), c.clone()]).is_err());
        assert!(Path::new(vec![]).is_err());
        let p = Path::new(vec![c]).unwrap();
        assert_eq!(p.num_points(), 2);
        assert!(p.get(1).is_some());
    }
}
