//! The surface model shared by both hatching methods: the best-fit plane of the patch (paper
//! §2.1 projects the cloud onto a plane too) and a smooth height field over it, fitted to the
//! scan by moving least squares.
//!
//! *Plane frame.* `e3` is the patch's least-variance direction (PCA), oriented to the input
//! normals when the cloud has them, else to world +Z (else +X); `e1` is world X projected onto
//! the plane (world Y when X is nearly normal), `e2 = e3 × e1`. A point is
//! `origin + s·e1 + t·e2 + f(s, t)·e3`; `(s, t)` are the *plane coordinates* (mm).
//!
//! *Height field.* A regular grid of spacing `h` over the boundary's box plus a margin. At each
//! node, a weighted quadratic `f + fs·ds + ft·dt + ½fss·ds² + fst·ds·dt + ½ftt·dt²` is fitted to
//! the scan points within a radius (weights `(1 − d²/r²)²`), then refitted without points whose
//! residual exceeds three robust standard deviations (outliers, hole walls). The surface at
//! `(s, t)` is the bilinear blend of the four surrounding nodes' quadratics, each evaluated at
//! `(s, t)` (exact for quadratic surfaces); its gradient, for normals, is the bilinear blend of
//! the nodes' fitted gradients (their curvature terms are too noisy to extrapolate).

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector6};
use rayon::prelude::*;
use trim_geom::{Point3, PointCloud, Vector3};

use super::HatchError;
use super::polygon::Polygon;

/// Scan points a node's fit needs; fewer and the radius grows.
pub const MIN_FIT_POINTS: usize = 12;
/// Grid spacing as a multiple of the mean point spacing inside the boundary.
pub const GRID_PER_SPACING: f64 = 2.5;
/// Initial fit radius as a multiple of the grid spacing.
pub const FIT_RADIUS_PER_GRID: f64 = 2.0;
/// How many times the fit radius may grow (×1.5 each) over gaps in the scan.
pub const FIT_RADIUS_GROWTH_STEPS: usize = 3;
/// The grid covers the boundary's box plus this many grid spacings on every side.
pub const GRID_MARGIN_CELLS: f64 = 4.0;
/// Scan points farther than this from the boundary's plane, beyond the boundary's own height
/// spread, are not on the patch (the far face of a thin part scanned from both sides), mm.
pub const LAYER_BAND_MM: f64 = 1.0;

/// Residuals beyond this many robust standard deviations (1.4826 × median) are dropped.
pub const OUTLIER_SIGMAS: f64 = 3.0;
/// Residuals below this (mm) are never dropped (a noise floor for very smooth scans).
pub const OUTLIER_FLOOR_MM: f64 = 0.02;
/// The steepest slope of the patch over its plane (tan 80°) before it is refused as folded.
pub const MAX_SLOPE: f64 = 5.67;

/// The best-fit plane frame of a patch (world frame, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFrame {
    /// The origin of the plane coordinates, world mm.
    pub origin: Point3,
    /// The plane's first axis (`s`), world, unit.
    pub e1: Vector3,
    /// The plane's second axis (`t`), world, unit.
    pub e2: Vector3,
    /// The plane normal (height `f`), world, unit; the side output normals point to.
    pub e3: Vector3,
}

impl PlaneFrame {
    /// The plane coordinates `(s, t)` of a world point (mm).
    #[must_use]
    pub fn to_plane(&self, p: &Point3) -> [f64; 2] {
        let d = p - self.origin;
        [d.dot(&self.e1), d.dot(&self.e2)]
    }

    /// The height of a world point over the plane (mm, along `e3`).
    #[must_use]
    pub fn height(&self, p: &Point3) -> f64 {
        (p - self.origin).dot(&self.e3)
    }

    /// The world point at plane coordinates `(s, t)` and height `f` (mm).
    #[must_use]
    pub fn to_world(&self, st: [f64; 2], f: f64) -> Point3 {
        self.origin + self.e1 * st[0] + self.e2 * st[1] + self.e3 * f
    }

