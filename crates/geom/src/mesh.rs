//! Triangle meshes on parry3d: area, area-weighted sampling with normals, point-to-mesh distance.
//!
//! A [`Mesh`] keeps every vertex and triangle it was given (so a file round-trips), but its
//! surface, the thing that is sampled and measured against, is the union of its non-degenerate
//! triangles: a triangle whose area is below [`DEGENERATE_TRIANGLE_REL_AREA`] times its longest
//! edge squared has no defined normal and no area to sample, so it is left out of the parry
//! [`TriMesh`] used for queries. [`Mesh::degenerate_triangles`] says how many were left out.

use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::TriMesh;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::sync::OnceLock;

use crate::cloud::{Aabb, PointCloud};
use crate::error::{GeomError, Result};
use crate::math::{Point3, Vector3, is_finite_point};

/// A triangle whose area is below this fraction of its longest edge squared is degenerate (a
/// sliver or a repeated vertex): it has no defined normal and is left out of the query surface.
pub const DEGENERATE_TRIANGLE_REL_AREA: f64 = 1e-12;

/// A triangle mesh in millimetres. Triangles index into the vertices; their vertex order gives the
/// face normal by the right-hand rule.
#[derive(Clone)]
pub struct Mesh {
    vertices: Vec<Point3>,
    triangles: Vec<[u32; 3]>,
    /// The non-degenerate triangles.
    surface_indices: Vec<[u32; 3]>,
    /// Their parry mesh, for queries: built on the first query (its BVH is most of the cost of
    /// loading a CAD that is only sampled, as registration does).
    surface: OnceLock<TriMesh>,
    /// For each triangle of `surface`, its index in `triangles`.
    surface_to_triangle: Vec<u32>,
    /// Cumulative areas of the `surface` triangles (mm²), for sampling.
    cumulative_area_mm2: Vec<f64>,
    /// The unit normal of each `surface` triangle.
    surface_normals: Vec<Vector3>,
}

impl std::fmt::Debug for Mesh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mesh")
            .field("vertices", &self.vertices.len())
            .field("triangles", &self.triangles.len())
            .field("degenerate_triangles", &self.degenerate_triangles())
            .finish()
    }
}

impl PartialEq for Mesh {
    fn eq(&self, other: &Self) -> bool {
        self.vertices == other.vertices && self.triangles == other.triangles
    }
}

impl Mesh {
    /// A mesh of `vertices` (mm) and `triangles` (indices into `vertices`).
    ///
    /// Refuses: no triangles; a NaN or infinite vertex (named by index); a triangle index out of
    /// range (named by triangle); more than `u32::MAX` vertices; a triangle whose area overflows;
    /// and a mesh whose triangles are all degenerate (it has no surface).
    pub fn new(vertices: Vec<Point3>, triangles: Vec<[u32; 3]>) -> Result<Mesh> {
        if triangles.is_empty() {
            return Err(GeomError::TooFewPoints {
                what: "mesh (triangles)".into(),
                needed: 1,
                got: 0,
            });
        }
        if u32::try_from(vertices.len()).is_err() || u32::try_from(triangles.len()).is_err() {
            return Err(GeomError::invalid(
                "vertices",
                format!(
                    "{} vertices and {} triangles: at most 2^32 - 1 of each are supported",
                    vertices.len(),
                    triangles.len()
                ),
            ));
        }
        if let Some(index) = vertices.iter().position(|p| !is_finite_point(p)) {
            return Err(GeomError::NonFinite {
                what: "vertex",
                index,
            });
        }
        let mut surface_indices = Vec::with_capacity(triangles.len());
        let mut surface_to_triangle = Vec::with_capacity(triangles.len());
        let mut cumulative_area_mm2 = Vec::with_capacity(triangles.len());
        let mut surface_normals = Vec::with_capacity(triangles.len());
        let mut total_mm2 = 0.0;
        for (t, tri) in triangles.iter().enumerate() {
            let [a, b, c] = corners(&vertices, *tri).ok_or_else(|| {
                GeomError::invalid(
                    "triangles",
                    format!(
                        "triangle {t} has indices {tri:?}, out of range for {} vertices",
                        vertices.len()
                    ),
                )
            })?;
            let cross = (b - a).cross(&(c - a));
            let area_mm2 = 0.5 * cross.norm();
            let longest_sq = (b - a)
                .norm_squared()
                .max((c - b).norm_squared())
                .max((a - c).norm_squared());
            if !area_mm2.is_finite() || !longest_sq.is_finite() {
                return Err(GeomError::NonFinite {
                    what: "triangle area (coordinates too large)",
                    index: t,
                });
            }
            let degenerate = area_mm2 <= DEGENERATE_TRIANGLE_REL_AREA * longest_sq;
            let Some(normal) = unit_along(&cross).filter(|_| !degenerate && area_mm2 > 0.0) else {
                continue;
            };
            surface_normals.push(normal);
            total_mm2 += area_mm2;
            surface_indices.push(*tri);
            // t < triangles.len(), checked above to fit in u32.
            surface_to_triangle.push(t as u32);
            cumulative_area_mm2.push(total_mm2);
        }
        if surface_indices.is_empty() {
            return Err(GeomError::invalid(
                "triangles",
                format!(
                    "all {} triangles are degenerate (zero area): the mesh has no surface",
                    triangles.len()
                ),
            ));
        }
        if !total_mm2.is_finite() {
            return Err(GeomError::invalid(
                "vertices",
                "the total area overflows: coordinates are too large",
            ));
        }
        // parry refuses only an empty index list (checked above): building it later cannot fail.
        Ok(Mesh {
            vertices,
            triangles,
            surface_indices,
            surface: OnceLock::new(),
            surface_to_triangle,
            cumulative_area_mm2,
            surface_normals,
        })
    }

