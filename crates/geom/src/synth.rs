//! Synthetic ceramic-core-like test cases: a twisted, cambered 40 × 100 mm slab with holes and
//! slots, its trimming path, a deformed and re-posed scan of it, and the ground-truth path.
//!
//! The part is built in *domain* coordinates `(u, v, w)`: `u` across the width, `v` along the
//! length, `w` through the thickness, all millimetres, centred on 0. The design map
//! [`design_point`] bends this box into the CAD shape (camber across `u`, a design twist about the
//! long axis). Every sample is placed exactly on the analytic surface (holes and slots are exact
//! circles and stadiums), with its exact normal from the map's Jacobian (`n' ∝ J⁻ᵀ n`); the
//! triangle mesh is only for `cad.stl` and for the scanner's occlusion test.
//!
//! The deformed part is `deform(cad)` ([`Deformation`]: per-axis scale, twist about the long
//! axis, bend), placed by `scan_from_cad_true = scan_from_cad_nominal · fixture_error`. The scan
//! sees only the faces visible from the scanner (back-face and ray-cast occlusion), with Gaussian
//! noise, outliers and dropout patches. `truth` is the template path under the same map.

use nalgebra::{Matrix3, Translation3, UnitQuaternion};
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal, UnitSphere};
use rand_xoshiro::Xoshiro256PlusPlus;
use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};

use crate::cloud::PointCloud;
use crate::error::{GeomError, Result};
use crate::math::{Point3, Similarity3, Vector3};
use crate::path::{Contour, Path};

/// Slab width (along `u`), mm.
pub const WIDTH_MM: f64 = 40.0;
/// Slab length (along `v`), mm.
pub const LENGTH_MM: f64 = 100.0;
/// Slab thickness (along `w`), mm.
pub const THICKNESS_MM: f64 = 3.0;
/// Design camber: the mid-surface rises this much at `u = 0` over the long edges, mm.
pub const CAMBER_MM: f64 = 2.5;
/// Design twist about the long axis, end to end, degrees.
pub const DESIGN_TWIST_DEG: f64 = 12.0;
/// Mesh edge length on the faces, mm (chord error of the camber ≈ 2 µm).
const MESH_STEP_MM: f64 = 1.0;
/// Mesh edge length along hole and slot rims, mm.
const RIM_STEP_MM: f64 = 0.2;
/// Path point spacing along contours, mm.
const PATH_STEP_MM: f64 = 0.25;
/// Central-difference step for Jacobians, mm.
const JACOBIAN_STEP_MM: f64 = 1e-4;
/// The scanner sees a face only below this incidence, degrees.
const MAX_VIEW_INCIDENCE_DEG: f64 = 75.0;
/// Occlusion rays start this far toward the scanner, mm (clears the mesh's chord error).
const RAY_START_OFFSET_MM: f64 = 0.1;
/// Distance of the scanner from the part centre, mm.
const SCANNER_DISTANCE_MM: f64 = 300.0;

/// What to generate. Angles in degrees and lengths in millimetres (edge units).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Bend: the deformed mid-length rises this much over the ends, mm.
    pub sag_mm: f64,
    /// Twist about the long axis, end to end, degrees.
    pub twist_deg: f64,
    /// Per-axis scale is drawn from `[1 − r, 1 + r]`.
    pub scale_range: f64,
    /// Standard deviation of the Gaussian scan noise per coordinate, mm.
    pub noise_mm: f64,
    /// Number of scan points (before outliers are added).
    pub scan_points: usize,
    /// Number of CAD points.
    pub cad_points: usize,
    /// Fixture rotation error, degrees (drawn in `[½, 1] ×` this, random axis).
    pub pose_deg: f64,
    /// Fixture translation error, mm (drawn in `[½, 1] ×` this, random direction).
    pub pose_mm: f64,
    /// Outliers added, as a fraction of the scan points.
    pub outlier_fraction: f64,
    /// Number of dropout patches (balls of 1.5–3 mm radius with no scan points).
    pub dropouts: usize,
    /// Scanner tilt away from the part's +Z, degrees.
    pub scanner_tilt_deg: f64,
}

impl Default for SynthParams {
    fn default() -> Self {
        SynthParams {
            seed: 1,
            sag_mm: 0.3,
            twist_deg: 0.6,
            scale_range: 0.01,
            noise_mm: 0.01,
            scan_points: 200_000,
            cad_points: 200_000,
            pose_deg: 5.0,
            pose_mm: 3.0,
            outlier_fraction: 0.01,
            dropouts: 4,
            scanner_tilt_deg: 25.0,
        }
    }
}