    /// The world vector of a plane direction `(ds, dt)`.
    #[must_use]
    pub fn plane_vector(&self, d: [f64; 2]) -> Vector3 {
        self.e1 * d[0] + self.e2 * d[1]
    }

    /// The frame through the centroid of `points` with `e3` their least-variance direction,
    /// oriented toward `up` (world).
    fn fit(points: &[Point3], up: &Vector3) -> PlaneFrame {
        let n = points.len().max(1) as f64;
        let mean: Vector3 = points.iter().map(|p| p.coords).sum::<Vector3>() / n;
        let cov = points.iter().fold(Matrix3::zeros(), |acc, p| {
            let d = p.coords - mean;
            acc + d * d.transpose()
        });
        let eig = SymmetricEigen::new(cov);
        let imin = (0..3)
            .min_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))
            .unwrap_or(2);
        let mut e3: Vector3 = eig.eigenvectors.column(imin).into_owned();
        if !e3.iter().all(|c| c.is_finite()) || e3.norm() < 0.5 {
            e3 = Vector3::z();
        }
        e3 = e3.normalize();
        if e3.dot(up) < 0.0 {
            e3 = -e3;
        }
        let reference = if e3.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = (reference - e3 * reference.dot(&e3)).normalize();
        let e2 = e3.cross(&e1);
        PlaneFrame {
            origin: Point3::from(mean),
            e1,
            e2,
            e3,
        }
    }
}

/// A fitted node quadratic: `[f, fs, ft, fss, fst, ftt]` about the node (mm, mm/mm, 1/mm).
type Quad = [f64; 6];

/// The smooth height-field model of a scanned patch (see the module docs).
#[derive(Debug, Clone)]
pub struct Surface {
    frame: PlaneFrame,
    lo: [f64; 2],
    h: f64,
    nx: usize,
    ny: usize,
    nodes: Vec<Option<Quad>>,
    /// The scan points inside the boundary (world), for coverage and the slab method.
    inside: Vec<Point3>,
    /// The scan points near the patch (world): inside the boundary plus the margin.
    near: Vec<Point3>,
    spacing_mm: f64,
}

