//! A whole test case: what to generate ([`SynthParams`]), the generator ([`generate`]) and what
//! it gives ([`SynthCase`]: CAD, template path, scan, ground truth, poses), written as files by
//! [`SynthCase::write_case`].

use nalgebra::{Translation3, UnitQuaternion};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, UnitSphere};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{GeomError, Path, Point3, PointCloud, Result, Similarity3, Vector3};

use crate::blockage::{Blockage, BlockageRanges, BlockageSampler, Film, draw_blockages};
use crate::burr::{Burr, BurrRanges, BurrSampler, draw_burrs};
use crate::mesh::{DEFAULT_MESH_STEP_MM, domain_mesh};
use crate::part::{
    DEFAULT_PATH_SPACING_MM, Deformation, SurfaceSampler, contour_edges, cutouts, design_point,
    map_contour, mapped_normal, template_path,
};
use crate::scanner::{ScanView, fixed_views, scan_part};

/// Seed tags of the random streams apart from the main one (each drawn from its own stream, so
/// a parameter that adds draws leaves every other case quantity as it was).
const PRESSING_STREAM: u64 = 0x7072_6573_7369_6e67;
const VIEWS_STREAM: u64 = 0x7669_6577_7300_0000;
const BURRS_STREAM: u64 = 0x6275_7272_7300_0000;
const BLOCKAGES_STREAM: u64 = 0x626c_6f63_6b00_0000;

/// The random stream `tag` of `seed`.
fn stream(seed: u64, tag: u64) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(seed ^ tag)
}

/// The most dropout patches a case may have.
pub const MAX_DROPOUTS: usize = 100;

/// What to generate. Angles in degrees and lengths in millimetres (edge units).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Bend: the deformed mid-length rises this much over the ends, mm.
    pub sag_mm: f64,
    /// The bend's direction, tilted this far from the thickness axis toward the chord, degrees
    /// (`Deformation::bend_tilt_rad`; 0–60, as given, no draw): a core bends in its own plane
    /// too, and then the leading and trailing edges slide along the span with the bend.
    pub bend_tilt_deg: f64,
    /// Twist about the long axis, end to end, degrees.
    pub twist_deg: f64,
    /// Curl of the part's free `+Y` end along its thickness, mm (`Deformation::tip_curl_mm`;
    /// signed as given, no draw).
    pub tip_curl_mm: f64,
    /// Per-axis scale (shrinkage) is drawn from `[1 − r, 1 + r]`, along the pressing axes.
    pub scale_range: f64,
    /// The change of the shrinkage along the span, end to end (`Deformation::shrink_gradient`;
    /// signed as given, no draw; |g| ≤ 0.02). Left out of case.json when 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub shrink_gradient: f64,
    /// The pressing axes (along which the per-axis scale acts) are the CAD axes turned by a
    /// seeded rotation of `[½, 1] ×` this, random axis, degrees (0: the CAD axes).
    pub pressing_tilt_deg: f64,
    /// Standard deviation of the Gaussian scan noise per coordinate, mm.
    pub noise_mm: f64,
    /// Number of visible samples drawn: the scan holds fewer where dropout patches remove
    /// some and where a burr web's true area thins its proposals (`burr::BurrSampler`), and the
    /// outliers are added on top.
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
    /// Views of the scanner (1–4), fixed to the machine: view `k` looks at the top side for
    /// even `k`, the bottom side for odd `k`, spread around the thickness axis.
    pub scanner_views: usize,
    /// The first view's tilt from the nominal thickness axis (`+z` of the scan frame), degrees.
    pub scanner_tilt_deg: f64,
    /// The tilts of views 2… (from their side's thickness axis), degrees: empty for seeded
    /// tilts in 10–55°, else exactly `scanner_views − 1` of them.
    pub view_tilts_deg: Vec<f64>,
    /// The template path's point spacing along its contours (domain arc length), mm.
    pub path_spacing_mm: f64,
    /// The CAD mesh's edge length on the faces, mm (1: 27k triangles; 0.35: 122k).
    pub mesh_step_mm: f64,
    /// The share of contours carrying burrs (flash webs; see `burr`), 0–1.
    pub burr_fraction: f64,
    /// Burr height (reach out of the material from the edge) range, mm.
    pub burr_height_mm: [f64; 2],
    /// Burr thickness range, mm.
    pub burr_thickness_mm: [f64; 2],
    /// Burr stretch length range along the contour, mm.
    pub burr_length_mm: [f64; 2],
    /// The share of the openings (holes and slots) carrying a blockage (a film over part of the
    /// opening; see `blockage`), 0–1. Left out of case.json when 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub blockage_fraction: f64,
    /// Blockage film thickness range, mm. Left out of case.json at its default.
    #[serde(skip_serializing_if = "is_default_blockage_thickness")]
    pub blockage_thickness_mm: [f64; 2],
    /// Range of the share of an opening's area a blockage covers. Left out of case.json at its
    /// default.
    #[serde(skip_serializing_if = "is_default_blockage_share")]
    pub blockage_share: [f64; 2],
}