impl SynthParams {
    /// Refuses out-of-range values, naming the field.
    pub fn validate(&self) -> Result<()> {
        let check = |name: &'static str, ok: bool, what: &str| {
            if ok {
                Ok(())
            } else {
                Err(GeomError::invalid(name, what.to_string()))
            }
        };
        check(
            "sag_mm",
            self.sag_mm.is_finite() && self.sag_mm.abs() <= 5.0,
            "must be finite, |sag| ≤ 5 mm",
        )?;
        check(
            "twist_deg",
            self.twist_deg.is_finite() && self.twist_deg.abs() <= 10.0,
            "must be finite, |twist| ≤ 10°",
        )?;
        check(
            "scale_range",
            (0.0..0.2).contains(&self.scale_range),
            "must be in [0, 0.2)",
        )?;
        check(
            "noise_mm",
            (0.0..=1.0).contains(&self.noise_mm),
            "must be in [0, 1] mm",
        )?;
        check(
            "scan_points",
            self.scan_points >= 1000,
            "must be at least 1000",
        )?;
        check(
            "cad_points",
            self.cad_points >= 1000,
            "must be at least 1000",
        )?;
        check(
            "pose_deg",
            (0.0..=45.0).contains(&self.pose_deg),
            "must be in [0, 45]°",
        )?;
        check(
            "pose_mm",
            (0.0..=50.0).contains(&self.pose_mm),
            "must be in [0, 50] mm",
        )?;
        check(
            "outlier_fraction",
            (0.0..=0.5).contains(&self.outlier_fraction),
            "must be in [0, 0.5]",
        )?;
        check(
            "scanner_tilt_deg",
            (0.0..=60.0).contains(&self.scanner_tilt_deg),
            "must be in [0, 60]°",
        )
    }
}

/// The smooth deformation of the part, in the CAD frame (mm): per-axis scale about the origin,
/// then a twist about the Y (long) axis growing linearly along Y, then a bend along Z.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Deformation {
    /// Scale along X, Y and Z.
    pub scale: Vector3,
    /// Twist end to end over [`LENGTH_MM`], radians.
    pub twist_rad: f64,
    /// Bend: the rise of mid-length over the ends along Z, mm.
    pub sag_mm: f64,
}

impl Deformation {
    /// No deformation.
    #[must_use]
    pub fn identity() -> Self {
        Deformation {
            scale: Vector3::new(1.0, 1.0, 1.0),
            twist_rad: 0.0,
            sag_mm: 0.0,
        }
    }

    /// The deformed position of a CAD-frame point.
    #[must_use]
    pub fn apply(&self, p_cad: &Point3) -> Point3 {
        let s = p_cad.coords.component_mul(&self.scale);
        let phi = self.twist_rad * s.y / LENGTH_MM;
        let (sin, cos) = phi.sin_cos();
        let x = cos * s.x - sin * s.z;
        let z = sin * s.x + cos * s.z;
        let t = 2.0 * s.y / LENGTH_MM;
        Point3::new(x, s.y, z + self.sag_mm * (1.0 - t * t))
    }
}

/// A hole (`half_length_mm = 0`) or a slot (a stadium along `v`) in domain coordinates.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cutout {
    /// Centre `u`, mm.
    pub u_mm: f64,
    /// Centre `v`, mm.
    pub v_mm: f64,
    /// Radius (half-width), mm.
    pub radius_mm: f64,
    /// Half-length of the straight part along `v`, mm (0 for a round hole).
    pub half_length_mm: f64,
}

impl Cutout {
    fn distance_to_axis(&self, u: f64, v: f64) -> f64 {
        let dv = (v - self.v_mm).abs() - self.half_length_mm;
        let du = u - self.u_mm;
        if dv <= 0.0 { du.abs() } else { du.hypot(dv) }
    }

    fn contains(&self, u: f64, v: f64) -> bool {
        self.distance_to_axis(u, v) < self.radius_mm
    }

    fn perimeter(&self) -> f64 {
        4.0 * self.half_length_mm + 2.0 * std::f64::consts::PI * self.radius_mm
    }

    /// The rim point at arc length `s` (counter-clockwise in `(u, v)` starting at `+u`), and the
    /// unit normal pointing out of the material (into the cutout).
    fn rim(&self, s: f64) -> ([f64; 2], [f64; 2]) {
        let (r, a) = (self.radius_mm, self.half_length_mm);
        let p = self.perimeter();
        let mut s = s.rem_euclid(p);
        // right side, going +v
        if s < 2.0 * a {
            return ([self.u_mm + r, self.v_mm - a + s], [-1.0, 0.0]);
        }
        s -= 2.0 * a;
        let half_arc = std::f64::consts::PI * r;
        if s < half_arc {
            let t = s / r;
            let (sn, cs) = t.sin_cos();
            return ([self.u_mm + r * cs, self.v_mm + a + r * sn], [-cs, -sn]);
        }
        s -= half_arc;
        if s < 2.0 * a {
            return ([self.u_mm - r, self.v_mm + a - s], [1.0, 0.0]);
        }
        s -= 2.0 * a;
        let t = std::f64::consts::PI + s / r;
        let (sn, cs) = t.sin_cos();
        ([self.u_mm + r * cs, self.v_mm - a + r * sn], [-cs, -sn])
    }
}