impl Surface {
    /// Fits the model to `cloud` over the region inside `boundary` (world points of a closed
    /// polyline; the last point may repeat the first). `grid_mm` overrides the grid spacing.
    pub fn fit(
        cloud: &PointCloud,
        boundary: &[Point3],
        grid_mm: Option<f64>,
    ) -> Result<Surface, HatchError> {
        let up = match cloud.normals() {
            Some(n) => n.iter().sum::<Vector3>(),
            None => Vector3::z(),
        };
        let up = if up.norm() > 1e-9 { up } else { Vector3::z() };
        // First frame from the boundary, then refined on the points it encloses.
        let mut frame = PlaneFrame::fit(boundary, &up);
        // The patch is one surface: only scan points within LAYER_BAND_MM (beyond the
        // boundary's own height spread) of the boundary's plane belong to it; a scan that sees
        // the part from both sides also holds the far face a thickness below.
        let band = boundary
            .iter()
            .map(|p| frame.height(p).abs())
            .fold(0.0, f64::max)
            + LAYER_BAND_MM;
        let boundary_frame = frame;
        let layer: Vec<Point3> = cloud
            .points()
            .par_iter()
            .filter(|p| boundary_frame.height(p).abs() <= band)
            .copied()
            .collect();
        let mut near = Vec::new();
        let mut inside = Vec::new();
        let mut h = 0.0;
        for round in 0..2 {
            let polygon = Polygon::new(boundary.iter().map(|p| frame.to_plane(p)).collect());
            if round == 0
                && let Some((first, second)) = polygon.self_crossing()
            {
                return Err(HatchError::BoundaryCrossesItself {
                    first,
                    second,
                    at: boundary[first],
                });
            }
            let area = polygon.area();
            inside = layer
                .par_iter()
                .filter(|p| polygon.contains(frame.to_plane(p)))
                .copied()
                .collect();
            if inside.len() < MIN_FIT_POINTS {
                return Err(HatchError::TooFewPoints {
                    what: "scan points inside the boundary",
                    needed: MIN_FIT_POINTS,
                    got: inside.len(),
                });
            }
            let spacing = (area / inside.len() as f64).sqrt();
            h = grid_mm.unwrap_or(GRID_PER_SPACING * spacing);
            let margin = GRID_MARGIN_CELLS * h;
            near = layer
                .par_iter()
                .filter(|p| {
                    let st = frame.to_plane(p);
                    polygon.contains(st) || polygon.distance(st) <= margin
                })
                .copied()
                .collect();
            let refined = PlaneFrame::fit(&inside, &up);
            frame = PlaneFrame {
                origin: frame.origin,
                ..refined
            };
        }
        let polygon = Polygon::new(boundary.iter().map(|p| frame.to_plane(p)).collect());
        let spacing_mm = (polygon.area() / inside.len() as f64).sqrt();
        let margin = GRID_MARGIN_CELLS * h;
        let (blo, bhi) = polygon.bounds();
        let lo = [blo[0] - margin, blo[1] - margin];
        let (wx, wy) = (bhi[0] + margin - lo[0], bhi[1] + margin - lo[1]);
        let nodes = ((wx / h).ceil().max(1.0) + 1.0) * ((wy / h).ceil().max(1.0) + 1.0);
        if nodes.is_nan() || nodes > crate::hatch::MAX_GRID_NODES as f64 {
            return Err(HatchError::setting(
                "hatch.grid_mm",
                match grid_mm {
                    Some(g) => g.to_string(),
                    None => format!("unset ({h} mm: {GRID_PER_SPACING} × the scan spacing)"),
                },
                format!(
                    "the region's {wx:.4} × {wy:.4} mm grid has {nodes} nodes, more than the {} a \
                     region may have",
                    crate::hatch::MAX_GRID_NODES
                ),
            ));
        }
        let nx = ((wx / h).ceil() as usize).max(1) + 1;
        let ny = ((wy / h).ceil() as usize).max(1) + 1;
        let plane_pts: Vec<([f64; 2], f64)> = near
            .iter()
            .map(|p| (frame.to_plane(p), frame.height(p)))
            .collect();
        let bins = Bins::new(&plane_pts, lo, h, nx, ny);
        let r0 = FIT_RADIUS_PER_GRID * h;
        let nodes: Vec<Option<Quad>> = (0..nx * ny)
            .into_par_iter()
            .map(|k| {
                let node = [lo[0] + (k % nx) as f64 * h, lo[1] + (k / nx) as f64 * h];
                let mut r = r0;
                for _ in 0..=FIT_RADIUS_GROWTH_STEPS {
                    if let Some(q) = fit_node(&plane_pts, &bins, node, r) {
                        return Some(q);
                    }
                    r *= 1.5;
                }
                None
            })
            .collect();
        // Steep nodes outside the region (walls of holes or edges the margin reaches) lose
        // their support; a steep node inside it means the patch folds over its plane.
        let mut nodes = nodes;
        let mut steepest: f64 = 0.0;
        for (k, node) in nodes.iter_mut().enumerate() {
            let Some(q) = node else { continue };
            let slope = q[1].hypot(q[2]);
            if slope <= MAX_SLOPE {
                continue;
            }
            let st = [lo[0] + (k % nx) as f64 * h, lo[1] + (k / nx) as f64 * h];
            if polygon.contains(st) || polygon.distance(st) <= h {
                steepest = steepest.max(slope);
            } else {
                *node = None;
            }
        }
        if steepest > MAX_SLOPE {
            return Err(HatchError::NotAHeightField {
                slope_deg: steepest.atan().to_degrees(),
            });
        }
        let surface = Surface {
            frame,
            lo,
            h,
            nx,
            ny,
            nodes,
            inside,
            near,
            spacing_mm,
        };
        Ok(surface)
    }

    /// The plane frame.
    #[must_use]
    pub fn frame(&self) -> &PlaneFrame {
        &self.frame
    }