    /// The vertices, millimetres.
    #[must_use]
    pub fn vertices(&self) -> &[Point3] {
        &self.vertices
    }

    /// The triangles as given, degenerate ones included.
    #[must_use]
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// How many triangles are degenerate and so left out of the query surface.
    #[must_use]
    pub fn degenerate_triangles(&self) -> usize {
        self.triangles.len() - self.surface_to_triangle.len()
    }

    /// The parry mesh of the non-degenerate triangles (for queries this type does not wrap).
    #[must_use]
    pub fn trimesh(&self) -> &TriMesh {
        self.surface.get_or_init(|| {
            TriMesh::new(self.vertices.clone(), self.surface_indices.clone())
                .expect("a mesh holds at least one non-degenerate triangle (checked in Mesh::new)")
        })
    }

    /// The bounding box of all vertices, millimetres.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::around(&self.vertices).unwrap_or(Aabb {
            min: Point3::origin(),
            max: Point3::origin(),
        })
    }

    /// The surface area, mm².
    #[must_use]
    pub fn area(&self) -> f64 {
        self.cumulative_area_mm2.last().copied().unwrap_or(0.0)
    }

    /// The unit normal of triangle `t` (an index into [`Mesh::triangles`]) by the right-hand
    /// rule, or `None` when `t` is out of range or the triangle is degenerate.
    #[must_use]
    pub fn face_normal(&self, t: usize) -> Option<Vector3> {
        let [a, b, c] = corners(&self.vertices, *self.triangles.get(t)?)?;
        unit_along(&(b - a).cross(&(c - a)))
    }

    /// `n` points drawn uniformly over the surface (each triangle with probability proportional to
    /// its area, uniformly inside it), each with its triangle's unit normal. The same seed gives
    /// the same cloud.
    #[must_use]
    pub fn sample_area_weighted(&self, n: usize, seed: u64) -> PointCloud {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let total_mm2 = self.area();
        let surface_vertices = &self.vertices;
        let surface_indices = &self.surface_indices;
        // The draws in their fixed order (three per sample), then the triangle searches and the
        // points side by side: the same samples as one sequential pass, in a fraction of its
        // time (the search over the cumulative areas is most of it).
        let draws: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                let target = rng.random::<f64>() * total_mm2;
                let r1 = rng.random::<f64>().sqrt();
                let r2 = rng.random::<f64>();
                [target, r1, r2]
            })
            .collect();
        let (points, normals): (Vec<Point3>, Vec<Vector3>) = draws
            .par_iter()
            .map(|&[target, r1, r2]| {
                let s = self
                    .cumulative_area_mm2
                    .partition_point(|&c| c <= target)
                    .min(surface_indices.len() - 1);
                let [a, b, c] = surface_indices[s].map(|i| surface_vertices[i as usize]);
                // Uniform in the triangle: (1 − √r1) a + √r1 (1 − r2) b + √r1 r2 c.
                let p = a + (b - a) * (r1 * (1.0 - r2)) + (c - a) * (r1 * r2);
                (p, self.surface_normals[s])
            })
            .unzip();
        PointCloud::with_normals(points, normals)
            .expect("points are convex combinations of finite vertices; normals are non-degenerate")
    }

    /// The unsigned distance (mm) from `p` to the surface; NaN when `p` is not finite.
    #[must_use]
    pub fn distance(&self, p: &Point3) -> f64 {
        (self.closest_point(p).0 - p).norm()
    }

    /// The closest surface point to `p` and the unit normal of the triangle it lies on. On an edge
    /// or vertex shared by several triangles, the normal is that of one of them. A non-finite `p`
    /// has no closest point: both are returned as NaN (parry would panic on it).
    #[must_use]
    pub fn closest_point(&self, p: &Point3) -> (Point3, Vector3) {
        if !is_finite_point(p) {
            return (
                Point3::new(f64::NAN, f64::NAN, f64::NAN),
                Vector3::new(f64::NAN, f64::NAN, f64::NAN),
            );
        }
        let (projection, feature) = self.trimesh().project_local_point_and_get_feature(p);
        let normal = match feature {
            parry3d_f64::shape::FeatureId::Face(s) => self
                .surface_to_triangle
                .get(s as usize)
                .and_then(|&t| self.face_normal(t as usize)),
            _ => None,
        };
        let normal = normal.unwrap_or_else(|| {
            // parry names the triangle for every TriMesh projection; should it not, fall back to
            // the nearest triangle found by scanning, which is slower but exact.
            self.nearest_triangle_normal(&projection.point)
        });
        (projection.point, normal)
    }

    fn nearest_triangle_normal(&self, on_surface: &Point3) -> Vector3 {
        let mut best = (f64::INFINITY, Vector3::z());
        for t in 0..self.trimesh().num_triangles() {
            // t < num_triangles, which fits in u32.
            let tri = self.trimesh().triangle(t as u32);
            let d = tri.distance_to_local_point(on_surface, false);
            if d < best.0
                && let Some(n) = tri.normal()
            {
                best = (d, n.into_inner());
            }
        }
        best.1
    }
}

