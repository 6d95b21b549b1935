//! The scanner: what it sees of the deformed, placed part.

use nalgebra::UnitQuaternion;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;
use rand::Rng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{GeomError, Point3, PointCloud, Result, Similarity3, Vector3};

use crate::case::SynthParams;
use crate::mesh::DomainMesh;
use crate::part::{Deformation, SurfaceSampler, design_point, mapped_normal};

/// The scanner sees a face only below this incidence, degrees.
pub(crate) const MAX_VIEW_INCIDENCE_DEG: f64 = 75.0;

/// Occlusion rays start this far toward the scanner, mm (clears the mesh's chord error).
pub(crate) const RAY_START_OFFSET_MM: f64 = 0.1;

/// Distance of the scanner from the part centre, mm.
pub(crate) const SCANNER_DISTANCE_MM: f64 = 300.0;

/// What the scanner sees of the deformed, placed part: samples of the surface facing the
/// scanner (within `MAX_VIEW_INCIDENCE_DEG`) and not hidden by the part itself (a ray cast
/// against the deformed mesh), with dropout patches, Gaussian noise and outliers. Returns the
/// scan (scan frame) and the scanner's position in it. Draws from `rng` in a fixed order, so a
/// seed gives the same scan.
pub(crate) fn scan_part(
    params: &SynthParams,
    rng: &mut Xoshiro256PlusPlus,
    sampler: &SurfaceSampler,
    mesh: &DomainMesh,
    scan_from_domain: &dyn Fn(&Point3) -> Point3,
    scan_from_cad_true: &Similarity3,
    deformation: &Deformation,
) -> Result<(PointCloud, Point3)> {
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
        let s = sampler.sample(rng);
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
        .map(|p| p + Vector3::new(noise.sample(rng), noise.sample(rng), noise.sample(rng)))
        .collect();
    let n_outliers = (params.outlier_fraction * scan_pts.len() as f64).round() as usize;
    if let Some(bounds) = trim_geom::Aabb::around(&scan_pts) {
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
    Ok((PointCloud::new(scan_pts)?, scanner_in_scan))
}