    /// The grid spacing (mm).
    #[must_use]
    pub fn grid_mm(&self) -> f64 {
        self.h
    }

    /// The mean scan point spacing inside the boundary (mm).
    #[must_use]
    pub fn point_spacing_mm(&self) -> f64 {
        self.spacing_mm
    }

    /// The scan points inside the boundary (world, mm).
    #[must_use]
    pub fn inside_points(&self) -> &[Point3] {
        &self.inside
    }

    /// The scan points inside the boundary or within the grid margin of it (world, mm).
    #[must_use]
    pub fn near_points(&self) -> &[Point3] {
        &self.near
    }

    /// Grid size `(nx, ny)` in nodes.
    pub(crate) fn grid_size(&self) -> (usize, usize) {
        (self.nx, self.ny)
    }

    /// The plane coordinates of node `(i, j)`.
    pub(crate) fn node_st(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.lo[0] + i as f64 * self.h,
            self.lo[1] + j as f64 * self.h,
        ]
    }

    /// The world position of node `(i, j)`, if its fit succeeded.
    pub(crate) fn node_point(&self, i: usize, j: usize) -> Option<Point3> {
        let q = self.nodes[j * self.nx + i]?;
        Some(self.frame.to_world(self.node_st(i, j), q[0]))
    }

    /// The height `f` and its gradient `(f_s, f_t)` at plane coordinates `st`, or `None` outside
    /// the grid or where no surrounding node has scan support.
    #[must_use]
    pub fn height_gradient(&self, st: [f64; 2]) -> Option<(f64, [f64; 2])> {
        let gx = (st[0] - self.lo[0]) / self.h;
        let gy = (st[1] - self.lo[1]) / self.h;
        if !(gx >= 0.0 && gy >= 0.0) {
            return None;
        }
        let i = (gx.floor() as usize).min(self.nx.saturating_sub(2));
        let j = (gy.floor() as usize).min(self.ny.saturating_sub(2));
        if i + 1 >= self.nx || j + 1 >= self.ny || gx > (self.nx - 1) as f64 + 1e-9 {
            return None;
        }
        if gy > (self.ny - 1) as f64 + 1e-9 {
            return None;
        }
        let (fx, fy) = (gx - i as f64, gy - j as f64);
        let mut sum_w = 0.0;
        let mut f = 0.0;
        let mut g = [0.0; 2];
        for (di, dj, w) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let Some(q) = self.nodes[(j + dj) * self.nx + i + di] else {
                continue;
            };
            let node = self.node_st(i + di, j + dj);
            let (ds, dt) = (st[0] - node[0], st[1] - node[1]);
            let value = q[0]
                + q[1] * ds
                + q[2] * dt
                + 0.5 * q[3] * ds * ds
                + q[4] * ds * dt
                + 0.5 * q[5] * dt * dt;
            // The gradient blends the nodes' own gradients: each node's second-order terms
            // are noisy (σ/r²), and evaluating them up to h√2 away tilts normals by degrees.
            let (gs, gt) = (q[1], q[2]);
            let w = w.max(1e-12);
            sum_w += w;
            f += w * value;
            g[0] += w * gs;
            g[1] += w * gt;
        }
        if sum_w <= 0.0 {
            return None;
        }
        Some((f / sum_w, [g[0] / sum_w, g[1] / sum_w]))
    }

    /// The surface point (world) over plane coordinates `st`.
    #[must_use]
    pub fn lift(&self, st: [f64; 2]) -> Option<Point3> {
        let (f, _) = self.height_gradient(st)?;
        Some(self.frame.to_world(st, f))
    }

    /// The surface point and unit normal (world, toward `e3`) over plane coordinates `st`.
    #[must_use]
    pub fn lift_with_normal(&self, st: [f64; 2]) -> Option<(Point3, Vector3)> {
        let (f, g) = self.height_gradient(st)?;
        let n = (self.frame.e3 - self.frame.e1 * g[0] - self.frame.e2 * g[1]).normalize();
        Some((self.frame.to_world(st, f), n))
    }

    /// The distance (mm, along `e3`) of a world point from the fitted surface.
    #[must_use]
    pub fn offset(&self, p: &Point3) -> Option<f64> {
        let (f, _) = self.height_gradient(self.frame.to_plane(p))?;
        Some((self.frame.height(p) - f).abs())
    }

    /// The length (mm) of the surface curve over the straight plane segment `a`–`b`, summed
    /// over `pieces` chords.
    #[must_use]
    pub fn surface_length(&self, a: [f64; 2], b: [f64; 2], pieces: usize) -> Option<f64> {
        let mut prev = self.lift(a)?;
        let mut sum = 0.0;
        for k in 1..=pieces.max(1) {
            let u = k as f64 / pieces.max(1) as f64;
            let p = self.lift([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])])?;
            sum += (p - prev).norm();
            prev = p;
        }
        Some(sum)
    }
}