/// The holes and slots of the synthetic core: four slots (40–55 mm) and 42 round holes.
#[must_use]
pub fn cutouts() -> Vec<Cutout> {
    let mut out = Vec::new();
    for (u, len) in [(-10.0, 40.0), (-3.5, 55.0), (3.5, 48.0), (10.0, 44.0)] {
        out.push(Cutout {
            u_mm: u,
            v_mm: 0.0,
            radius_mm: 1.0,
            half_length_mm: len / 2.0 - 1.0,
        });
    }
    for u in [-16.0, 16.0] {
        for k in 0..13 {
            out.push(Cutout {
                u_mm: u,
                v_mm: -45.0 + 7.5 * f64::from(k),
                radius_mm: if k % 2 == 0 { 1.5 } else { 1.2 },
                half_length_mm: 0.0,
            });
        }
    }
    for u in [-10.0, -3.5, 3.5, 10.0] {
        for v in [-44.0, -36.0, 36.0, 44.0] {
            out.push(Cutout {
                u_mm: u,
                v_mm: v,
                radius_mm: 1.2,
                half_length_mm: 0.0,
            });
        }
    }
    out
}

/// The design map from domain coordinates `(u, v, w)` to the CAD frame (mm): a camber
/// `CAMBER_MM·(1 − (2u/W)²)` added to `w`, then the cross-section turned about the long axis by
/// `DESIGN_TWIST·v/L`.
#[must_use]
pub fn design_point(u: f64, v: f64, w: f64) -> Point3 {
    let c = 2.0 * u / WIDTH_MM;
    let z0 = CAMBER_MM * (1.0 - c * c) + w;
    let theta = DESIGN_TWIST_DEG.to_radians() * v / LENGTH_MM;
    let (sin, cos) = theta.sin_cos();
    Point3::new(cos * u - sin * z0, v, sin * u + cos * z0)
}

/// The unit normal of the image of a domain surface with domain normal `n_domain` under `map`
/// (`n' ∝ J⁻ᵀ n`, J by central differences).
fn mapped_normal(map: &impl Fn(&Point3) -> Point3, domain: &Point3, n_domain: &Vector3) -> Vector3 {
    let h = JACOBIAN_STEP_MM;
    let mut j = Matrix3::zeros();
    for axis in 0..3 {
        let mut e = Vector3::zeros();
        e[axis] = h;
        let d = (map(&(domain + e)) - map(&(domain - e))) / (2.0 * h);
        j.set_column(axis, &d);
    }
    let n = j
        .try_inverse()
        .map_or(*n_domain, |inv| inv.transpose() * n_domain);
    n.normalize()
}

/// One surface sample in domain coordinates with its domain normal.
struct DomainSample {
    point: Point3,
    normal: Vector3,
}

/// Samples the part's surface uniformly in domain area (top, bottom, outer walls, cutout walls).
struct SurfaceSampler {
    cutouts: Vec<Cutout>,
    cumulative_area: Vec<f64>,
}

impl SurfaceSampler {
    fn new(cutouts: Vec<Cutout>) -> Self {
        let face: f64 = WIDTH_MM * LENGTH_MM
            - cutouts
                .iter()
                .map(|c| {
                    std::f64::consts::PI * c.radius_mm.powi(2)
                        + 4.0 * c.half_length_mm * c.radius_mm
                })
                .sum::<f64>();
        let mut areas = vec![face, face, 2.0 * (WIDTH_MM + LENGTH_MM) * THICKNESS_MM];
        areas.extend(cutouts.iter().map(|c| c.perimeter() * THICKNESS_MM));
        let mut acc = 0.0;
        let cumulative_area = areas
            .iter()
            .map(|a| {
                acc += a;
                acc
            })
            .collect();
        SurfaceSampler {
            cutouts,
            cumulative_area,
        }
    }

    fn in_material(&self, u: f64, v: f64) -> bool {
        !self.cutouts.iter().any(|c| c.contains(u, v))
    }

    fn sample(&self, rng: &mut impl Rng) -> DomainSample {
        let total = *self.cumulative_area.last().unwrap_or(&1.0);
        let pick = rng.random_range(0.0..total);
        let piece = self.cumulative_area.partition_point(|&a| a <= pick);
        let half_t = THICKNESS_MM / 2.0;
        match piece {
            0 | 1 => loop {
                let u = rng.random_range(-WIDTH_MM / 2.0..WIDTH_MM / 2.0);
                let v = rng.random_range(-LENGTH_MM / 2.0..LENGTH_MM / 2.0);
                if self.in_material(u, v) {
                    let sign = if piece == 0 { 1.0 } else { -1.0 };
                    return DomainSample {
                        point: Point3::new(u, v, sign * half_t),
                        normal: Vector3::new(0.0, 0.0, sign),
                    };
                }
            },
            2 => {
                let (w2, l2) = (WIDTH_MM / 2.0, LENGTH_MM / 2.0);
                let mut s = rng.random_range(0.0..2.0 * (WIDTH_MM + LENGTH_MM));
                let w = rng.random_range(-half_t..half_t);
                let (point, normal) = if s < WIDTH_MM {
                    ((-w2 + s, -l2), (0.0, -1.0))
                } else {
                    s -= WIDTH_MM;
                    if s < LENGTH_MM {
                        ((w2, -l2 + s), (1.0, 0.0))
                    } else {
                        s -= LENGTH_MM;
                        if s < WIDTH_MM {
                            ((w2 - s, l2), (0.0, 1.0))
                        } else {
                            ((-w2, l2 - (s - WIDTH_MM)), (-1.0, 0.0))
                        }
                    }
                };
                DomainSample {
                    point: Point3::new(point.0, point.1, w),
                    normal: Vector3::new(normal.0, normal.1, 0.0),
                }
            }
            k => {
                let c = &self.cutouts[(k - 3).min(self.cutouts.len() - 1)];
                let (p, n) = c.rim(rng.random_range(0.0..c.perimeter()));
                DomainSample {
                    point: Point3::new(p[0], p[1], rng.random_range(-half_t..half_t)),
                    normal: Vector3::new(n[0], n[1], 0.0),
                }
            }
        }
    }
}

