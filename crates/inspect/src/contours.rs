//! Where a point lies relative to the path's contours, CAD frame: the nearest contour, the arc
//! length of its foot on it and its distance from it.

use trim_geom::{Contour, ContourId, KdTree, Path, Point3, UnitVector3, Vector3};

use crate::error::{InspectError, Result};

/// A closed contour's last point lies within this of its first, mm.
pub const CLOSED_WITHIN_MM: f64 = 0.01;

/// One contour's geometry, CAD frame.
#[derive(Debug, Clone)]
pub struct ContourGeometry {
    /// The contour's id.
    pub id: ContourId,
    /// Its points, mm.
    pub points: Vec<Point3>,
    /// The arc length at each point from the first, mm.
    pub arc_mm: Vec<f64>,
    /// Whether it is closed (last point on the first).
    pub closed: bool,
    /// The mean feature vector (the face's normal where the contour follows a face's edge).
    pub feature: UnitVector3,
    /// Each point's unit feature vector.
    pub features: Vec<Vector3>,
}

impl ContourGeometry {
    /// The geometry of `contour`; refuses a non-finite point naming it.
    pub fn new(contour: &Contour) -> Result<ContourGeometry> {
        let points = contour.points().to_vec();
        if let Some(i) = points
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
        {
            return Err(InspectError::NonFinite {
                what: format!("path contour {}", contour.id()),
                index: i,
                value: format!("{:?}", points[i]),
            });
        }
        if points.len() < 2 {
            return Err(InspectError::Contour {
                contour: contour.id(),
                message: format!("needs at least 2 points, got {}", points.len()),
            });
        }
        let mut arc_mm = Vec::with_capacity(points.len());
        let mut acc = 0.0;
        arc_mm.push(0.0);
        for w in points.windows(2) {
            acc += (w[1] - w[0]).norm();
            arc_mm.push(acc);
        }
        if acc <= 0.0 {
            return Err(InspectError::Contour {
                contour: contour.id(),
                message: "has zero length".into(),
            });
        }
        let closed =
            points.len() > 2 && (points[points.len() - 1] - points[0]).norm() <= CLOSED_WITHIN_MM;
        Ok(ContourGeometry {
            id: contour.id(),
            points,
            arc_mm,
            closed,
            feature: contour.feature(),
            features: contour.features().to_vec(),
        })
    }

    /// Its length, mm.
    #[must_use]
    pub fn length_mm(&self) -> f64 {
        self.arc_mm.last().copied().unwrap_or(0.0)
    }