/// Blockage film thickness range by default, mm (issue 23: 50–200 µm).
pub const DEFAULT_BLOCKAGE_THICKNESS_MM: [f64; 2] = [0.05, 0.2];

/// Range of the covered share of a blocked opening by default.
pub const DEFAULT_BLOCKAGE_SHARE: [f64; 2] = [0.3, 1.0];

// The parameters added after case.json's format settled are written only when set, so a case
// generated without them writes the file it always did.
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_default_blockage_thickness(v: &[f64; 2]) -> bool {
    *v == DEFAULT_BLOCKAGE_THICKNESS_MM
}

fn is_default_blockage_share(v: &[f64; 2]) -> bool {
    *v == DEFAULT_BLOCKAGE_SHARE
}

impl Default for SynthParams {
    fn default() -> Self {
        SynthParams {
            seed: 1,
            sag_mm: 0.3,
            bend_tilt_deg: 0.0,
            tip_curl_mm: 0.0,
            shrink_gradient: 0.0,
            twist_deg: 0.6,
            scale_range: 0.01,
            noise_mm: 0.01,
            scan_points: 200_000,
            cad_points: 200_000,
            pose_deg: 5.0,
            pose_mm: 3.0,
            outlier_fraction: 0.01,
            dropouts: 4,
            pressing_tilt_deg: 0.0,
            scanner_views: 1,
            scanner_tilt_deg: 25.0,
            view_tilts_deg: Vec::new(),
            path_spacing_mm: DEFAULT_PATH_SPACING_MM,
            mesh_step_mm: DEFAULT_MESH_STEP_MM,
            burr_fraction: 0.0,
            burr_height_mm: [0.1, 0.5],
            burr_thickness_mm: [0.02, 0.1],
            burr_length_mm: [2.0, 15.0],
            blockage_fraction: 0.0,
            blockage_thickness_mm: DEFAULT_BLOCKAGE_THICKNESS_MM,
            blockage_share: DEFAULT_BLOCKAGE_SHARE,
        }
    }
}