/// The domain triangulation of the part: vertices `(u, v, w)` and outward-oriented triangles.
struct DomainMesh {
    vertices: Vec<Point3>,
    triangles: Vec<[u32; 3]>,
}

fn domain_mesh(cutouts: &[Cutout]) -> Result<DomainMesh> {
    let (w2, l2) = (WIDTH_MM / 2.0, LENGTH_MM / 2.0);
    // Boundary loops in (u, v) with the out-of-material normal of each point.
    let mut loops: Vec<Vec<([f64; 2], [f64; 2])>> = Vec::new();
    let mut outer = Vec::new();
    let corners = [[-w2, -l2], [w2, -l2], [w2, l2], [-w2, l2]];
    for i in 0..4 {
        let (a, b) = (corners[i], corners[(i + 1) % 4]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / MESH_STEP_MM).ceil() as usize;
        let normal = [(b[1] - a[1]) / len, -(b[0] - a[0]) / len];
        for k in 0..n {
            let t = k as f64 / n as f64;
            outer.push(([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], normal));
        }
    }
    loops.push(outer);
    for c in cutouts {
        let n = ((c.perimeter() / RIM_STEP_MM).ceil() as usize).max(24);
        loops.push(
            (0..n)
                .map(|k| c.rim(c.perimeter() * k as f64 / n as f64))
                .collect(),
        );
    }
    let clearance = 0.6 * MESH_STEP_MM;
    let sampler = SurfaceSampler::new(cutouts.to_vec());
    let mut cdt: ConstrainedDelaunayTriangulation<Point2<f64>> =
        ConstrainedDelaunayTriangulation::new();
    let mut uv: Vec<[f64; 2]> = Vec::new();
    let mut loop_ids: Vec<Vec<usize>> = Vec::new();
    for l in &loops {
        let mut ids = Vec::with_capacity(l.len());
        for (p, _) in l {
            ids.push(insert(&mut cdt, &mut uv, *p)?);
        }
        loop_ids.push(ids);
    }
    let nu = (WIDTH_MM / MESH_STEP_MM).round() as i32;
    let nv = (LENGTH_MM / MESH_STEP_MM).round() as i32;
    for i in 1..nu {
        for j in 1..nv {
            let u = -w2 + f64::from(i) * MESH_STEP_MM;
            let v = -l2 + f64::from(j) * MESH_STEP_MM;
            let near_edge = u.abs() > w2 - clearance || v.abs() > l2 - clearance;
            let near_cutout = cutouts
                .iter()
                .any(|c| c.distance_to_axis(u, v) < c.radius_mm + clearance);
            if !near_edge && !near_cutout {
                insert(&mut cdt, &mut uv, [u, v])?;
            }
        }
    }
    for ids in &loop_ids {
        for k in 0..ids.len() {
            let (a, b) = (ids[k], ids[(k + 1) % ids.len()]);
            cdt.add_constraint(
                spade::handles::FixedVertexHandle::from_index(a),
                spade::handles::FixedVertexHandle::from_index(b),
            );
        }
    }
    let n = uv.len();
    let half_t = THICKNESS_MM / 2.0;
    let mut vertices: Vec<Point3> = uv.iter().map(|p| Point3::new(p[0], p[1], half_t)).collect();
    vertices.extend(uv.iter().map(|p| Point3::new(p[0], p[1], -half_t)));
    let idx = |i: usize| u32::try_from(i).unwrap_or(u32::MAX);
    let mut triangles = Vec::new();
    for face in cdt.inner_faces() {
        let vs = face.vertices().map(|v| v.fix().index());
        let c = [
            (uv[vs[0]][0] + uv[vs[1]][0] + uv[vs[2]][0]) / 3.0,
            (uv[vs[0]][1] + uv[vs[1]][1] + uv[vs[2]][1]) / 3.0,
        ];
        if !sampler.in_material(c[0], c[1]) {
            continue;
        }
        let (a, b) = (uv[vs[0]], uv[vs[1]]);
        let cc = uv[vs[2]];
        let ccw = (b[0] - a[0]) * (cc[1] - a[1]) - (b[1] - a[1]) * (cc[0] - a[0]) > 0.0;
        let (i0, i1, i2) = if ccw {
            (vs[0], vs[1], vs[2])
        } else {
            (vs[0], vs[2], vs[1])
        };
        triangles.push([idx(i0), idx(i1), idx(i2)]);
        triangles.push([idx(i0 + n), idx(i2 + n), idx(i1 + n)]);
    }
    for (l, ids) in loops.iter().zip(&loop_ids) {
        for k in 0..ids.len() {
            let k1 = (k + 1) % ids.len();
            let (a, b) = (ids[k], ids[k1]);
            let mid_normal = Vector3::new(l[k].1[0] + l[k1].1[0], l[k].1[1] + l[k1].1[1], 0.0);
            let (ta, tb, ba, bb) = (a, b, a + n, b + n);
            let tri_normal = (vertices[tb] - vertices[ta]).cross(&(vertices[ba] - vertices[ta]));
            if tri_normal.dot(&mid_normal) > 0.0 {
                triangles.push([idx(ta), idx(tb), idx(ba)]);
                triangles.push([idx(tb), idx(bb), idx(ba)]);
            } else {
                triangles.push([idx(ta), idx(ba), idx(tb)]);
                triangles.push([idx(tb), idx(ba), idx(bb)]);
            }
        }
    }
    Ok(DomainMesh {
        vertices,
        triangles,
    })
}

