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

/// The template path's default point spacing along contours (domain arc length), mm.
pub const DEFAULT_PATH_SPACING_MM: f64 = 0.25;

/// Point spacing of the demo's hatch boundary, mm.
pub(crate) const PATH_STEP_MM: f64 = DEFAULT_PATH_SPACING_MM;

/// Central-difference step for Jacobians, mm.
pub(crate) const JACOBIAN_STEP_MM: f64 = 1e-4;

/// The smooth deformation of the part, in the CAD frame (mm): a shrinkage that changes along the
/// span (a density gradient from pressing), a per-axis scale about the origin along the pressing
/// axes (the shrinkage of a pressed and sintered core,
/// `Σᵢ scaleᵢ (aᵢ·p) aᵢ = R·diag(scale)·Rᵀ·p` with `aᵢ = R·eᵢ`), then a twist about the Y (long)
/// axis growing linearly along Y, then a bend along Z, then a curl of the `+Y` end along Z.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Deformation {
    /// Scale along the three pressing axes (`pressing_axes`, in order).
    pub scale: Vector3,
    /// The pressing axes, CAD frame: row `i` is the unit axis `scale[i]` acts along (the rows
    /// of a rotation). The identity (scale along the CAD axes) in cases written before it
    /// existed and when `pressing_tilt_deg` is 0.
    #[serde(default = "identity_axes")]
    pub pressing_axes: [[f64; 3]; 3],
    /// Twist end to end over [`LENGTH_MM`], radians.
    pub twist_rad: f64,
    /// Bend: the rise of mid-length over the ends along Z, mm (the sections turn with it, as
    /// a beam's do).
    pub sag_mm: f64,
    /// Curl of the free `+Y` end along Z, mm: a sintered core's ends warp on their own (the
    /// bend is not a parabola), rising as the cube of the distance past
    /// [`TIP_CURL_START`] of the half length, this much at the end. 0 in cases written
    /// before it existed.
    #[serde(default)]
    pub tip_curl_mm: f64,
    /// The bend's (and the curl's) direction, turned this far from Z toward X, radians: the
    /// mid-plane moves by `w(y)·(sin, 0, cos)` and the sections turn with it. 0 in cases written
    /// before it existed.
    #[serde(default)]
    pub bend_tilt_rad: f64,
    /// The change of the part's linear shrinkage along its span, from the `−Y` end to the `+Y`
    /// end over [`LENGTH_MM`] (a pressed core's green density, and so its shrinkage, varies
    /// from the end the powder entered to the other): the material at `y` grows by
    /// `1 + g·y/LENGTH_MM` in every direction, so the span stretches as `y + g·y²/(2·LENGTH_MM)`
    /// and the sections scale with it. Applied before the per-axis scale. An affine map cannot
    /// undo it. 0 in cases written before it existed.
    #[serde(default)]
    pub shrink_gradient: f64,
}

/// Where the tip curl starts, as a share of the half length from the middle.
pub const TIP_CURL_START: f64 = 0.4;

impl Deformation {
    /// No deformation.
    #[must_use]
    pub fn identity() -> Self {
        Deformation {
            scale: Vector3::new(1.0, 1.0, 1.0),
            pressing_axes: identity_axes(),
            twist_rad: 0.0,
            sag_mm: 0.0,
            tip_curl_mm: 0.0,
            bend_tilt_rad: 0.0,
            shrink_gradient: 0.0,
        }
    }

    /// The scale part alone, CAD frame: `R·diag(scale)·Rᵀ`.
    #[must_use]
    pub fn scale_matrix(&self) -> Matrix3<f64> {
        let r = Matrix3::from_columns(&self.pressing_axes.map(Vector3::from));
        r * Matrix3::from_diagonal(&self.scale) * r.transpose()
    }

    /// The deformed position of a CAD-frame point.
    #[must_use]
    pub fn apply(&self, p_cad: &Point3) -> Point3 {
        // The shrinkage along the span: left out when 0, so cases without it are what they were
        // bit for bit.
        let p = if self.shrink_gradient == 0.0 {
            p_cad.coords
        } else {
            let y = p_cad.y;
            let grow = 1.0 + self.shrink_gradient * y / LENGTH_MM;
            Vector3::new(
                p_cad.x * grow,
                y + self.shrink_gradient * y * y / (2.0 * LENGTH_MM),
                p_cad.z * grow,
            )
        };
        // Σᵢ sᵢ (aᵢ·p) aᵢ, summed axis by axis: with the identity axes this is the per-axis
        // product bit for bit, so cases without a pressing tilt are what they were.
        let mut s = Vector3::zeros();
        for (axis, scale) in self.pressing_axes.iter().zip(self.scale.iter()) {
            let a = Vector3::from(*axis);
            s += a * (scale * a.dot(&p));
        }
        let phi = self.twist_rad * s.y / LENGTH_MM;
        let (sin, cos) = phi.sin_cos();
        let x = cos * s.x - sin * s.z;
        let z = sin * s.x + cos * s.z;
        // The bend and the curl as a beam bends (Euler–Bernoulli): the mid-plane moves by
        // `w(y)` along the bend direction `b` and each cross-section turns with it, so a point
        // `p·b` off the mid-plane moves back along the length by `(p·b)·w′(y)` (shifting the
        // sections without turning them would shear the material by the slope, over 1 % at the
        // ends of a 0.3 mm sag).
        let t = 2.0 * s.y / LENGTH_MM;
        let dt_dy = 2.0 / LENGTH_MM;
        let span = 1.0 - TIP_CURL_START;
        let curl = ((t - TIP_CURL_START) / span).max(0.0);
        let w = self.sag_mm * (1.0 - t * t) + self.tip_curl_mm * curl.powi(3);
        let slope = (self.sag_mm * -2.0 * t + self.tip_curl_mm * 3.0 * curl * curl / span) * dt_dy;
        let (sin_b, cos_b) = self.bend_tilt_rad.sin_cos();
        let lever = x * sin_b + z * cos_b;
        Point3::new(x + w * sin_b, s.y - lever * slope, z + w * cos_b)
    }
}