fn unit_along(v: &Vector3) -> Option<Vector3> {
    crate::math::unit_or_none(v, 0.0)
}

fn corners(vertices: &[Point3], tri: [u32; 3]) -> Option<[Point3; 3]> {
    Some([
        *vertices.get(tri[0] as usize)?,
        *vertices.get(tri[1] as usize)?,
        *vertices.get(tri[2] as usize)?,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit cube [0, 1]³ with outward normals.
    fn cube() -> Mesh {
        let v = (0..8)
            .map(|i| Point3::new(f64::from(i & 1), f64::from((i >> 1) & 1), f64::from(i >> 2)))
            .collect();
        let t = vec![
            [0, 2, 1],
            [1, 2, 3], // z = 0
            [4, 5, 6],
            [5, 7, 6], // z = 1
            [0, 1, 4],
            [1, 5, 4], // y = 0
            [2, 6, 3],
            [3, 6, 7], // y = 1
            [0, 4, 2],
            [2, 4, 6], // x = 0
            [1, 3, 5],
            [3, 7, 5], // x = 1
        ];
        Mesh::new(v, t).unwrap()
    }

    #[test]
    fn refuses_empty_nan_out_of_range_and_all_degenerate() {
        let p = vec![
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        ];
        assert!(Mesh::new(p.clone(), vec![]).is_err());
        let e = Mesh::new(p.clone(), vec![[0, 1, 3]]).unwrap_err();
        assert!(e.to_string().contains("triangle 0"), "{e}");
        let mut nan = p.clone();
        nan[2].y = f64::NAN;
        let e = Mesh::new(nan, vec![[0, 1, 2]]).unwrap_err();
        assert!(e.to_string().contains("vertex 2"), "{e}");
        let e = Mesh::new(p.clone(), vec![[0, 1, 1]]).unwrap_err();
        assert!(e.to_string().contains("degenerate"), "{e}");
        let huge = vec![
            Point3::new(-1e300, 0.0, 0.0),
            Point3::new(1e300, 0.0, 0.0),
            Point3::new(0.0, 1e300, 0.0),
        ];
        assert!(Mesh::new(huge, vec![[0, 1, 2]]).is_err());
    }

    #[test]
    fn area_bounds_and_degenerate_count() {
        let m = cube();
        assert!((m.area() - 6.0).abs() < 1e-12);
        assert_eq!(m.bounds().max, Point3::new(1.0, 1.0, 1.0));
        assert_eq!(m.degenerate_triangles(), 0);
        let mut t = m.triangles().to_vec();
        t.push([0, 0, 1]);
        let m2 = Mesh::new(m.vertices().to_vec(), t).unwrap();
        assert_eq!(m2.degenerate_triangles(), 1);
        assert_eq!(m2.triangles().len(), 13);
        assert!((m2.area() - 6.0).abs() < 1e-12);
    }

    #[test]
    fn samples_lie_on_the_surface_with_outward_normals_and_are_deterministic() {
        let m = cube();
        let s = m.sample_area_weighted(3000, 7);
        assert_eq!(s.len(), 3000);
        assert_eq!(s, m.sample_area_weighted(3000, 7));
        assert_ne!(s, m.sample_area_weighted(3000, 8));
        let c = Point3::new(0.5, 0.5, 0.5);
        let normals = s.normals().unwrap();
        let mut per_face = [0usize; 6];
        for (p, n) in s.points().iter().zip(normals) {
            assert!(m.distance(p) < 1e-12, "{p}");
            // Outward: the normal is the axis along which p is farthest from the centre.
            let d = p - c;
            let axis = d.iamax();
            assert!((n[axis].abs() - 1.0).abs() < 1e-12 && n[axis] * d[axis] > 0.0);
            per_face[axis * 2 + usize::from(d[axis] > 0.0)] += 1;
        }
        // Equal areas: each face gets 500 ± 5 sigma (sigma = √(3000·1/6·5/6) ≈ 20.4).
        for count in per_face {
            assert!((398..=602).contains(&count), "{per_face:?}");
        }
    }

    #[test]
    fn tiny_triangles_sample_with_unit_normals() {
        // A 1e-7 mm triangle: its cross product (~1e-14) is below PointCloud's zero-normal
        // threshold unless normalised with care.
        let m = Mesh::new(
            vec![
                Point3::new(5.0, 5.0, 5.0),
                Point3::new(5.0 + 1e-7, 5.0, 5.0),
                Point3::new(5.0, 5.0 + 1e-7, 5.0),
            ],
            vec![[0, 1, 2]],
        )
        .unwrap();
        let s = m.sample_area_weighted(10, 1);
        for n in s.normals().unwrap() {
            assert!((n - Vector3::z()).norm() < 1e-9, "{n}");
        }
        assert!((m.face_normal(0).unwrap() - Vector3::z()).norm() < 1e-9);
    }

    #[test]
    fn distance_and_closest_point_match_the_cube() {
        let m = cube();
        let (q, n) = m.closest_point(&Point3::new(0.5, 0.25, 3.0));
        assert!((q - Point3::new(0.5, 0.25, 1.0)).norm() < 1e-12);
        assert!((n - Vector3::z()).norm() < 1e-12);
        assert!((m.distance(&Point3::new(0.5, 0.5, 0.5)) - 0.5).abs() < 1e-12);
        assert!((m.distance(&Point3::new(2.0, 2.0, 0.5)) - 2f64.sqrt()).abs() < 1e-12);
        assert!(m.distance(&Point3::new(f64::NAN, 0.0, 0.0)).is_nan());
        assert!(
            m.closest_point(&Point3::new(0.0, f64::INFINITY, 0.0))
                .1
                .x
                .is_nan()
        );
        let (q, n) = m.closest_point(&Point3::new(-4.0, 0.5, 0.5));
        assert!((q - Point3::new(0.0, 0.5, 0.5)).norm() < 1e-12);
        assert!((n + Vector3::x()).norm() < 1e-12);
    }
}