/// Inserts a domain point into the triangulation; returns its vertex index (an existing one for
/// a duplicate).
fn insert(
    cdt: &mut ConstrainedDelaunayTriangulation<Point2<f64>>,
    uv: &mut Vec<[f64; 2]>,
    p: [f64; 2],
) -> Result<usize> {
    let h = cdt
        .insert(Point2::new(p[0], p[1]))
        .map_err(|e| GeomError::invalid("synth mesh", format!("triangulation: {e:?}")))?;
    if h.index() == uv.len() {
        uv.push(p);
    }
    Ok(h.index())
}

/// A generated case. CAD-frame quantities are the nominal design; scan-frame ones are the
/// deformed, re-posed part.
#[derive(Debug, Clone)]
pub struct SynthCase {
    /// The parameters it was generated from.
    pub params: SynthParams,
    /// CAD mesh vertices, CAD frame, mm.
    pub cad_vertices: Vec<Point3>,
    /// CAD mesh triangles (indices into `cad_vertices`, counter-clockwise seen from outside).
    pub cad_triangles: Vec<[u32; 3]>,
    /// Points sampled uniformly on the exact CAD surface, with exact outward normals, CAD frame.
    pub cad_points: PointCloud,
    /// The template path, CAD frame: hole and slot rims on the top face, and the top face's
    /// outer edges (strip edges); feature vectors are the top-face normal at each point.
    pub path: Path,
    /// The scan, scan frame, without normals: visible faces only, noise, outliers, dropouts.
    pub scan: PointCloud,
    /// The template path on the deformed, re-posed part, scan frame (the ground truth).
    pub truth: Path,
    /// The fixture's nominal pose of the CAD in the scan frame (where registration starts).
    pub scan_from_cad_nominal: Similarity3,
    /// The true rigid placement of the deformed part: `scan = scan_from_cad_true · deform(cad)`.
    pub scan_from_cad_true: Similarity3,
    /// The deformation applied before the placement.
    pub deformation: Deformation,
    /// Where the scanner was, scan frame, mm.
    pub scanner_in_scan: Point3,
}

impl SynthCase {
    /// The CAD as a mesh.
    pub fn cad_mesh(&self) -> Result<crate::mesh::Mesh> {
        crate::mesh::Mesh::new(self.cad_vertices.clone(), self.cad_triangles.clone())
    }

    /// Writes the case into `dir` (created if missing): `cad.stl`, `cad_points.ply` (with
    /// normals), `path.csv`, `scan.ply`, `truth.csv`, and `case.json` (parameters, scanner
    /// position and the true transforms: `scanner_in_scan_mm` is what `trimctl register
    /// --viewpoint` takes, `scan_from_cad_nominal` the 16 numbers `--initial` reads from a text
    /// file, the rest is for tests).
    pub fn write_case(&self, dir: &std::path::Path) -> Result<()> {
        use crate::formats::{PlyEncoding, write_path, write_ply, write_stl};
        std::fs::create_dir_all(dir).map_err(|e| GeomError::io(dir, e))?;
        write_stl(&dir.join("cad.stl"), &self.cad_mesh()?)?;
        write_ply(
            &dir.join("cad_points.ply"),
            &self.cad_points,
            PlyEncoding::BinaryLittleEndian,
        )?;
        write_path(&dir.join("path.csv"), &self.path)?;
        write_ply(
            &dir.join("scan.ply"),
            &self.scan,
            PlyEncoding::BinaryLittleEndian,
        )?;
        write_path(&dir.join("truth.csv"), &self.truth)?;
        let m = |s: &Similarity3| {
            let h = s.to_homogeneous();
            [0, 1, 2, 3].map(|i| [0, 1, 2, 3].map(|j| h[(i, j)]))
        };
        let meta = CaseInfo {
            params: self.params.clone(),
            scanner_in_scan_mm: self.scanner_in_scan.coords.into(),
            scan_from_cad_nominal: m(&self.scan_from_cad_nominal),
            scan_from_cad_true: m(&self.scan_from_cad_true),
            deformation: self.deformation,
        };
        let text = serde_json::to_string_pretty(&meta)
            .map_err(|e| GeomError::invalid("case.json", e.to_string()))?;
        let path = dir.join("case.json");
        std::fs::write(&path, text).map_err(|e| GeomError::io(&path, e))
    }

    /// The true scan-frame position of a CAD-frame point (deformation, then placement).
    #[must_use]
    pub fn scan_from_cad_point(&self, p_cad: &Point3) -> Point3 {
        self.scan_from_cad_true * self.deformation.apply(p_cad)
    }
}

