//! The per-contour measurement and [`inspect`].
//!
//! 1. *Crop*, scan frame: the scan points near the registered contours and openings (a kd-tree
//!    over the registered path, densified, and the openings' grids carried by the fit).
//! 2. *Map* them into the CAD frame through the fit ([`Placement::cad_from_scan_point`]).
//! 3. *Distance*: each mapped point within `band_mm` of a contour gets its signed distance to
//!    the CAD mesh (parry's closest point, inside or outside by the pseudo-normal there:
//!    [`SignedMesh`]; positive outside the material), and its rise above the face along the
//!    contour's feature vector.
//! 4. *Noise* σ: given, or 1.4826 × the median absolute deviation of the distances within
//!    0.1 mm of the surface.
//! 5. *Bins*, equal and at most `bin_length_mm` long, along each contour. A bin has *excess* when at least
//!    `min_points` points stand more than `noise_factor·σ` outside the material; its height is
//!    that of the web it belongs to, whose free edge is fitted to the readings (distance and
//!    rise above the face) of all its bins ([`crate::height::web_heights_mm`]).
//!    *Gouge* alike inside, its depth the `min_points`-th largest reading. A bin is *covered*
//!    when it holds `min_bin_points` points.
//! 6. Per contour: `excess_height_um` the largest bin height (0 when no bin has excess),
//!    `excess_length_mm` the length of the bins with excess, `gouge_depth_um` likewise,
//!    `coverage` the share of covered bins, `blocked_fraction` ([`crate::opening`]), U and the
//!    verdict ([`crate::verdict`]).

use std::time::Instant;

use parry3d_f64::query::PointQueryWithLocation;
use parry3d_f64::shape::{TriMesh, TriMeshFlags};
use rayon::prelude::*;
use trim_geom::mesh::Mesh;
use trim_geom::{ContourId, KdTree, Path, Point3};

use crate::contours::{ContourGeometry, PathIndex};
use crate::crop::Crop;
use crate::error::{InspectError, Result};
use crate::height::{Reading, web_heights_mm};
use crate::inputs::check_path_on_cad;
use crate::opening::{FilmThickness, Opening, WebStretch, opening_of, read_opening};
use crate::placement::Placement;
use crate::settings::InspectSettings;
use crate::verdict::{Limits, Measured, Verdict, decide, uncertainty_um};

/// Distances within this of the surface estimate the noise, mm.
pub const NOISE_WINDOW_MM: f64 = 0.1;

/// The noise estimate's floor, µm (a noise-free synthetic scan would otherwise call every
/// rounding error excess).
pub const MIN_NOISE_UM: f64 = 0.5;

/// A bin's excess is a web on the rim, not a film's edge, when its height stands at least this
/// far inside the band, mm (a film over an opening reads out to the band's edge).
pub const WEB_BAND_MARGIN_MM: f64 = 0.05;

/// How far across the rim (toward the centre of its curvature) and below the face the mesh is
/// probed to tell a hole's rim (the centre out of the material) from an outer corner's, mm.
const CURVATURE_PROBE_MM: f64 = 0.05;

/// Spacing of the crop's points along the registered contours, mm.
const CROP_STEP_MM: f64 = 0.1;

/// A stretch of a contour with excess (or gouge).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExcessBin {
    /// Start along the contour, mm of arc length from its first point (CAD frame).
    pub start_mm: f64,
    /// End along the contour, mm.
    pub end_mm: f64,
    /// The bin's height, µm: for excess the fitted free edge of the web the bin belongs to
    /// ([`crate::height::web_heights_mm`], on the readings of all of that web's bins); for
    /// gouge the `min_points`-th largest depth.
    pub height_um: f64,
    /// Points clearly above the noise in the bin.
    pub points: usize,
}