/// The most scan or CAD points a case may ask for: 10 million points with normals take about
/// 0.5 GB each, and the registration's working copies several times that; a larger count
/// would exhaust the memory (and abort a Python interpreter) instead of being refused.
pub const MAX_POINTS: usize = 10_000_000;

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
            "tip_curl_mm",
            self.tip_curl_mm.is_finite() && self.tip_curl_mm.abs() <= 5.0,
            "must be finite, |curl| ≤ 5 mm",
        )?;
        check(
            "twist_deg",
            self.twist_deg.is_finite() && self.twist_deg.abs() <= 10.0,
            "must be finite, |twist| ≤ 10°",
        )?;
        check(
            "shrink_gradient",
            self.shrink_gradient.is_finite() && self.shrink_gradient.abs() <= 0.02,
            "must be finite, |gradient| ≤ 0.02",
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
        let count = |name: &'static str, n: usize, most: usize| {
            check(
                name,
                (1000..=most).contains(&n),
                &format!("must be in [1000, {most}], got {n}"),
            )
        };
        count("scan_points", self.scan_points, MAX_POINTS)?;
        count("cad_points", self.cad_points, MAX_POINTS)?;
        check(
            "dropouts",
            self.dropouts <= MAX_DROPOUTS,
            &format!("must be at most {MAX_DROPOUTS}, got {}", self.dropouts),
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
            "bend_tilt_deg",
            (0.0..=60.0).contains(&self.bend_tilt_deg),
            "must be in [0, 60]°",
        )?;
        check(
            "pressing_tilt_deg",
            (0.0..=30.0).contains(&self.pressing_tilt_deg),
            "must be in [0, 30]°",
        )?;
        check(
            "scanner_views",
            (1..=4).contains(&self.scanner_views),
            "must be 1 to 4",
        )?;
        check(
            "scanner_tilt_deg",
            (0.0..=60.0).contains(&self.scanner_tilt_deg),
            "must be in [0, 60]°",
        )?;
        check(
            "view_tilts_deg",
            self.view_tilts_deg.is_empty() || self.view_tilts_deg.len() + 1 == self.scanner_views,
            &format!(
                "must be empty (seeded tilts) or give the {} views after the first, got {}",
                self.scanner_views.saturating_sub(1),
                self.view_tilts_deg.len()
            ),
        )?;
        check(
            "view_tilts_deg",
            self.view_tilts_deg.iter().all(|t| (0.0..=60.0).contains(t)),
            "every tilt must be in [0, 60]°",
        )?;
        check(
            "path_spacing_mm",
            (0.05..=0.25).contains(&self.path_spacing_mm),
            "must be in [0.05, 0.25] mm",
        )?;
        check(
            "mesh_step_mm",
            (0.25..=2.0).contains(&self.mesh_step_mm),
            "must be in [0.25, 2] mm",
        )?;
        check(
            "burr_fraction",
            (0.0..=1.0).contains(&self.burr_fraction),
            "must be in [0, 1]",
        )?;
        let range = |[lo, hi]: [f64; 2], min: f64, max: f64| lo >= min && lo <= hi && hi <= max;
        check(
            "burr_height_mm",
            range(self.burr_height_mm, 0.01, 2.0),
            "must be [min, max] with 0.01 ≤ min ≤ max ≤ 2 mm",
        )?;
        check(
            "burr_thickness_mm",
            range(self.burr_thickness_mm, 0.005, 0.5),
            "must be [min, max] with 0.005 ≤ min ≤ max ≤ 0.5 mm",
        )?;
        check(
            "burr_length_mm",
            range(self.burr_length_mm, 0.5, 50.0),
            "must be [min, max] with 0.5 ≤ min ≤ max ≤ 50 mm",
        )?;
        check(
            "blockage_fraction",
            (0.0..=1.0).contains(&self.blockage_fraction),
            "must be in [0, 1]",
        )?;
        check(
            "blockage_thickness_mm",
            range(self.blockage_thickness_mm, 0.005, 1.0),
            "must be [min, max] with 0.005 ≤ min ≤ max ≤ 1 mm",
        )?;
        check(
            "blockage_share",
            range(self.blockage_share, 0.05, 1.0),
            "must be [min, max] with 0.05 ≤ min ≤ max ≤ 1",
        )
    }
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
    /// Where the first view's scanner was, scan frame, mm (`views[0]`; for a single viewpoint).
    pub scanner_in_scan: Point3,
    /// The scanner's views, fixed to the machine (scan frame), whatever the part's true pose.
    pub views: Vec<ScanView>,
    /// The burrs on the scanned part (ground truth; none on the CAD or the template path).
    pub burrs: Vec<Burr>,
    /// The blockages on the scanned part (ground truth; none on the CAD).
    pub blockages: Vec<Blockage>,
}

impl SynthCase {
    /// The CAD as a mesh.
    pub fn cad_mesh(&self) -> Result<trim_geom::mesh::Mesh> {
        trim_geom::mesh::Mesh::new(self.cad_vertices.clone(), self.cad_triangles.clone())
    }

    /// Writes the case into `dir` (created if missing): `cad.stl`, `cad_points.ply` (with
    /// normals), `path.csv`, `scan.ply`, `truth.csv`, and `case.json` (parameters, scanner
    /// views, burrs and the true transforms: `scanner_in_scan_mm` (the first view's scanner) is
    /// what `trimctl register --viewpoint` takes, `scan_from_cad_nominal` the 16 numbers
    /// `--initial` reads from a text file, the rest is for tests).
    pub fn write_case(&self, dir: &std::path::Path) -> Result<()> {
        use trim_geom::formats::{PlyEncoding, write_path, write_ply, write_stl};
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
            views: self.views.clone(),
            burrs: self.burrs.clone(),
            blockages: self.blockages.clone(),
        };
        let text = serde_json::to_string_pretty(&meta)
            .map_err(|e| GeomError::invalid("case.json", e.to_string()))?;
        let path = dir.join("case.json");
        trim_geom::fs::write_atomic(&path, text).map_err(|e| GeomError::io(&path, e))
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
    /// The first view's scanner position, scan frame, mm.
    pub scanner_in_scan_mm: [f64; 3],
    /// The fixture's nominal `scan_from_cad`, row-major 4×4.
    pub scan_from_cad_nominal: [[f64; 4]; 4],
    /// The true rigid placement of the deformed part, row-major 4×4.
    pub scan_from_cad_true: [[f64; 4]; 4],
    /// The deformation.
    pub deformation: Deformation,
    /// The scanner's views, scan frame (absent in cases written before them: one view).
    #[serde(default)]
    pub views: Vec<ScanView>,
    /// The burrs (contour id, stretch, height, thickness; absent in cases written before them).
    #[serde(default)]
    pub burrs: Vec<Burr>,
    /// The blockages (contour id, covered share, thickness, free edge; absent when none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub blockages: Vec<Blockage>,
}

