//! The share of a hole or slot still covered: a grid across the opening at the face's level,
//! each node covered when a scan point lies at it.
//!
//! A closed contour rims an opening when, seen along its feature vector (the face's normal),
//! most of what it encloses is not material: a ray cast down the normal from the face's level
//! at a grid node meets the CAD's surface within `opening_depth_mm` only over material. The
//! face's level at a node is interpolated from the rim's heights (inverse squared distance to
//! the rim's points, weights `1/d⁴`), so a twisted or cambered face is followed.

use parry3d_f64::query::{Ray, RayCast};
use trim_geom::mesh::Mesh;
use trim_geom::{KdTree, Point3, Vector3};

use crate::contours::ContourGeometry;
use crate::settings::InspectSettings;

/// Where the rays start above the face's level, mm.
const RAY_START_MM: f64 = 0.05;

/// A contour rims an opening when at least this share of its enclosed nodes is open.
const OPEN_SHARE: f64 = 0.5;

/// The most grid nodes one opening is measured on (the step grows past it).
const MAX_NODES: usize = 200_000;

/// An opening's grid, CAD frame.
#[derive(Debug, Clone)]
pub struct Opening {
    /// The grid's nodes at the face's level, mm (those of the open region, clear of the rim).
    pub nodes: Vec<Point3>,
    /// The face's normal (the contour's feature vector).
    pub normal: Vector3,
}

/// The opening a closed contour rims, or none (an open contour, or one around material).
#[must_use]
pub fn opening_of(g: &ContourGeometry, mesh: &Mesh, settings: &InspectSettings) -> Option<Opening> {
    if !g.closed {
        return None;
    }
    let n = g.feature.into_inner();
    let e1 = n
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| {
            n.cross(&Vector3::y())
                .try_normalize(1e-9)
                .unwrap_or_else(Vector3::z)
        });
    let e2 = n.cross(&e1);
    let centre =
        g.points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / g.points.len() as f64;
    let centre = Point3::from(centre);
    let rim: Vec<(f64, f64, f64)> = g
        .points
        .iter()
        .map(|p| {
            let d = p - centre;
            (d.dot(&e1), d.dot(&e2), d.dot(&n))
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (a, b, _) in &rim {
        lo = [lo[0].min(*a), lo[1].min(*b)];
        hi = [hi[0].max(*a), hi[1].max(*b)];
    }
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let step = settings
        .opening_grid_mm
        .max((area / MAX_NODES as f64).sqrt());
    let (na, nb) = (
        ((hi[0] - lo[0]) / step).ceil() as usize,
        ((hi[1] - lo[1]) / step).ceil() as usize,
    );
    let mut enclosed = 0usize;
    let mut open = Vec::new();
    let trimesh = mesh.trimesh();
    for i in 0..na {
        for j in 0..nb {
            let a = lo[0] + (i as f64 + 0.5) * step;
            let b = lo[1] + (j as f64 + 0.5) * step;
            let (inside, rim_distance) = place(&rim, a, b);
            // Nodes near the rim are left out: a film there cannot be told from the wall's top.
            if !inside || rim_distance < settings.opening_rim_clearance_mm {
                continue;
            }
            let Some(height) = face_height(&rim, a, b) else {
                continue;
            };
            enclosed += 1;
            let node = centre + e1 * a + e2 * b + n * height;
            let ray = Ray::new(node + n * RAY_START_MM, -n);
            let material = trimesh
                .cast_local_ray(&ray, RAY_START_MM + settings.opening_depth_mm, true)
                .is_some();
            if !material {
                open.push(node);
            }
        }
    }
    (enclosed > 0 && open.len() as f64 >= OPEN_SHARE * enclosed as f64).then_some(Opening {
        nodes: open,
        normal: n,
    })
}

/// Whether `(a, b)` is inside the rim polygon (even-odd) and its distance from the rim.
fn place(rim: &[(f64, f64, f64)], a: f64, b: f64) -> (bool, f64) {
    let mut inside = false;
    let mut best = f64::INFINITY;
    for w in rim.windows(2) {
        let ((a0, b0, _), (a1, b1, _)) = (w[0], w[1]);
        if (b0 > b) != (b1 > b) && a < a0 + (b - b0) * (a1 - a0) / (b1 - b0) {
            inside = !inside;
        }
        let (da, db) = (a1 - a0, b1 - b0);
        let len2 = da * da + db * db;
        let t = if len2 > 0.0 {
            (((a - a0) * da + (b - b0) * db) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d2 = (a0 + t * da - a).powi(2) + (b0 + t * db - b).powi(2);
        best = best.min(d2);
    }
    (inside, best.sqrt())
}

/// The face's height at `(a, b)`, interpolated from the rim's heights (weights `1/d⁴` to the
/// rim's points but its last, as each segment's first), or none for an empty rim. Computed only
/// for the nodes kept: it visits every rim point.
fn face_height(rim: &[(f64, f64, f64)], a: f64, b: f64) -> Option<f64> {
    let (mut wsum, mut hsum) = (0.0, 0.0);
    for w in rim.windows(2) {
        let (a0, b0, h0) = w[0];
        let v2 = (a0 - a).powi(2) + (b0 - b).powi(2);
        let w = 1.0 / (v2 * v2).max(1e-12);
        wsum += w;
        hsum += w * h0;
    }
    (wsum > 0.0).then(|| hsum / wsum)
}

/// The share of the opening's nodes with a scan point (CAD frame, in `tree` over `points`)
/// within `opening_support_mm` across the face and `opening_depth_mm` below or above its level.
#[must_use]
pub fn covered_share(
    opening: &Opening,
    tree: &KdTree,
    points: &[Point3],
    settings: &InspectSettings,
) -> f64 {
    let (support, depth) = (settings.opening_support_mm, settings.opening_depth_mm);
    let radius = support.hypot(depth);
    let covered = opening
        .nodes
        .iter()
        .filter(|node| {
            tree.within_radius_unsorted(node, radius).iter().any(|nb| {
                let d = points[nb.index] - **node;
                let along = d.dot(&opening.normal);
                let across2 = d.norm_squared() - along * along;
                along.abs() <= depth && across2 <= support * support
            })
        })
        .count();
    covered as f64 / opening.nodes.len().max(1) as f64
}