/// One contour's measurement and verdict.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ContourInspection {
    /// The contour's id (the path's).
    pub id: ContourId,
    /// The decision.
    pub verdict: Verdict,
    /// Largest distance of excess material from the nominal solid, µm (0: none clearly above
    /// the noise).
    pub excess_height_um: f64,
    /// Length of the contour with excess, mm.
    pub excess_length_mm: f64,
    /// Largest depth of the measured surface inside the nominal solid, µm (0: none).
    pub gouge_depth_um: f64,
    /// For a contour that rims a hole or slot: the share of the opening still covered; none
    /// where there is no opening.
    pub blocked_fraction: Option<f64>,
    /// For a blocked opening whose film the scan sees from both sides: its thickness
    /// ([`crate::opening::read_opening`]); none where only one side (or no film) is seen.
    #[serde(default)]
    pub film: Option<FilmThickness>,
    /// The expanded uncertainty U, µm.
    pub uncertainty_um: f64,
    /// Share of the contour's bins the scan covers.
    pub coverage: f64,
    /// Why the verdict is what it is.
    pub reason: String,
    /// The registration's bound for the contour, µm.
    pub bound_um: f64,
    /// The contour's length, mm (CAD frame).
    pub length_mm: f64,
    /// Scan points measured within the band.
    pub points: usize,
    /// The bins with excess, in order along the contour.
    pub excess_bins: Vec<ExcessBin>,
    /// The bins with gouge.
    pub gouge_bins: Vec<ExcessBin>,
}

/// The inspection of a part.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Inspection {
    /// The tolerance judged against, µm.
    pub tolerance_um: f64,
    /// The scan noise used (given or estimated), µm.
    pub noise_um: f64,
    /// Per contour, in path order.
    pub contours: Vec<ContourInspection>,
    /// Scan points measured (within the band of a contour).
    pub points_measured: usize,
    /// Wall time per stage, s.
    pub timings_s: Vec<(String, f64)>,
}

/// A scan point measured for a contour.
#[derive(Debug, Clone, Copy)]
struct Sample {
    contour: u32,
    arc_mm: f64,
    distance_mm: f64,
    rise_mm: f64,
}

/// The CAD surface for signed distances: parry's mesh with pseudo-normals (the angle-weighted
/// normals of edges and vertices), so a point whose nearest surface point is an edge or a
/// vertex is inside or outside by that point's pseudo-normal, not by one of the faces there
/// (a point below the top face's plane but out past a hole's rim is outside).
pub struct SignedMesh {
    trimesh: TriMesh,
}

impl SignedMesh {
    /// The oriented mesh of `mesh` (closed, consistently oriented, outward normals).
    pub fn new(mesh: &Mesh) -> Result<SignedMesh> {
        let trimesh = TriMesh::with_flags(
            mesh.vertices().to_vec(),
            mesh.triangles().to_vec(),
            TriMeshFlags::ORIENTED | TriMeshFlags::MERGE_DUPLICATE_VERTICES,
        )
        .map_err(|e| InspectError::Contour {
            contour: 0,
            message: format!("the CAD mesh cannot be oriented for signed distances: {e:?}"),
        })?;
        Ok(SignedMesh { trimesh })
    }

    /// The signed distance of a CAD-frame point, mm, positive outside the material; none for
    /// a point that is not finite or so far off that its distance overflows. parry's search
    /// keeps a face only when its distance compares below the best so far (from `f64::MAX`):
    /// a NaN point (a far outlier carried through the deformation field's extrapolation) or
    /// one past 1e154 mm (its squared distance is infinite) never does, and parry's
    /// `project_local_point_and_get_location` unwraps that `None`. The bounded query returns it.
    #[must_use]
    pub fn distance(&self, p: &Point3) -> Option<f64> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return None;
        }
        let (proj, _) = self
            .trimesh
            .project_local_point_and_get_location_with_max_dist(p, false, f64::MAX)?;
        let d = (p - proj.point).norm();
        d.is_finite().then_some(if proj.is_inside { -d } else { d })
    }
}

/// Signed distances (mm, positive outside the material) of CAD-frame points to `mesh`;
/// refuses a point whose distance cannot be measured ([`SignedMesh::distance`]), naming it
/// (leave the points far beyond the part out first: [`crate::inputs::CadExtent::near`]).
pub fn signed_distances(mesh: &Mesh, points_cad: &[Point3]) -> Result<Vec<f64>> {
    let signed = SignedMesh::new(mesh)?;
    let distances: Vec<Option<f64>> = points_cad
        .par_iter()
        .with_min_len(1024)
        .map(|p| signed.distance(p))
        .collect();
    distances
        .iter()
        .zip(points_cad)
        .enumerate()
        .map(|(index, (d, p))| {
            d.ok_or_else(|| InspectError::Unmeasurable {
                what: "CAD-frame points".into(),
                index,
                value: format!("[{}, {}, {}]", p.x, p.y, p.z),
            })
        })
        .collect()
}