fn identity_axes() -> [[f64; 3]; 3] {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
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

    /// The two half-circle arcs of the rim as `[start, end)` in arc length ([`Cutout::rim`]'s
    /// order: right side, top arc, left side, bottom arc), mm.
    fn arcs(&self) -> [(f64, f64); 2] {
        let (a, half_arc) = (self.half_length_mm, std::f64::consts::PI * self.radius_mm);
        [
            (2.0 * a, 2.0 * a + half_arc),
            (4.0 * a + half_arc, self.perimeter()),
        ]
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

    /// The sampled area (domain), mm².
    pub(crate) fn area(&self) -> f64 {
        *self.cumulative_area.last().unwrap_or(&0.0)
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

/// A top-face edge a contour follows, domain `(u, v)` plane: a cutout's rim (closed) or a
/// straight stretch of the outer boundary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Edge {
    /// A hole's or slot's rim, counter-clockwise from `+u` ([`Cutout::rim`]).
    Rim(Cutout),
    /// From `.0` to `.1`, the material on the left.
    Segment([f64; 2], [f64; 2]),
}

impl Edge {
    /// Length, mm.
    pub(crate) fn length(&self) -> f64 {
        match self {
            Edge::Rim(c) => c.perimeter(),
            Edge::Segment(a, b) => (b[0] - a[0]).hypot(b[1] - a[1]),
        }
    }

    /// The point at arc length `s` (mm from the start), and the unit normal out of the
    /// material, domain plane.
    pub(crate) fn at(&self, s: f64) -> ([f64; 2], [f64; 2]) {
        match self {
            Edge::Rim(c) => c.rim(s),
            Edge::Segment(..) => self.at_step_of(s / self.length(), 1),
        }
    }

    /// The curvature of the arcs, 1/mm: a rim's arcs bend toward the side out of the material,
    /// so a strip reaching out by `t` from them is `1 − κt` as long as its foot; 0 for a
    /// segment.
    pub(crate) fn arc_curvature(&self) -> f64 {
        match self {
            Edge::Rim(c) => 1.0 / c.radius_mm,
            Edge::Segment(..) => 0.0,
        }
    }

    /// Whether arc length `s` (mm from the start, `0 ≤ s ≤` the length) lies on an arc (of
    /// curvature [`Self::arc_curvature`]) rather than on a straight stretch.
    pub(crate) fn on_arc(&self, s: f64) -> bool {
        match self {
            Edge::Rim(c) => {
                let s = s.rem_euclid(c.perimeter());
                c.arcs().iter().any(|&(lo, hi)| (lo..hi).contains(&s))
            }
            Edge::Segment(..) => false,
        }
    }

    /// How much of `[s0, s1]` (`0 ≤ s0 ≤ s1 ≤` the length) lies on the arcs, mm.
    #[cfg(test)]
    pub(crate) fn arc_length_within(&self, s0: f64, s1: f64) -> f64 {
        match self {
            Edge::Rim(c) => c
                .arcs()
                .iter()
                .map(|&(lo, hi)| (s1.min(hi) - s0.max(lo)).max(0.0))
                .sum(),
            Edge::Segment(..) => 0.0,
        }
    }

    /// The point `k / n` of the way along (and the normal), computed as the template path
    /// always has (bit for bit).
    pub(crate) fn at_step(&self, k: usize, n: usize) -> ([f64; 2], [f64; 2]) {
        self.at_step_of(k as f64, n)
    }

    fn at_step_of(&self, k: f64, n: usize) -> ([f64; 2], [f64; 2]) {
        match self {
            Edge::Rim(c) => c.rim(c.perimeter() * k / n as f64),
            Edge::Segment(a, b) => {
                let len = self.length();
                let t = k / n as f64;
                (
                    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])],
                    [(b[1] - a[1]) / len, -(b[0] - a[0]) / len],
                )
            }
        }
    }

    /// Where a domain-plane point is relative to the edge: `(s, t)` with `s` the arc length of
    /// its foot on the edge (mm from the start) and `t` its distance out of the material along
    /// the edge's normal (negative inside), mm. The inverse of `at(s) + t·normal(s)` for
    /// `t` below a rim's radius. (The tests check burr points with it.)
    #[cfg(test)]
    pub(crate) fn locate(&self, u: f64, v: f64) -> (f64, f64) {
        match self {
            Edge::Segment(a, _) => {
                let (_, n) = self.at(0.0);
                let d = [-n[1], n[0]];
                let q = [u - a[0], v - a[1]];
                (q[0] * d[0] + q[1] * d[1], q[0] * n[0] + q[1] * n[1])
            }
            Edge::Rim(c) => {
                let (r, a) = (c.radius_mm, c.half_length_mm);
                let t = r - c.distance_to_axis(u, v);
                let (du, dv) = (u - c.u_mm, v - c.v_mm);
                let pi = std::f64::consts::PI;
                let s = if dv.abs() <= a {
                    if du >= 0.0 {
                        dv + a
                    } else {
                        2.0 * a + pi * r + (a - dv)
                    }
                } else if dv > a {
                    2.0 * a + r * (dv - a).atan2(du)
                } else {
                    // The lower arc, angles (π, 2π) from +u.
                    4.0 * a + pi * r + r * ((dv + a).atan2(du) + pi)
                };
                (s, t)
            }
        }
    }
}

