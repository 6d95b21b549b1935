//! The triangle mesh of the part in domain coordinates (constrained Delaunay on the faces, rims
//! of holes and slots): for `cad.stl` and the scanner's occlusion test.

use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};
use trim_geom::{GeomError, Point3, Result, Vector3};

use crate::part::{Cutout, LENGTH_MM, SurfaceSampler, THICKNESS_MM, WIDTH_MM};

/// The default mesh edge length on the faces, mm (chord error of the camber ≈ 2 µm).
pub const DEFAULT_MESH_STEP_MM: f64 = 1.0;

/// Mesh edge length along hole and slot rims, mm.
pub(crate) const RIM_STEP_MM: f64 = 0.2;

/// The domain triangulation of the part: vertices `(u, v, w)` and outward-oriented triangles.
pub(crate) struct DomainMesh {
    pub(crate) vertices: Vec<Point3>,
    pub(crate) triangles: Vec<[u32; 3]>,
}

/// The mesh with an edge length of `step_mm` on the faces and along the outer boundary
/// ([`RIM_STEP_MM`] along rims).
pub(crate) fn domain_mesh(cutouts: &[Cutout], step_mm: f64) -> Result<DomainMesh> {
    let (w2, l2) = (WIDTH_MM / 2.0, LENGTH_MM / 2.0);
    // Boundary loops in (u, v) with the out-of-material normal of each point.
    let mut loops: Vec<Vec<([f64; 2], [f64; 2])>> = Vec::new();
    let mut outer = Vec::new();
    let corners = [[-w2, -l2], [w2, -l2], [w2, l2], [-w2, l2]];
    for i in 0..4 {
        let (a, b) = (corners[i], corners[(i + 1) % 4]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / step_mm).ceil() as usize;
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
    let clearance = 0.6 * step_mm;
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
    let nu = (WIDTH_MM / step_mm).round() as i32;
    let nv = (LENGTH_MM / step_mm).round() as i32;
    for i in 1..nu {
        for j in 1..nv {
            let u = -w2 + f64::from(i) * step_mm;
            let v = -l2 + f64::from(j) * step_mm;
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
pub(crate) fn insert(
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