fn check_points(what: &str, points: &[Point3]) -> Result<()> {
    if points.is_empty() {
        return Err(InspectError::Empty { what: what.into() });
    }
    if let Some(index) = points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        return Err(InspectError::NonFinite {
            what: what.into(),
            index,
            value: format!(
                "[{}, {}, {}]",
                points[index].x, points[index].y, points[index].z
            ),
        });
    }
    Ok(())
}

/// Inspects `path`'s contours (CAD frame) on `scan` (scan frame, mm) of the part placed on the
/// CAD `mesh` by `placement`.
pub fn inspect(
    mesh: &Mesh,
    path: &Path,
    scan: &[Point3],
    placement: &Placement,
    settings: &InspectSettings,
) -> Result<Inspection> {
    settings.validate()?;
    check_points("scan", scan)?;
    check_points("CAD mesh", mesh.vertices())?;
    check_path_on_cad(mesh.vertices(), path)?;
    let mut timings = Vec::new();
    let mut t = Instant::now();
    let mut lap = |name: &str, t: &mut Instant| {
        timings.push((name.to_string(), t.elapsed().as_secs_f64()));
        *t = Instant::now();
    };
    let index = PathIndex::new(path)?;
    let bounds = index
        .contours
        .iter()
        .map(|g| placement.bound_for(g.id))
        .collect::<Result<Vec<_>>>()?;
    lap("path", &mut t);
    let openings: Vec<Option<Opening>> = index
        .contours
        .par_iter()
        .map(|g| opening_of(g, mesh, settings))
        .collect();
    lap("openings", &mut t);

    // 1. Crop in the scan frame around the registered contours and openings.
    let mut crop_points = Vec::new();
    for g in &index.contours {
        for w in g.points.windows(2) {
            let steps = ((w[1] - w[0]).norm() / CROP_STEP_MM).ceil().max(1.0) as usize;
            for j in 0..steps {
                crop_points.push(w[0] + (w[1] - w[0]) * (j as f64 / steps as f64));
            }
        }
        if let Some(last) = g.points.last() {
            crop_points.push(*last);
        }
    }
    for o in openings.iter().flatten() {
        crop_points.extend(o.nodes.iter().step_by(2));
    }
    let crop_scan: Vec<Point3> = crop_points
        .par_iter()
        .map(|p| placement.scan_from_cad_point(p))
        .collect();
    let reach = settings
        .band_mm
        .max(settings.opening_support_mm.hypot(settings.opening_depth_mm))
        + CROP_STEP_MM
        + settings.opening_grid_mm;
    let crop = Crop::new(&crop_scan, reach);
    let cad_from_scan = placement.scan_from_cad.inverse();
    let cropped: Vec<Point3> = scan
        .par_iter()
        .with_min_len(4096)
        .filter(|q| crop.contains(q))
        .copied()
        .collect();
    // A scan wholly off the part measures nothing: say so rather than judge every contour
    // undecided for want of coverage.
    if cropped.is_empty() {
        return Err(InspectError::OffPart {
            points: scan.len(),
            reach_mm: reach,
        });
    }
    lap("crop", &mut t);
    // 2. Map into the CAD frame (a point the field's inverse does not carry to a finite one
    // is no reading).
    let mapped: Vec<Point3> = cropped
        .par_iter()
        .with_min_len(1024)
        .map(|q| placement.cad_from_scan_point(&cad_from_scan, q, settings.inverse_iterations))
        .filter(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
        .collect();
    lap("map", &mut t);

    // 3. Distances of the points in a contour's band.
    let signed = SignedMesh::new(mesh)?;
    let samples: Vec<Sample> = mapped
        .par_iter()
        .with_min_len(1024)
        .filter_map(|p| {
            let l = index.locate(p, settings.band_mm)?;
            Some(Sample {
                contour: u32::try_from(l.contour).unwrap_or(u32::MAX),
                arc_mm: l.arc_mm,
                distance_mm: signed.distance(p)?,
                rise_mm: l.rise_mm,
            })
        })
        .collect();
    lap("distances", &mut t);

    // 4. Noise.
    let noise_um = match settings.noise_um {
        Some(n) => n,
        None => estimate_noise_um(&samples),
    };
    let threshold_mm = settings.noise_factor * noise_um * 1e-3;

    // 5–6. Bins and openings.
    let mut per_contour: Vec<Vec<Sample>> = vec![Vec::new(); index.contours.len()];
    for s in &samples {
        if let Some(v) = per_contour.get_mut(s.contour as usize) {
            v.push(*s);
        }
    }
    let tree = KdTree::build(&mapped);
    lap("noise + tree", &mut t);
    let limits = Limits {
        tolerance_um: settings.tolerance_um,
        min_coverage: settings.min_coverage,
        max_blocked_fraction: settings.max_blocked_fraction,
    };
    let contours: Vec<ContourInspection> = index
        .contours
        .par_iter()
        .zip(per_contour.par_iter())
        .zip(openings.par_iter())
        .zip(bounds.par_iter())
        .map(|(((g, samples), opening), bound_um)| {
            let length_mm = g.length_mm();
            // Equal bins of at most `bin_length_mm`: a short last bin would hold few points by
            // its length alone and read as not covered (a 3.2 mm rim in four bins, the last
            // 0.2 mm long, was `undecided` at 75 % coverage).
            let n_bins = ((length_mm / settings.bin_length_mm).ceil() as usize).max(1);
            let bin_mm = if length_mm > 0.0 {
                length_mm / n_bins as f64
            } else {
                settings.bin_length_mm
            };
            let bin_of = |arc: f64| ((arc / bin_mm).floor().max(0.0) as usize).min(n_bins - 1);
            let mut counts = vec![0usize; n_bins];
            for s in samples {
                counts[bin_of(s.arc_mm)] += 1;
            }
            let above = beyond(samples, threshold_mm, 1.0, n_bins, &bin_of);
            let below = beyond(samples, threshold_mm, -1.0, n_bins, &bin_of);
            // Excess: the webs' free edges fitted along the contour (crate::height), one
            // height per web; gouge: the robust top.
            let curvature = rim_curvatures_per_mm(g, &signed, n_bins, bin_mm);
            let heights = web_heights_mm(
                &above,
                &curvature,
                g.closed,
                noise_um * 1e-3,
                threshold_mm,
                settings.band_mm,
                settings.min_points,
            );
            let bins = |lists: &[Vec<Reading>], height: &dyn Fn(usize, &[f64]) -> f64| {
                lists
                    .iter()
                    .enumerate()
                    .filter(|(_, l)| l.len() >= settings.min_points)
                    .map(|(b, l)| {
                        let mut distances: Vec<f64> = l.iter().map(|r| r.distance_mm).collect();
                        distances.sort_by(|x, y| y.total_cmp(x));
                        ExcessBin {
                            start_mm: b as f64 * bin_mm,
                            end_mm: ((b + 1) as f64 * bin_mm).min(length_mm),
                            height_um: height(b, &distances) * 1e3,
                            points: l.len(),
                        }
                    })
                    .collect::<Vec<ExcessBin>>()
            };
            let robust_top = |_: usize, l: &[f64]| l[settings.min_points - 1];
            let excess_bins = bins(&above, &|b, l| heights[b].unwrap_or(robust_top(b, l)));
            let gouge_bins = bins(&below, &robust_top);
            let top = |b: &[ExcessBin]| b.iter().map(|x| x.height_um).fold(0.0, f64::max);
            // Summed from +0 (an empty f64 sum is −0).
            let span = |b: &[ExcessBin]| b.iter().fold(0.0, |acc, x| acc + (x.end_mm - x.start_mm));
            let covered = counts
                .iter()
                .filter(|&&c| c >= settings.min_bin_points)
                .count();
            let coverage = covered as f64 / n_bins as f64;
            // The webs measured on the rim (their free edge within the band: a film's rim reads
            // out to the band's edge) and what reads as them across the face.
            let webs: Vec<WebStretch> = excess_bins
                .iter()
                .filter(|b| b.height_um < 1e3 * (settings.band_mm - WEB_BAND_MARGIN_MM))
                .map(|b| WebStretch {
                    start_mm: b.start_mm,
                    end_mm: b.end_mm,
                    reach_mm: b.height_um * 1e-3 + settings.opening_support_mm + threshold_mm,
                })
                .collect();
            let reading = opening
                .as_ref()
                .map(|o| read_opening(o, &tree, &mapped, noise_um * 1e-3, &webs, settings));
            let blocked_fraction = reading.map(|r| r.covered_share);
            let u = uncertainty_um(noise_um, *bound_um, settings.coverage_factor);
            let measured = Measured {
                excess_height_um: top(&excess_bins),
                gouge_depth_um: top(&gouge_bins),
                blocked_fraction,
                coverage,
                uncertainty_um: u,
            };
            let (verdict, reason) = decide(&measured, &limits);
            ContourInspection {
                id: g.id,
                verdict,
                excess_height_um: measured.excess_height_um,
                excess_length_mm: span(&excess_bins),
                gouge_depth_um: measured.gouge_depth_um,
                blocked_fraction,
                film: reading.and_then(|r| r.film),
                uncertainty_um: u,
                coverage,
                reason,
                bound_um: *bound_um,
                length_mm,
                points: samples.len(),
                excess_bins,
                gouge_bins,
            }
        })
        .collect();
    lap("bins + openings + verdicts", &mut t);
    Ok(Inspection {
        tolerance_um: settings.tolerance_um,
        noise_um,
        contours,
        points_measured: samples.len(),
        timings_s: timings,
    })
}

/// The rim's curvature at the middle of each of `n_bins` bins `bin_mm` long (the circle through
/// the bin's ends and middle), 1/mm: positive where its centre lies out of the material (a
/// hole's rim, whose webs narrow as they reach in), negative where it lies inside (an outer
/// corner's), told by the mesh a little across and below the rim toward the centre.
fn rim_curvatures_per_mm(
    g: &ContourGeometry,
    signed: &SignedMesh,
    n_bins: usize,
    bin_mm: f64,
) -> Vec<f64> {
    (0..n_bins)
        .map(|b| {
            let arc = (b as f64 + 0.5) * bin_mm;
            let k = g.curvature_at(arc, 0.5 * bin_mm);
            let kappa = k.norm();
            if kappa == 0.0 {
                return 0.0;
            }
            let probe = g.point_at(arc) + (k / kappa - *g.feature) * CURVATURE_PROBE_MM;
            if signed.distance(&probe).is_some_and(|d| d > 0.0) {
                kappa
            } else {
                -kappa
            }
        })
        .collect()
}

/// The readings (`side` +1: outside the material, −1: inside, distances read positive) of the
/// points standing beyond the noise threshold on that side, binned along the contour. Each
/// point reads its own distance: a neighbourhood median was tried to take the noise off a web's
/// top and read the tops 15–40 µm low (DESIGN.md "Inspection").
fn beyond(
    samples: &[Sample],
    threshold_mm: f64,
    side: f64,
    n_bins: usize,
    bin_of: &dyn Fn(f64) -> usize,
) -> Vec<Vec<Reading>> {
    let mut bins: Vec<Vec<Reading>> = vec![Vec::new(); n_bins];
    for s in samples {
        let d = side * s.distance_mm;
        if d > threshold_mm {
            bins[bin_of(s.arc_mm)].push(Reading {
                distance_mm: d,
                rise_mm: s.rise_mm,
            });
        }
    }
    bins
}

/// 1.4826 × the median absolute deviation of the distances within [`NOISE_WINDOW_MM`] of the
/// surface, µm (at least [`MIN_NOISE_UM`]).
fn estimate_noise_um(samples: &[Sample]) -> f64 {
    let mut near: Vec<f64> = samples
        .iter()
        .map(|s| s.distance_mm)
        .filter(|d| d.abs() < NOISE_WINDOW_MM)
        .collect();
    if near.is_empty() {
        return MIN_NOISE_UM;
    }
    let median = |v: &mut Vec<f64>| {
        let k = v.len() / 2;
        *v.select_nth_unstable_by(k, f64::total_cmp).1
    };
    let m = median(&mut near);
    let mut dev: Vec<f64> = near.iter().map(|d| (d - m).abs()).collect();
    (1.4826 * median(&mut dev) * 1e3).max(MIN_NOISE_UM)
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::{Contour, Vector3};

    /// A 10 × 10 × 2 mm box, top face at z = 0, and a contour along its top edge y = 0.
    fn case() -> (Mesh, Path) {
        let v = |x: f64, y: f64, z: f64| Point3::new(x, y, z);
        let vertices = vec![
            v(0.0, 0.0, -2.0),
            v(10.0, 0.0, -2.0),
            v(10.0, 10.0, -2.0),
            v(0.0, 10.0, -2.0),
            v(0.0, 0.0, 0.0),
            v(10.0, 0.0, 0.0),
            v(10.0, 10.0, 0.0),
            v(0.0, 10.0, 0.0),
        ];
        let triangles = vec![
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        let mesh = Mesh::new(vertices, triangles).unwrap_or_else(|e| panic!("{e}"));
        let points = (0..=40)
            .map(|k| v(1.0 + 0.2 * f64::from(k), 0.0, 0.0))
            .collect();
        let contour = Contour::new(1, points, Vector3::z()).unwrap_or_else(|e| panic!("{e}"));
        (
            mesh,
            Path::new(vec![contour]).unwrap_or_else(|e| panic!("{e}")),
        )
    }

    fn placement() -> Placement {
        Placement::rigid(Similarity3::identity(), 4.0)
    }

    use trim_geom::Similarity3;

    /// Points on the top face and the front wall near the contour, every 0.05 mm.
    fn clean_scan() -> Vec<Point3> {
        let mut scan = Vec::new();
        for i in 0..200 {
            let x = 0.5 + 0.05 * f64::from(i);
            for j in 0..10 {
                scan.push(Point3::new(x, 0.05 * f64::from(j), 0.0));
                scan.push(Point3::new(x, 0.0, -0.05 * f64::from(j)));
            }
        }
        scan
    }

    #[test]
    fn a_web_off_the_edge_is_excess_as_tall_as_its_reach() {
        let (mesh, path) = case();
        let mut scan = clean_scan();
        // A web 0.2 mm out of the front wall from x = 4 to 6, flush with the top face and
        // 0.05 mm thick: its upper side and its free edge.
        for i in 0..40 {
            let x = 4.0 + 0.05 * f64::from(i);
            for j in 1..=8 {
                scan.push(Point3::new(x, -0.025 * f64::from(j), 0.0));
            }
            for k in 1..=5 {
                scan.push(Point3::new(x, -0.2, -0.01 * f64::from(k)));
            }
        }
        let settings = InspectSettings {
            noise_um: Some(2.0),
            ..InspectSettings::default()
        };
        let r =
            inspect(&mesh, &path, &scan, &placement(), &settings).unwrap_or_else(|e| panic!("{e}"));
        let c = &r.contours[0];
        assert!((c.excess_height_um - 200.0).abs() < 1.0, "{c:?}");
        assert!((c.excess_length_mm - 2.0).abs() < 1e-9, "{c:?}");
        assert_eq!(c.gouge_depth_um, 0.0);
        assert_eq!(c.verdict, Verdict::Fail, "{c:?}");
        assert_eq!(c.blocked_fraction, None);
        // Without the web: nothing, and it passes (U = 2·√(2² + 2²) µm).
        let clean = inspect(&mesh, &path, &clean_scan(), &placement(), &settings)
            .unwrap_or_else(|e| panic!("{e}"));
        let c = &clean.contours[0];
        assert_eq!((c.excess_height_um, c.gouge_depth_um), (0.0, 0.0), "{c:?}");
        assert_eq!(c.verdict, Verdict::Pass, "{c:?}");
        assert!((c.uncertainty_um - 2.0 * 8f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn a_cut_below_the_face_is_a_gouge() {
        let (mesh, path) = case();
        let scan: Vec<Point3> = clean_scan()
            .into_iter()
            .map(|p| {
                if (5.0..6.0).contains(&p.x) && p.z == 0.0 {
                    Point3::new(p.x, p.y, -0.08)
                } else {
                    p
                }
            })
            .collect();
        let settings = InspectSettings {
            noise_um: Some(2.0),
            ..InspectSettings::default()
        };
        let r =
            inspect(&mesh, &path, &scan, &placement(), &settings).unwrap_or_else(|e| panic!("{e}"));
        let c = &r.contours[0];
        assert!((c.gouge_depth_um - 80.0).abs() < 1.0, "{c:?}");
        assert_eq!(c.verdict, Verdict::Fail);
    }

    #[test]
    fn a_contour_the_scan_misses_is_undecided_with_the_reason() {
        let (mesh, path) = case();
        let scan: Vec<Point3> = clean_scan().into_iter().filter(|p| p.x < 4.0).collect();
        let r = inspect(
            &mesh,
            &path,
            &scan,
            &placement(),
            &InspectSettings::default(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let c = &r.contours[0];
        assert_eq!(c.verdict, Verdict::Undecided);
        assert!(c.coverage < 0.5, "{c:?}");
        assert!(c.reason.contains("covers"), "{}", c.reason);
    }

    /// A far outlier in the scan (1e4 mm, 1e300 mm off) is no reading and changes nothing; a
    /// signed distance asked of it is refused, not a panic in parry (which unwrapped the
    /// `None` of its search for a NaN or overflowing point); a scan wholly off the part and a
    /// contour far off the CAD are refused naming the cause.
    #[test]
    fn far_outliers_are_left_out_and_a_scan_off_the_part_is_refused() {
        let (mesh, path) = case();
        let settings = InspectSettings {
            noise_um: Some(2.0),
            ..InspectSettings::default()
        };
        let clean = inspect(&mesh, &path, &clean_scan(), &placement(), &settings)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut scan = clean_scan();
        scan.push(Point3::new(1e4, 0.0, 0.0));
        scan.push(Point3::new(1e300, 0.0, 0.0));
        let r =
            inspect(&mesh, &path, &scan, &placement(), &settings).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(r.contours, clean.contours);
        let signed = SignedMesh::new(&mesh).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(signed.distance(&Point3::new(1e300, 5.0, -1.0)), None);
        assert_eq!(signed.distance(&Point3::new(f64::NAN, 5.0, -1.0)), None);
        assert_eq!(
            signed.distance(&Point3::new(1e4, 5.0, -1.0)),
            Some(1e4 - 10.0)
        );
        let e = signed_distances(&mesh, &[Point3::origin(), Point3::new(1e300, 0.0, 0.0)])
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("point 1") && e.contains("cannot be measured"),
            "{e}"
        );
        let off: Vec<Point3> = clean_scan()
            .into_iter()
            .map(|p| p + Vector3::new(500.0, 0.0, 0.0))
            .collect();
        let e = inspect(&mesh, &path, &off, &placement(), &settings)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("none of its 4000 points"), "{e}");
        let far = Contour::new(
            4,
            vec![Point3::new(5e4, 0.0, 0.0), Point3::new(5e4 + 1.0, 0.0, 0.0)],
            Vector3::z(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let mut contours = path.contours().to_vec();
        contours.push(far);
        let far_path = Path::new(contours).unwrap_or_else(|e| panic!("{e}"));
        let e = inspect(&mesh, &far_path, &clean_scan(), &placement(), &settings)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("contour 4 lies 49991 mm outside the CAD's bounding box"),
            "{e}"
        );
    }

    #[test]
    fn bad_inputs_are_refused_naming_them() {
        let (mesh, path) = case();
        let s = InspectSettings::default();
        let e = inspect(&mesh, &path, &[], &placement(), &s).err();
        assert!(
            matches!(e, Some(InspectError::Empty { ref what }) if what == "scan"),
            "{e:?}"
        );
        let mut scan = clean_scan();
        scan[7] = Point3::new(1.0, f64::NAN, 0.0);
        let e = inspect(&mesh, &path, &scan, &placement(), &s)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("scan: point 7 is not finite"), "{e}");
        scan[7] = Point3::new(f64::INFINITY, 0.0, 0.0);
        assert!(inspect(&mesh, &path, &scan, &placement(), &s).is_err());
        let bad = InspectSettings {
            band_mm: 0.0,
            ..InspectSettings::default()
        };
        let e = inspect(&mesh, &path, &clean_scan(), &placement(), &bad)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("band_mm"), "{e}");
        // A one-point contour is refused where it is made (trim-geom), naming the contour.
        let one = Contour::new(9, vec![Point3::origin()], Vector3::z());
        let e = one
            .err()
            .map(|e| InspectError::from(e).to_string())
            .unwrap_or_default();
        assert!(
            e.contains("contour 9") && e.contains("at least 2 points"),
            "{e}"
        );
        // A registration whose report lacks a contour of the path is refused by id.
        let no_bound = Placement {
            default_bound_um: None,
            ..placement()
        };
        let e = inspect(&mesh, &path, &clean_scan(), &no_bound, &s)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("no contour 1"), "{e}");
    }
}