    /// The point at arc length `arc_mm` (clamped to the contour's ends; taken round a closed
    /// contour), mm.
    #[must_use]
    pub fn point_at(&self, arc_mm: f64) -> Point3 {
        let length = self.length_mm();
        let arc = if self.closed && length > 0.0 {
            arc_mm.rem_euclid(length)
        } else {
            arc_mm.clamp(0.0, length)
        };
        let k = self
            .arc_mm
            .partition_point(|a| *a <= arc)
            .clamp(1, self.points.len() - 1)
            - 1;
        let span = self.arc_mm[k + 1] - self.arc_mm[k];
        let t = if span > 0.0 {
            ((arc - self.arc_mm[k]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.points[k] + (self.points[k + 1] - self.points[k]) * t
    }

    /// The contour's curvature at `arc_mm`: the vector toward the centre of the circle through
    /// its points `half_mm` before, at and after it, its length that circle's curvature, 1/mm;
    /// zero where the three are in a line (or not distinct, as at an open contour's end).
    #[must_use]
    pub fn curvature_at(&self, arc_mm: f64, half_mm: f64) -> Vector3 {
        let b = self.point_at(arc_mm);
        let u = self.point_at(arc_mm - half_mm) - b;
        let v = self.point_at(arc_mm + half_mm) - b;
        let w = u.cross(&v);
        let w2 = w.norm_squared();
        if w2 <= COLLINEAR_AREA_MM2 * COLLINEAR_AREA_MM2 {
            return Vector3::zeros();
        }
        // The circumcentre, from b.
        let centre = (v * u.norm_squared() - u * v.norm_squared()).cross(&w) / (2.0 * w2);
        let r2 = centre.norm_squared();
        if r2 > 0.0 {
            centre / r2
        } else {
            Vector3::zeros()
        }
    }

    /// The foot of `p` on segment `k` (points `k`, `k + 1`): arc length, distance and rise (the
    /// offset of `p` from the foot along the feature vector there, interpolated), mm.
    fn foot_on(&self, k: usize, p: &Point3) -> (f64, f64, f64) {
        let (a, b) = (self.points[k], self.points[k + 1]);
        let ab = b - a;
        let len2 = ab.norm_squared();
        let t = if len2 > 0.0 {
            ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let foot = a + ab * t;
        let feature = (self.features[k] * (1.0 - t) + self.features[k + 1] * t)
            .try_normalize(1e-12)
            .unwrap_or(*self.feature);
        (
            self.arc_mm[k] + t * len2.sqrt(),
            (p - foot).norm(),
            (p - foot).dot(&feature),
        )
    }
}

/// Where a point lies: its contour (index into the path), the arc length of its foot on it and
/// its distance from it, mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Location {
    /// Index of the contour in the path.
    pub contour: usize,
    /// Arc length of the foot from the contour's first point, mm.
    pub arc_mm: f64,
    /// Distance from the contour (its nearest segment), mm.
    pub distance_mm: f64,
    /// Offset from the foot along the contour's feature vector there, mm (positive: above the
    /// face whose edge the contour follows).
    pub rise_mm: f64,
}

/// The path's contours with a kd-tree over their points.
#[derive(Debug)]
pub struct PathIndex {
    /// The contours, in path order.
    pub contours: Vec<ContourGeometry>,
    tree: KdTree,
    owner: Vec<(u32, u32)>,
}

impl PathIndex {
    /// The index of `path` (CAD frame). The tree holds the contours' points and, along
    /// segments longer than `TREE_STEP_MM`, points between them, so a point's nearest tree
    /// point lies on its nearest segment or on a neighbour of it.
    pub fn new(path: &Path) -> Result<PathIndex> {
        let contours = path
            .contours()
            .iter()
            .map(ContourGeometry::new)
            .collect::<Result<Vec<_>>>()?;
        let mut all = Vec::new();
        let mut owner = Vec::new();
        for (c, g) in contours.iter().enumerate() {
            let c = u32::try_from(c).unwrap_or(u32::MAX);
            for (k, w) in g.points.windows(2).enumerate() {
                let k = u32::try_from(k).unwrap_or(u32::MAX);
                let steps = ((w[1] - w[0]).norm() / TREE_STEP_MM).ceil().max(1.0) as usize;
                for j in 0..steps {
                    all.push(w[0] + (w[1] - w[0]) * (j as f64 / steps as f64));
                    owner.push((c, k));
                }
            }
        }
        Ok(PathIndex {
            contours,
            tree: KdTree::build(&all),
            owner,
        })
    }

    /// The nearest contour within `within_mm` of `p` (the contour of its nearest tree point;
    /// the foot on that point's segment and the segments either side), or none.
    #[must_use]
    pub fn locate(&self, p: &Point3, within_mm: f64) -> Option<Location> {
        let n = self.tree.nearest(p)?;
        if n.distance_sq.sqrt() > within_mm + TREE_STEP_MM {
            return None;
        }
        let (c, k) = self.owner[n.index];
        let (c, k) = (c as usize, k as usize);
        let g = &self.contours[c];
        let segments = g.points.len() - 1;
        let mut best = (f64::NAN, f64::INFINITY, 0.0);
        for s in [k.wrapping_sub(1), k, k + 1] {
            if s < segments {
                let f = g.foot_on(s, p);
                if f.1 < best.1 {
                    best = f;
                }
            }
        }
        (best.1 <= within_mm).then_some(Location {
            contour: c,
            arc_mm: best.0,
            distance_mm: best.1,
            rise_mm: best.2,
        })
    }
}

/// Three points spanning a triangle of less than this area (twice it: the cross product's
/// length, mm²) are taken as in a line.
const COLLINEAR_AREA_MM2: f64 = 1e-12;

/// The largest spacing of the path index's tree points along a segment, mm.
pub const TREE_STEP_MM: f64 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::Vector3;

    #[test]
    fn a_point_is_located_on_the_nearest_segment() {
        let square = Contour::new(
            7,
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(10.0, 0.0, 0.0),
                Point3::new(10.0, 10.0, 0.0),
                Point3::new(0.0, 10.0, 0.0),
                Point3::new(0.0, 0.0, 0.0),
            ],
            Vector3::z(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let path = Path::new(vec![square]).unwrap_or_else(|e| panic!("{e}"));
        let index = PathIndex::new(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(index.contours[0].closed);
        assert!((index.contours[0].length_mm() - 40.0).abs() < 1e-12);
        let l = index
            .locate(&Point3::new(10.3, 4.0, 0.0), 0.5)
            .unwrap_or_else(|| panic!("not located"));
        assert_eq!(l.contour, 0);
        assert!((l.arc_mm - 14.0).abs() < 1e-12, "{l:?}");
        assert!((l.distance_mm - 0.3).abs() < 1e-12, "{l:?}");
        assert!(index.locate(&Point3::new(5.0, 5.0, 0.0), 0.5).is_none());
        // Mid-way along a long segment.
        let l = index
            .locate(&Point3::new(5.0, 0.2, 0.1), 0.5)
            .unwrap_or_else(|| panic!("not located"));
        assert!((l.arc_mm - 5.0).abs() < 1e-12, "{l:?}");
        // Above the face (the feature is +Z) by 0.1 mm.
        assert!((l.rise_mm - 0.1).abs() < 1e-12, "{l:?}");
        let below = index
            .locate(&Point3::new(10.2, 3.0, -0.05), 0.5)
            .unwrap_or_else(|| panic!("not located"));
        assert!((below.rise_mm + 0.05).abs() < 1e-12, "{below:?}");
    }

    /// A circle of radius 1.2 mm in 96 chords: the curvature points to the centre and is
    /// 1/1.2 mm within 1 % (the chords lie up to 0.6 µm inside the circle, against the three
    /// points' 0.1 mm sagitta), all round (across the first point too); a straight contour has
    /// none.
    #[test]
    fn the_curvature_points_to_the_centre() {
        let n = 96;
        let r = 1.2;
        let points: Vec<Point3> = (0..=n)
            .map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / f64::from(n);
                Point3::new(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect();
        let circle = Contour::new(3, points, Vector3::z()).unwrap_or_else(|e| panic!("{e}"));
        let g = ContourGeometry::new(&circle).unwrap_or_else(|e| panic!("{e}"));
        assert!(g.closed);
        for arc in [0.0, 0.1, 3.0, g.length_mm() - 0.05] {
            let p = g.point_at(arc);
            let k = g.curvature_at(arc, 0.5);
            assert!((k.norm() * r - 1.0).abs() < 0.01, "{arc}: {k:?}");
            let toward = -p.coords.normalize();
            assert!(k.normalize().dot(&toward) > 0.999, "{arc}: {k:?} at {p:?}");
        }
        let line = Contour::new(
            4,
            vec![Point3::new(0.0, 0.0, 0.0), Point3::new(5.0, 0.0, 0.0)],
            Vector3::z(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let g = ContourGeometry::new(&line).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(g.curvature_at(2.0, 0.5), Vector3::zeros());
        assert_eq!(g.curvature_at(0.0, 0.5), Vector3::zeros());
        assert_eq!(g.point_at(7.0), Point3::new(5.0, 0.0, 0.0));
    }
}
