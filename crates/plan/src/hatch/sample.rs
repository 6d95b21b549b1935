//! Points along a track: equal steps of the pulse pitch (the paper's "equal-distance step
//! method", §2.2, measured in 3D along the surface curve), or the fewest points within a chord
//! tolerance (Douglas–Peucker, for vector marking). Every point is lifted onto the fitted
//! surface and carries its unit normal.

use trim_geom::{Point3, Vector3};

use super::PointSpacing;
use super::surface::Surface;

/// Dense points per grid spacing used to measure lengths along a track.
const DENSE_PER_GRID: f64 = 4.0;

/// A sampled track: plane coordinates (mm), world points (mm) and unit normals (world).
pub(crate) type Sampled = (Vec<[f64; 2]>, Vec<Point3>, Vec<Vector3>);

/// Samples the plane polyline `line` onto the surface. Returns the plane coordinates, world
/// points and unit normals; `None` where the surface has no support.
pub(crate) fn sample_track(
    surface: &Surface,
    line: &[[f64; 2]],
    spacing: PointSpacing,
) -> Option<Sampled> {
    let max_len = match spacing {
        PointSpacing::Pitch { step_mm } => (surface.grid_mm() / DENSE_PER_GRID).min(step_mm / 2.0),
        PointSpacing::Chord { .. } => surface.grid_mm() / DENSE_PER_GRID,
    };
    let mut dense: Vec<[f64; 2]> = Vec::with_capacity(line.len() * 2);
    for w in line.windows(2) {
        let (a, b) = (w[0], w[1]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = ((len / max_len).ceil() as usize).max(1);
        for k in 0..n {
            let u = k as f64 / n as f64;
            dense.push([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])]);
        }
    }
    dense.push(*line.last()?);
    let lifted: Vec<Point3> = dense
        .iter()
        .map(|st| surface.lift(*st))
        .collect::<Option<_>>()?;
    let st: Vec<[f64; 2]> = match spacing {
        PointSpacing::Pitch { step_mm } => equal_steps(&dense, &lifted, step_mm),
        PointSpacing::Chord { tolerance_mm } => {
            let mut keep = vec![false; dense.len()];
            keep[0] = true;
            keep[dense.len() - 1] = true;
            douglas_peucker(&lifted, 0, dense.len() - 1, tolerance_mm, &mut keep);
            dense
                .iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(p, _)| *p)
                .collect()
        }
    };
    let mut points = Vec::with_capacity(st.len());
    let mut normals = Vec::with_capacity(st.len());
    for p in &st {
        let (x, n) = surface.lift_with_normal(*p)?;
        points.push(x);
        normals.push(n);
    }
    Some((st, points, normals))
}

/// Plane points at 3D arc-length steps of `step` along the dense polyline, the end included.
fn equal_steps(dense: &[[f64; 2]], lifted: &[Point3], step: f64) -> Vec<[f64; 2]> {
    let mut out = vec![dense[0]];
    let mut next = step;
    let mut run = 0.0;
    for k in 1..dense.len() {
        let seg = (lifted[k] - lifted[k - 1]).norm();
        while run + seg >= next && seg > 0.0 {
            let u = (next - run) / seg;
            let (a, b) = (dense[k - 1], dense[k]);
            out.push([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])]);
            next += step;
        }
        run += seg;
    }
    // The end point on the boundary; a remainder shorter than a thousandth of a step merges.
    let end = dense[dense.len() - 1];
    let remainder = run - (next - step);
    if remainder > step * 1e-3 || out.len() == 1 {
        out.push(end);
    } else if let Some(last) = out.last_mut() {
        *last = end;
    }
    out
}

fn douglas_peucker(points: &[Point3], a: usize, b: usize, tol: f64, keep: &mut [bool]) {
    if b <= a + 1 {
        return;
    }
    let (pa, pb) = (points[a], points[b]);
    let ab = pb - pa;
    let len2 = ab.norm_squared();
    let (mut worst, mut at) = (0.0, a);
    for (k, p) in points.iter().enumerate().take(b).skip(a + 1) {
        let ap = p - pa;
        let d = if len2 > 0.0 {
            let u = (ap.dot(&ab) / len2).clamp(0.0, 1.0);
            (ap - ab * u).norm()
        } else {
            ap.norm()
        };
        if d > worst {
            worst = d;
            at = k;
        }
    }
    if worst > tol {
        keep[at] = true;
        douglas_peucker(points, a, at, tol, keep);
        douglas_peucker(points, at, b, tol, keep);
    }
}
