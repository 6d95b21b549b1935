//! The scanner: fixed to the machine, one to four views, and what it sees of the deformed,
//! placed part.

use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;
use rand::Rng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{GeomError, Point3, PointCloud, Result, Similarity3, Vector3};

use crate::blockage::BlockageSampler;
use crate::burr::BurrSampler;
use crate::case::SynthParams;
use crate::mesh::DomainMesh;
use crate::part::{SurfaceSampler, design_point, mapped_normal};

/// The scanner sees a face only below this incidence, degrees.
pub(crate) const MAX_VIEW_INCIDENCE_DEG: f64 = 75.0;

/// Occlusion rays start this far toward the scanner, mm (clears the mesh's chord error).
pub(crate) const RAY_START_OFFSET_MM: f64 = 0.1;

/// Distance of the scanner from the part's nominal centre, mm.
pub(crate) const SCANNER_DISTANCE_MM: f64 = 300.0;

/// The first view's azimuth about the nominal thickness axis, from the nominal `+x`, degrees
/// (where the single scanner looked from before the views were fixed to the machine).
pub const FIRST_VIEW_AZIMUTH_DEG: f64 = -68.2;

/// The seeded tilts of the views after the first, degrees from the thickness axis.
pub const VIEW_TILT_RANGE_DEG: [f64; 2] = [10.0, 55.0];

/// The seeded jitter of the views' azimuths after the first (± this about the even spread), degrees.
pub const VIEW_AZIMUTH_JITTER_DEG: f64 = 20.0;

/// Views of the built-in demo's scanner (`trimctl run`'s twin): a cell's scanner fixed to the
/// machine, looking from three directions, two on the top side and one below (with one view the
/// ends of the demo's long strips are fixed by the field alone and registration flags them).
pub const DEMO_SCANNER_VIEWS: usize = 3;

/// One view of the scanner. Views are fixed to the machine: defined in the scan frame about the
/// fixture's *nominal* pose of the part, whatever its true pose.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanView {
    /// The scanner's position (its projection centre), scan frame, mm: what registration's
    /// `scanner_viewpoint_mm` means.
    pub scanner_in_scan_mm: Point3,
    /// Unit direction from the part's nominal centre toward the scanner, scan frame (what
    /// registration's `view_direction` means).
    pub toward_scanner_in_scan: Vector3,
    /// Tilt from the nominal thickness axis on the view's side, degrees.
    pub tilt_deg: f64,
    /// Azimuth about the nominal thickness axis, from the nominal `+x`, degrees.
    pub azimuth_deg: f64,
    /// The side it looks at: `true` the top face's (nominal `+z`), `false` the bottom's.
    pub top_side: bool,
}