/// What `case.json` holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CaseInfo {
    /// The generator's parameters.
    pub params: SynthParams,
    /// The scanner position, scan frame, mm.
    pub scanner_in_scan_mm: [f64; 3],
    /// The fixture's nominal `scan_from_cad`, row-major 4×4.
    pub scan_from_cad_nominal: [[f64; 4]; 4],
    /// The true rigid placement of the deformed part, row-major 4×4.
    pub scan_from_cad_true: [[f64; 4]; 4],
    /// The deformation.
    pub deformation: Deformation,
}

/// The top-face contours: one per cutout rim (closed), and the four outer edges, the long ones
/// split at mid-length (six strip edges). Ids count from 1 in that order.
fn template_path(cutouts: &[Cutout]) -> Result<Path> {
    let top = THICKNESS_MM / 2.0;
    let design = |p: &Point3| design_point(p.x, p.y, p.z);
    let up = Vector3::z();
    let mut contours = Vec::new();
    let mut id = 1;
    let mut push = |domain: Vec<Point3>, id: &mut i64| -> Result<()> {
        let points: Vec<Point3> = domain.iter().map(design).collect();
        let features: Vec<Vector3> = domain
            .iter()
            .map(|d| mapped_normal(&design, d, &up))
            .collect();
        contours.push(Contour::with_features(*id, points, features)?);
        *id += 1;
        Ok(())
    };
    for c in cutouts {
        let n = ((c.perimeter() / PATH_STEP_MM).ceil() as usize).max(24);
        let domain: Vec<Point3> = (0..=n)
            .map(|k| {
                let (p, _) = c.rim(c.perimeter() * k as f64 / n as f64);
                Point3::new(p[0], p[1], top)
            })
            .collect();
        push(domain, &mut id)?;
    }
    let (w2, l2) = (WIDTH_MM / 2.0, LENGTH_MM / 2.0);
    let edges = [
        ([-w2, -l2], [w2, -l2]),
        ([w2, -l2], [w2, 0.0]),
        ([w2, 0.0], [w2, l2]),
        ([w2, l2], [-w2, l2]),
        ([-w2, l2], [-w2, 0.0]),
        ([-w2, 0.0], [-w2, -l2]),
    ];
    for (a, b) in edges {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / PATH_STEP_MM).ceil() as usize;
        let domain: Vec<Point3> = (0..=n)
            .map(|k| {
                let t = k as f64 / n as f64;
                Point3::new(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), top)
            })
            .collect();
        push(domain, &mut id)?;
    }
    Path::new(contours)
}

/// The demo's flash-film region on the top face, CAD frame: the rectangle `|u| ≤ 8`,
/// `30.5 ≤ v ≤ 33.5` mm, 3 mm clear of the slot ends and 1.3 mm of the end holes (no cutout inside), as a closed
/// contour (last point = first) with the face normal as feature vector, a point every
/// `PATH_STEP_MM`.
pub fn demo_hatch_boundary() -> Result<Contour> {
    let top = THICKNESS_MM / 2.0;
    let corners: [[f64; 2]; 5] = [
        [-8.0, 30.5],
        [8.0, 30.5],
        [8.0, 33.5],
        [-8.0, 33.5],
        [-8.0, 30.5],
    ];
    let mut domain = Vec::new();
    for w in corners.windows(2) {
        let (a, b) = (w[0], w[1]);
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / PATH_STEP_MM).ceil() as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            domain.push(Point3::new(
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                top,
            ));
        }
    }
    domain.push(domain[0]);
    let design = |p: &Point3| design_point(p.x, p.y, p.z);
    let points = domain.iter().map(design).collect();
    let features = domain
        .iter()
        .map(|d| mapped_normal(&design, d, &Vector3::z()))
        .collect();
    Contour::with_features(0, points, features)
}

/// The contour under a point map, with feature vectors mapped as normals (`J⁻ᵀ`).
fn map_contour(c: &Contour, map: &impl Fn(&Point3) -> Point3) -> Result<Contour> {
    let points: Vec<Point3> = c.points().iter().map(map).collect();
    let features: Vec<Vector3> = c
        .points()
        .iter()
        .zip(c.features())
        .map(|(p, f)| mapped_normal(map, p, f))
        .collect();
    Contour::with_features(c.id(), points, features)
}