/// The top-face edges the template path follows, in contour-id order (id = index + 1): every
/// cutout's rim, then the outer boundary's four edges with the long ones split at mid-length
/// (six strip edges), counter-clockwise.
pub(crate) fn contour_edges(cutouts: &[Cutout]) -> Vec<Edge> {
    let (w2, l2) = (WIDTH_MM / 2.0, LENGTH_MM / 2.0);
    let mut edges: Vec<Edge> = cutouts.iter().map(|c| Edge::Rim(*c)).collect();
    edges.extend(
        [
            ([-w2, -l2], [w2, -l2]),
            ([w2, -l2], [w2, 0.0]),
            ([w2, 0.0], [w2, l2]),
            ([w2, l2], [-w2, l2]),
            ([-w2, l2], [-w2, 0.0]),
            ([-w2, 0.0], [-w2, -l2]),
        ]
        .map(|(a, b)| Edge::Segment(a, b)),
    );
    edges
}

/// How many segments a contour along `edge` has at `spacing_mm` (rims at least 24).
pub(crate) fn contour_segments(edge: &Edge, spacing_mm: f64) -> usize {
    let n = (edge.length() / spacing_mm).ceil() as usize;
    match edge {
        Edge::Rim(_) => n.max(24),
        Edge::Segment(..) => n.max(1),
    }
}

/// The top-face contours along [`contour_edges`] (ids from 1), a point every `spacing_mm` or
/// less of domain arc length (rims closed, at least 24 segments), feature vectors the top
/// face's normal.
pub(crate) fn template_path(cutouts: &[Cutout], spacing_mm: f64) -> Result<Path> {
    let top = THICKNESS_MM / 2.0;
    let design = |p: &Point3| design_point(p.x, p.y, p.z);
    let up = Vector3::z();
    let mut contours = Vec::new();
    for (id, edge) in (1..).zip(contour_edges(cutouts)) {
        let n = contour_segments(&edge, spacing_mm);
        let domain: Vec<Point3> = (0..=n)
            .map(|k| {
                let (p, _) = edge.at_step(k, n);
                Point3::new(p[0], p[1], top)
            })
            .collect();
        let points: Vec<Point3> = domain.iter().map(design).collect();
        let features: Vec<Vector3> = domain
            .iter()
            .map(|d| mapped_normal(&design, d, &up))
            .collect();
        contours.push(Contour::with_features(id, points, features)?);
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

/// Pieces of a surface by area, to pick one in proportion to its area (the burrs' webs, the
/// films over openings).
#[derive(Debug, Clone, Default)]
pub(crate) struct AreaTable {
    cumulative: Vec<f64>,
}

impl AreaTable {
    /// Adds a piece of `area` mm².
    pub(crate) fn push(&mut self, area: f64) {
        let total = self.total();
        self.cumulative.push(total + area);
    }

    /// The pieces' total area, mm².
    pub(crate) fn total(&self) -> f64 {
        *self.cumulative.last().unwrap_or(&0.0)
    }

    /// Piece `i`'s area, mm².
    pub(crate) fn area_of(&self, i: usize) -> f64 {
        self.cumulative[i] - if i == 0 { 0.0 } else { self.cumulative[i - 1] }
    }

    /// A piece drawn in proportion to its area (one draw of `rng`). Only called when
    /// [`Self::total`] is positive.
    pub(crate) fn pick(&self, rng: &mut impl Rng) -> usize {
        let pick = rng.random_range(0.0..self.total());
        self.cumulative
            .partition_point(|&a| a <= pick)
            .min(self.cumulative.len() - 1)
    }
}