/// The views of `params` (`scanner_views` of them) about the fixture's nominal pose: view `k`
/// looks at the top side for even `k` and the bottom side for odd `k`; view 0 at
/// `scanner_tilt_deg` and [`FIRST_VIEW_AZIMUTH_DEG`], view `k ≥ 1` at `view_tilts_deg[k − 1]`
/// (else seeded in [`VIEW_TILT_RANGE_DEG`]) and an azimuth `k·360°/n` further on, ± a seeded
/// [`VIEW_AZIMUTH_JITTER_DEG`]. Draws the same numbers from `rng` whatever the tilts given.
pub(crate) fn fixed_views(
    params: &SynthParams,
    scan_from_cad_nominal: &Similarity3,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<ScanView> {
    let aim = scan_from_cad_nominal * design_point(0.0, 0.0, 0.0);
    let rotation = scan_from_cad_nominal.isometry.rotation;
    let (x, y, z) = (
        rotation * Vector3::x(),
        rotation * Vector3::y(),
        rotation * Vector3::z(),
    );
    let n = params.scanner_views;
    (0..n)
        .map(|k| {
            let (tilt_deg, azimuth_deg) = if k == 0 {
                (params.scanner_tilt_deg, FIRST_VIEW_AZIMUTH_DEG)
            } else {
                let [lo, hi] = VIEW_TILT_RANGE_DEG;
                let seeded = rng.random_range(lo..=hi);
                let jitter = rng.random_range(-VIEW_AZIMUTH_JITTER_DEG..=VIEW_AZIMUTH_JITTER_DEG);
                (
                    params.view_tilts_deg.get(k - 1).copied().unwrap_or(seeded),
                    FIRST_VIEW_AZIMUTH_DEG + 360.0 * k as f64 / n as f64 + jitter,
                )
            };
            let top_side = k % 2 == 0;
            let side = if top_side { 1.0 } else { -1.0 };
            let (tilt, azimuth) = (tilt_deg.to_radians(), azimuth_deg.to_radians());
            let toward = (z * (side * tilt.cos())
                + (x * azimuth.cos() + y * azimuth.sin()) * tilt.sin())
            .normalize();
            ScanView {
                scanner_in_scan_mm: aim + toward * SCANNER_DISTANCE_MM,
                toward_scanner_in_scan: toward,
                tilt_deg,
                azimuth_deg,
                top_side,
            }
        })
        .collect()
}

/// A rescan's dropout centre is drawn from the part's surface until a seen point comes up, at
/// most this many times (a core's seen share is a third or more).
const DROPOUT_CENTRE_ATTEMPTS: usize = 1000;

/// What the scanner sees of the deformed, placed part (and its burrs): samples of the surface
/// seen by at least one view (facing it within `MAX_VIEW_INCIDENCE_DEG` and not hidden by the
/// part itself: a ray cast toward that view's scanner against the deformed mesh), with dropout
/// patches, Gaussian noise and outliers. The part and the burrs are sampled in proportion to
/// their areas. Returns the scan, scan frame. Draws from `rng` in a fixed order, so a seed
/// gives the same scan. With `dropout_seed` (a rescan), the dropout patches' centres are drawn
/// from a stream of their own on the part's seen surface (see below).
#[allow(clippy::too_many_arguments)]
pub(crate) fn scan_part(
    params: &SynthParams,
    rng: &mut Xoshiro256PlusPlus,
    dropout_seed: Option<u64>,
    sampler: &SurfaceSampler,
    (burrs, films): (&BurrSampler, &BlockageSampler),
    mesh: &DomainMesh,
    scan_from_domain: &dyn Fn(&Point3) -> Point3,
    views: &[ScanView],
) -> Result<PointCloud> {
    // The deformed mesh in the scan frame, for occlusion.
    let scan_vertices: Vec<Point3> = mesh.vertices.iter().map(scan_from_domain).collect();
    let trimesh = TriMesh::new(scan_vertices, mesh.triangles.clone())
        .map_err(|e| GeomError::invalid("synth mesh", format!("{e:?}")))?;
    let cos_max = MAX_VIEW_INCIDENCE_DEG.to_radians().cos();
    let seen = |p: &Point3, n: &Vector3| {
        views.iter().any(|view| {
            let to_scanner = (view.scanner_in_scan_mm - p).normalize();
            if n.dot(&to_scanner) < cos_max {
                return false;
            }
            let ray = Ray::new(p + to_scanner * RAY_START_OFFSET_MM, to_scanner);
            trimesh
                .cast_local_ray(&ray, SCANNER_DISTANCE_MM * 2.0, false)
                .is_none()
        })
    };
    let (part_area, burr_area, film_area) = (sampler.area(), burrs.area(), films.area());

    let mut visible = Vec::with_capacity(params.scan_points);
    // Whether each visible sample is on the part (false: a web proposal its true area does
    // not hold, `BurrSampler`). Such samples keep their place until the draws that follow
    // them (dropout centres by index, noise per sample, the outliers' box) are made, and are
    // dropped after: the scan is the one the webs' strips gave, less what they do not have.
    let mut kept = Vec::with_capacity(params.scan_points);
    let max_attempts = params.scan_points.saturating_mul(20);
    let mut attempts = 0usize;
    while visible.len() < params.scan_points && attempts < max_attempts {
        attempts += 1;
        // No extra draw without burrs or films, and the same draw with burrs alone: such cases
        // are what they were.
        let defect_area = burr_area + film_area;
        let pick = (defect_area > 0.0).then(|| rng.random_range(0.0..part_area + defect_area));
        let (s, on_part) = match pick {
            Some(x) if x < burr_area => {
                let w = burrs.sample(rng);
                (w.sample, w.kept)
            }
            Some(x) if x < defect_area => (films.sample(rng), true),
            _ => (sampler.sample(rng), true),
        };
        let p = scan_from_domain(&s.point);
        let n = mapped_normal(&scan_from_domain, &s.point, &s.normal);
        if seen(&p, &n) {
            visible.push(p);
            kept.push(on_part);
        }
    }
    if visible.len() < params.scan_points {
        return Err(GeomError::TooFewPoints {
            what: "synthetic scan (visible samples)".into(),
            needed: params.scan_points,
            got: visible.len(),
        });
    }
    // Dropouts: balls around random visible points. A rescan draws their centres from the
    // part's own seen surface with a stream of their own: drawn from `visible`, they moved with
    // whatever a trim left of the burrs and films (a cut differing by a fraction of a
    // micrometre changed the burrs' area, hence every later draw), so where a rescan lost its
    // patches, and which contours it left uncovered, was chance.
    let holes: Vec<(Point3, f64)> = match dropout_seed {
        None => (0..params.dropouts)
            .map(|_| {
                let c = visible[rng.random_range(0..visible.len())];
                (c, rng.random_range(1.5..3.0))
            })
            .collect(),
        Some(seed) => {
            let mut own = <Xoshiro256PlusPlus as rand::SeedableRng>::seed_from_u64(seed);
            (0..params.dropouts)
                .filter_map(|_| {
                    let radius = own.random_range(1.5..3.0);
                    (0..DROPOUT_CENTRE_ATTEMPTS).find_map(|_| {
                        let s = sampler.sample(&mut own);
                        let p = scan_from_domain(&s.point);
                        seen(&p, &mapped_normal(&scan_from_domain, &s.point, &s.normal))
                            .then_some((p, radius))
                    })
                })
                .collect()
        }
    };
    let (visible, kept): (Vec<Point3>, Vec<bool>) = visible
        .into_iter()
        .zip(kept)
        .filter(|(p, _)| holes.iter().all(|(c, r)| (p - c).norm() > *r))
        .unzip();
    let noise = Normal::new(0.0, params.noise_mm.max(0.0))
        .map_err(|e| GeomError::invalid("noise_mm", e.to_string()))?;
    let noisy: Vec<Point3> = visible
        .iter()
        .map(|p| p + Vector3::new(noise.sample(rng), noise.sample(rng), noise.sample(rng)))
        .collect();
    let n_outliers = (params.outlier_fraction * noisy.len() as f64).round() as usize;
    let bounds = trim_geom::Aabb::around(&noisy);
    let mut scan_pts: Vec<Point3> = noisy
        .into_iter()
        .zip(kept)
        .filter_map(|(p, on_part)| on_part.then_some(p))
        .collect();
    if let Some(bounds) = bounds {
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
    PointCloud::new(scan_pts)
}