/// Points binned by grid cell (counting sort), for radius queries in the plane.
struct Bins {
    start: Vec<u32>,
    order: Vec<u32>,
    lo: [f64; 2],
    h: f64,
    nx: usize,
    ny: usize,
}

impl Bins {
    fn new(points: &[([f64; 2], f64)], lo: [f64; 2], h: f64, nx: usize, ny: usize) -> Bins {
        let cell = |st: [f64; 2]| -> Option<usize> {
            let i = ((st[0] - lo[0]) / h).floor();
            let j = ((st[1] - lo[1]) / h).floor();
            (i >= 0.0 && j >= 0.0 && (i as usize) < nx && (j as usize) < ny)
                .then(|| j as usize * nx + i as usize)
        };
        let mut count = vec![0u32; nx * ny + 1];
        let cells: Vec<Option<usize>> = points.iter().map(|(st, _)| cell(*st)).collect();
        for c in cells.iter().flatten() {
            count[c + 1] += 1;
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let start = count.clone();
        let mut fill = count;
        let mut order = vec![0u32; fill[nx * ny] as usize];
        for (k, c) in cells.iter().enumerate() {
            if let Some(c) = c {
                order[fill[*c] as usize] = k as u32;
                fill[*c] += 1;
            }
        }
        Bins {
            start,
            order,
            lo,
            h,
            nx,
            ny,
        }
    }

    /// Calls `visit` with every point index in cells overlapping the disc.
    fn for_each_near(&self, c: [f64; 2], r: f64, mut visit: impl FnMut(usize)) {
        let i0 = (((c[0] - r - self.lo[0]) / self.h).floor().max(0.0)) as usize;
        let j0 = (((c[1] - r - self.lo[1]) / self.h).floor().max(0.0)) as usize;
        let i1 = ((((c[0] + r - self.lo[0]) / self.h).floor().max(0.0)) as usize).min(self.nx - 1);
        let j1 = ((((c[1] + r - self.lo[1]) / self.h).floor().max(0.0)) as usize).min(self.ny - 1);
        for j in j0..=j1 {
            let row = j * self.nx;
            let a = self.start[row + i0] as usize;
            let b = self.start[row + i1 + 1] as usize;
            for &k in &self.order[a..b] {
                visit(k as usize);
            }
        }
    }
}

/// The weighted quadratic fit at `node` over points within `r`, with one outlier-rejecting
/// refit; `None` with too few points or a singular system.
fn fit_node(points: &[([f64; 2], f64)], bins: &Bins, node: [f64; 2], r: f64) -> Option<Quad> {
    let mut local: Vec<(f64, f64, f64, f64)> = Vec::with_capacity(64);
    let r2 = r * r;
    bins.for_each_near(node, r, |k| {
        let (st, f) = points[k];
        let (ds, dt) = (st[0] - node[0], st[1] - node[1]);
        let d2 = ds * ds + dt * dt;
        if d2 < r2 {
            let w = 1.0 - d2 / r2;
            local.push((ds, dt, f, w * w));
        }
    });
    if local.len() < MIN_FIT_POINTS {
        return None;
    }
    // Quadrant support: a node outside the scan would only extrapolate.
    let mut quadrants = [false; 4];
    for &(ds, dt, _, _) in &local {
        quadrants[usize::from(ds >= 0.0) + 2 * usize::from(dt >= 0.0)] = true;
    }
    if quadrants.iter().filter(|&&q| q).count() < 3 {
        return None;
    }
    // Gross outliers first (a cluster of points millimetres off the surface bends the first
    // quadratic enough to hide itself in the residuals): heights beyond
    // GROSS_OUTLIER_SIGMAS robust deviations of the local heights, and at least
    // GROSS_OUTLIER_FLOOR_MM, from their median are left out. Then reject and refit until the
    // kept set stops changing.
    let mut heights: Vec<f64> = local.iter().map(|l| l.2).collect();
    let median_height = median(&mut heights);
    let mut spread: Vec<f64> = heights.iter().map(|h| (h - median_height).abs()).collect();
    let gross = (GROSS_OUTLIER_SIGMAS * 1.4826 * median(&mut spread)).max(GROSS_OUTLIER_FLOOR_MM);
    let mut kept: Vec<_> = local
        .iter()
        .filter(|l| (l.2 - median_height).abs() <= gross)
        .copied()
        .collect();
    if kept.len() < MIN_FIT_POINTS {
        kept.clone_from(&local);
    }
    let mut q = solve_quadratic(&kept, r)?;
    for _ in 0..REFITS {
        let mut residuals: Vec<f64> = local
            .iter()
            .map(|&(ds, dt, f, _)| (f - eval(&q, ds, dt)).abs())
            .collect();
        let limit =
            (OUTLIER_SIGMAS * 1.4826 * median(&mut residuals.clone())).max(OUTLIER_FLOOR_MM);
        let next: Vec<_> = local
            .iter()
            .zip(residuals.drain(..))
            .filter(|(_, e)| *e <= limit)
            .map(|(l, _)| *l)
            .collect();
        if next.len() < MIN_FIT_POINTS || next.len() == kept.len() {
            break;
        }
        kept = next;
        q = solve_quadratic(&kept, r)?;
    }
    Some(q)
}

/// The median of `values` (reordered), 0 when empty.
fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// A local height this many robust deviations from the local median height is a gross outlier
/// (before the first fit)…
const GROSS_OUTLIER_SIGMAS: f64 = 6.0;
/// …and at least this far from it, mm (the local heights of a curved patch spread too).
const GROSS_OUTLIER_FLOOR_MM: f64 = 0.5;
/// Reject-and-refit rounds after the first fit at most.
const REFITS: usize = 3;

fn eval(q: &Quad, ds: f64, dt: f64) -> f64 {
    q[0] + q[1] * ds + q[2] * dt + 0.5 * q[3] * ds * ds + q[4] * ds * dt + 0.5 * q[5] * dt * dt
}

/// Weighted least squares for the quadratic, in coordinates scaled by `r` (conditioning).
fn solve_quadratic(local: &[(f64, f64, f64, f64)], r: f64) -> Option<Quad> {
    let mut a = Matrix6::<f64>::zeros();
    let mut b = Vector6::<f64>::zeros();
    for &(ds, dt, f, w) in local {
        let (x, y) = (ds / r, dt / r);
        let row = Vector6::new(1.0, x, y, 0.5 * x * x, x * y, 0.5 * y * y);
        a += row * row.transpose() * w;
        b += row * (w * f);
    }
    // A tiny ridge keeps nearly flat, nearly collinear supports solvable.
    let ridge = 1e-9 * a.trace().max(1e-300);
    for k in 0..6 {
        a[(k, k)] += ridge;
    }
    let c = a.cholesky()?.solve(&b);
    let q = [
        c[0],
        c[1] / r,
        c[2] / r,
        c[3] / (r * r),
        c[4] / (r * r),
        c[5] / (r * r),
    ];
    q.iter().all(|v| v.is_finite()).then_some(q)
}
