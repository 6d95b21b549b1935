//! The part: the slab's dimensions, its holes and slots, the design map from domain coordinates
//! to the CAD frame with exact normals, the deformation, surface sampling, the template path and
//! the demo's hatch region.

use nalgebra::Matrix3;
use rand::Rng;
use trim_geom::{Contour, Path, Point3, Result, Vector3};

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

/// Path point spacing along contours, mm.
pub(crate) const PATH_STEP_MM: f64 = 0.25;

/// Central-difference step for Jacobians, mm.
pub(crate) const JACOBIAN_STEP_MM: f64 = 1e-4;

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
    pub(crate) fn distance_to_axis(&self, u: f64, v: f64) -> f64 {
        let dv = (v - self.v_mm).abs() - self.half_length_mm;
        let du = u - self.u_mm;
        if dv <= 0.0 { du.abs() } else { du.hypot(dv) }
    }

    pub(crate) fn contains(&self, u: f64, v: f64) -> bool {
        self.distance_to_axis(u, v) < self.radius_mm
    }

    pub(crate) fn perimeter(&self) -> f64 {
        4.0 * self.half_length_mm + 2.0 * std::f64::consts::PI * self.radius_mm
    }

    /// The rim point at arc length `s` (counter-clockwise in `(u, v)` starting at `+u`), and the
    /// unit normal pointing out of the material (into the cutout).
    pub(crate) fn rim(&self, s: f64) -> ([f64; 2], [f64; 2]) {
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
pub(crate) fn mapped_normal(
    map: &impl Fn(&Point3) -> Point3,
    domain: &Point3,
    n_domain: &Vector3,
) -> Vector3 {
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
pub(crate) struct DomainSample {
    pub(crate) point: Point3,
    pub(crate) normal: Vector3,
}

/// Samples the part's surface uniformly in domain area (top, bottom, outer walls, cutout walls).
pub(crate) struct SurfaceSampler {
    pub(crate) cutouts: Vec<Cutout>,
    pub(crate) cumulative_area: Vec<f64>,
}

impl SurfaceSampler {
    pub(crate) fn new(cutouts: Vec<Cutout>) -> Self {
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

    pub(crate) fn in_material(&self, u: f64, v: f64) -> bool {
        !self.cutouts.iter().any(|c| c.contains(u, v))
    }

    pub(crate) fn sample(&self, rng: &mut impl Rng) -> DomainSample {
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

/// The top-face contours: one per cutout rim (closed), and the four outer edges, the long ones
/// split at mid-length (six strip edges). Ids count from 1 in that order.
pub(crate) fn template_path(cutouts: &[Cutout]) -> Result<Path> {
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
pub(crate) fn map_contour(c: &Contour, map: &impl Fn(&Point3) -> Point3) -> Result<Contour> {
    let points: Vec<Point3> = c.points().iter().map(map).collect();
    let features: Vec<Vector3> = c
        .points()
        .iter()
        .zip(c.features())
        .map(|(p, f)| mapped_normal(map, p, f))
        .collect();
    Contour::with_features(c.id(), points, features)
}