/// Generates a case (deterministic in `params.seed`).
pub fn generate(params: &SynthParams) -> Result<SynthCase> {
    params.validate()?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(params.seed);
    let cutouts = cutouts();
    let sampler = SurfaceSampler::new(cutouts.clone());
    let mesh = domain_mesh(&cutouts, params.mesh_step_mm)?;
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
    let edges = contour_edges(&cutouts);
    let path = template_path(&cutouts, params.path_spacing_mm)?;

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
        pressing_axes: pressing_axes(params.pressing_tilt_deg, params.seed),
        tip_curl_mm: params.tip_curl_mm,
        bend_tilt_rad: params.bend_tilt_deg.to_radians(),
        shrink_gradient: params.shrink_gradient,
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

    let views = fixed_views(
        params,
        &scan_from_cad_nominal,
        &mut stream(params.seed, VIEWS_STREAM),
    );
    let burrs = draw_burrs(
        &BurrRanges {
            fraction: params.burr_fraction,
            height_mm: params.burr_height_mm,
            thickness_mm: params.burr_thickness_mm,
            length_mm: params.burr_length_mm,
        },
        &edges,
        params.path_spacing_mm,
        &mut stream(params.seed, BURRS_STREAM),
    );
    let blockages = draw_blockages(
        &BlockageRanges {
            fraction: params.blockage_fraction,
            thickness_mm: params.blockage_thickness_mm,
            covered_share: params.blockage_share,
        },
        &cutouts,
        &mut stream(params.seed, BLOCKAGES_STREAM),
    );
    let scan = scan_part(
        params,
        &mut rng,
        None,
        &sampler,
        (
            &BurrSampler::new(&edges, &burrs),
            &BlockageSampler::new(&Film::of(&blockages)),
        ),
        &mesh,
        &scan_from_domain,
        &views,
    )?;
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
        scanner_in_scan: views
            .first()
            .map_or(Point3::origin(), |v| v.scanner_in_scan_mm),
        views,
        burrs,
        blockages,
    })
}

/// The pressing axes: the CAD axes turned by `[½, 1] × tilt_deg` about a seeded axis (rows of
/// the rotation's columns), the CAD axes exactly for no tilt.
fn pressing_axes(tilt_deg: f64, seed: u64) -> [[f64; 3]; 3] {
    if tilt_deg == 0.0 {
        return Deformation::identity().pressing_axes;
    }
    let mut rng = stream(seed, PRESSING_STREAM);
    let axis: [f64; 3] = UnitSphere.sample(&mut rng);
    let angle = tilt_deg.to_radians() * rng.random_range(0.5..=1.0);
    let rotation = UnitQuaternion::from_scaled_axis(Vector3::from(axis) * angle);
    [0, 1, 2].map(|i| {
        let mut e = Vector3::zeros();
        e[i] = 1.0;
        (rotation * e).into()
    })
}

#[cfg(test)]
mod limits {
    use super::*;

    /// A point count that would exhaust the memory is refused by name, before anything is
    /// allocated.
    #[test]
    fn point_counts_and_dropouts_have_an_upper_bound() {
        for (params, key) in [
            (
                SynthParams {
                    scan_points: MAX_POINTS + 1,
                    ..SynthParams::default()
                },
                "scan_points",
            ),
            (
                SynthParams {
                    cad_points: usize::MAX,
                    ..SynthParams::default()
                },
                "cad_points",
            ),
            (
                SynthParams {
                    dropouts: MAX_DROPOUTS + 1,
                    ..SynthParams::default()
                },
                "dropouts",
            ),
        ] {
            let e = params.validate().unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
            assert!(generate(&params).is_err(), "{key}");
        }
        SynthParams {
            scan_points: MAX_POINTS,
            dropouts: MAX_DROPOUTS,
            ..SynthParams::default()
        }
        .validate()
        .unwrap();
    }
}