/// Generates a case (deterministic in `params.seed`).
pub fn generate(params: &SynthParams) -> Result<SynthCase> {
    params.validate()?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(params.seed);
    let cutouts = cutouts();
    let sampler = SurfaceSampler::new(cutouts.clone());
    let mesh = domain_mesh(&cutouts)?;
    let cad_vertices: Vec<Point3> = mesh
        .vertices
        .iter()
        .map(|d| design_point(d.x, d.y, d.z))
        .collect();
    let design = |d: &Point3| design_point(d.x, d.y, d.z);

    // CAD points: exact surface, exact normals.
    let mut cad_pts = Vec::with_capacity(params.cad_points);
    let mut cad_normals = Vec::with_capacity(params.cad_points);
    for _ in 0..params.cad_points {
        let s = sampler.sample(&mut rng);
        cad_pts.push(design(&s.point));
        cad_normals.push(mapped_normal(&design, &s.point, &s.normal));
    }
    let cad_points = PointCloud::with_normals(cad_pts, cad_normals)?;
    let path = template_path(&cutouts)?;

    // Deformation and placement.
    let r = params.scale_range;
    let deformation = Deformation {
        scale: Vector3::new(
            1.0 + rng.random_range(-r..=r),
            1.0 + rng.random_range(-r..=r),
            1.0 + rng.random_range(-r..=r),
        ),
        twist_rad: params.twist_deg.to_radians() * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
        sag_mm: params.sag_mm * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
    };
    let axis: [f64; 3] = UnitSphere.sample(&mut rng);
    let dir: [f64; 3] = UnitSphere.sample(&mut rng);
    let angle = params.pose_deg.to_radians() * rng.random_range(0.5..=1.0);
    let shift = params.pose_mm * rng.random_range(0.5..=1.0);
    let fixture_error = Similarity3::from_parts(
        Translation3::from(Vector3::from(dir) * shift),
        UnitQuaternion::from_scaled_axis(Vector3::from(axis) * angle),
        1.0,
    );
    let scan_from_cad_nominal = Similarity3::identity();
    let scan_from_cad_true = scan_from_cad_nominal * fixture_error;
    let scan_from_domain = |d: &Point3| scan_from_cad_true * deformation.apply(&design(d));

    // The deformed mesh in the scan frame, for occlusion.
    let scan_vertices: Vec<Point3> = mesh.vertices.iter().map(scan_from_domain).collect();
    let trimesh = TriMesh::new(scan_vertices, mesh.triangles.clone())
        .map_err(|e| GeomError::invalid("synth mesh", format!("{e:?}")))?;
    let tilt = params.scanner_tilt_deg.to_radians();
    let view_in_cad =
        UnitQuaternion::from_scaled_axis(Vector3::new(tilt, 0.4 * tilt, 0.0)) * Vector3::z();
    let centre_in_scan = scan_from_cad_true * deformation.apply(&design_point(0.0, 0.0, 0.0));
    let scanner_in_scan =
        centre_in_scan + scan_from_cad_true.isometry.rotation * view_in_cad * SCANNER_DISTANCE_MM;
    let cos_max = MAX_VIEW_INCIDENCE_DEG.to_radians().cos();

    let mut visible = Vec::with_capacity(params.scan_points);
    let max_attempts = params.scan_points.saturating_mul(20);
    let mut attempts = 0usize;
    while visible.len() < params.scan_points && attempts < max_attempts {
        attempts += 1;
        let s = sampler.sample(&mut rng);
        let p = scan_from_domain(&s.point);
        let n = mapped_normal(&scan_from_domain, &s.point, &s.normal);
        let to_scanner = (scanner_in_scan - p).normalize();
        if n.dot(&to_scanner) < cos_max {
            continue;
        }
        let origin = p + to_scanner * RAY_START_OFFSET_MM;
        let ray = Ray::new(origin, to_scanner);
        if trimesh
            .cast_local_ray(&ray, SCANNER_DISTANCE_MM * 2.0, false)
            .is_some()
        {
            continue;
        }
        visible.push(p);
    }
    if visible.len() < params.scan_points {
        return Err(GeomError::TooFewPoints {
            what: "synthetic scan (visible samples)".into(),
            needed: params.scan_points,
            got: visible.len(),
        });
    }
    // Dropouts: balls around random visible points.
    let holes: Vec<(Point3, f64)> = (0..params.dropouts)
        .map(|_| {
            let c = visible[rng.random_range(0..visible.len())];
            (c, rng.random_range(1.5..3.0))
        })
        .collect();
    visible.retain(|p| holes.iter().all(|(c, r)| (p - c).norm() > *r));
    let noise = Normal::new(0.0, params.noise_mm.max(0.0))
        .map_err(|e| GeomError::invalid("noise_mm", e.to_string()))?;
    let mut scan_pts: Vec<Point3> = visible
        .iter()
        .map(|p| {
            p + Vector3::new(
                noise.sample(&mut rng),
                noise.sample(&mut rng),
                noise.sample(&mut rng),
            )
        })
        .collect();
    let n_outliers = (params.outlier_fraction * scan_pts.len() as f64).round() as usize;
    if let Some(bounds) = crate::cloud::Aabb::around(&scan_pts) {
        let lo = bounds.min - Vector3::repeat(2.0);
        let hi = bounds.max + Vector3::repeat(2.0);
        for _ in 0..n_outliers {
            scan_pts.push(Point3::new(
                rng.random_range(lo.x..hi.x),
                rng.random_range(lo.y..hi.y),
                rng.random_range(lo.z..hi.z),
            ));
        }
    }
    let scan = PointCloud::new(scan_pts)?;
    let truth_map = |p: &Point3| scan_from_cad_true * deformation.apply(p);
    let truth = Path::new(
        path.contours()
            .iter()
            .map(|c| map_contour(c, &truth_map))
            .collect::<Result<Vec<_>>>()?,
    )?;
    Ok(SynthCase {
        params: params.clone(),
        cad_vertices,
        cad_triangles: mesh.triangles,
        cad_points,
        path,
        scan,
        truth,
        scan_from_cad_nominal,
        scan_from_cad_true,
        deformation,
        scanner_in_scan,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small(seed: u64) -> SynthParams {
        SynthParams {
            seed,
            scan_points: 20_000,
            cad_points: 20_000,
            ..SynthParams::default()
        }
    }

    #[test]
    fn is_deterministic_in_the_seed() {
        let a = generate(&small(3)).unwrap();
        let b = generate(&small(3)).unwrap();
        let c = generate(&small(4)).unwrap();
        assert_eq!(a.scan.points(), b.scan.points());
        assert_ne!(a.scan.points(), c.scan.points());
    }

    #[test]
    fn has_the_advertised_shape() {
        let case = generate(&small(1)).unwrap();
        assert!((50..=60).contains(&case.path.len()), "{}", case.path.len());
        assert_eq!(case.truth.len(), case.path.len());
        // Outliers: 1 % of the inliers (within rounding).
        let n = case.scan.len();
        assert!(n > 19_000 && n < 20_300, "{n}");
        // CAD points lie on the mesh surface: every mesh vertex has a CAD point within 0.5 mm.
        let b = case.cad_points.bounds().unwrap();
        assert!((b.extent().y - LENGTH_MM).abs() < 0.5, "{b:?}");
        // Truth is the template under the true map.
        let p = case.path.contours()[0].points()[3];
        let t = case.truth.contours()[0].points()[3];
        assert!((case.scan_from_cad_point(&p) - t).norm() < 1e-12);
        // The slot rims are 40–55 mm long straight-ish contours: their perimeter ≥ 80 mm.
        assert!(case.path.contours()[1].length() > 100.0);
    }

    #[test]
    fn cad_normals_point_out_of_the_material() {
        let case = generate(&small(2)).unwrap();
        // A point pushed along its normal leaves the part: it is farther from the mid-surface
        // for top and bottom samples, or outside the footprint for wall samples. Check top ones:
        // their normals have a positive z after the design twist (≤ 6°) and camber (≤ 15°).
        let ns = case.cad_points.normals().unwrap();
        let ups = ns.iter().filter(|n| n.z > 0.9).count();
        let downs = ns.iter().filter(|n| n.z < -0.9).count();
        let ratio = ups as f64 / downs as f64;
        assert!((ratio - 1.0).abs() < 0.05, "{ups} up, {downs} down");
    }

    #[test]
    fn writes_a_case_that_reads_back() {
        let case = generate(&small(6)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        case.write_case(dir.path()).unwrap();
        let scan = crate::formats::read_points(&dir.path().join("scan.ply")).unwrap();
        assert_eq!(scan.len(), case.scan.len());
        let truth = crate::formats::read_path(&dir.path().join("truth.csv")).unwrap();
        assert_eq!(truth.len(), case.truth.len());
        let mesh = crate::formats::read_mesh(&dir.path().join("cad.stl")).unwrap();
        assert_eq!(mesh.triangles().len(), case.cad_triangles.len());
        let info: CaseInfo =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("case.json")).unwrap())
                .unwrap();
        assert_eq!(info.params, case.params);
    }

    #[test]
    fn mesh_is_closed() {
        let case = generate(&small(1)).unwrap();
        let mut edges = std::collections::HashMap::new();
        for t in &case.cad_triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a, b)).or_insert(0i32) += 1;
            }
        }
        // Every directed edge has exactly one opposite: closed and consistently oriented.
        for (&(a, b), &count) in &edges {
            assert_eq!(count, 1, "edge {a}-{b} used {count} times");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
        }
    }

    #[test]
    fn scan_sees_the_top_and_not_the_bottom() {
        let params = SynthParams {
            sag_mm: 0.0,
            twist_deg: 0.0,
            scale_range: 0.0,
            ..small(5)
        };
        let case = generate(&params).unwrap();
        let cad_from_scan = case.scan_from_cad_true.inverse();
        let theta_per_mm = DESIGN_TWIST_DEG.to_radians() / LENGTH_MM;
        let all = cutouts();
        let (mut top, mut bottom) = (0, 0);
        for p in case.scan.points() {
            // Undo the (identity) deformation and the design map: back to (u, v, w).
            let q = cad_from_scan * *p;
            let (sin, cos) = (theta_per_mm * q.y).sin_cos();
            let u = cos * q.x + sin * q.z;
            let z0 = -sin * q.x + cos * q.z;
            let c = 2.0 * u / WIDTH_MM;
            let w = z0 - CAMBER_MM * (1.0 - c * c);
            let clear = all
                .iter()
                .all(|k| k.distance_to_axis(u, q.y) > k.radius_mm + 0.2);
            if clear && u.abs() < 19.5 && q.y.abs() < 49.5 {
                if (w - THICKNESS_MM / 2.0).abs() < 0.05 {
                    top += 1;
                } else if (w + THICKNESS_MM / 2.0).abs() < 0.05 {
                    bottom += 1;
                }
            }
        }
        assert!(top > 10_000, "{top} points on the top face");
        assert_eq!(bottom, 0, "{bottom} scan points on the bottom face");
    }
}
