//! Synthetic calibration artefacts: what a true cell's scanner sees of a sphere fixed on the
//! table at a set of machine poses, and of the tool mark (for tests and
//! `trimctl synth --calibration`).
//!
//! The scanner looks along its own −Z: it sees the surfaces whose normal faces its origin, from
//! about 150 mm away. Each scan holds the sphere's visible cap, a patch of the table plane around
//! it and 2 % outliers, with Gaussian noise on every coordinate.

use std::io::Write;
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_cell::cell_model::{ScanPose, ScannerPose, TableModel};
use trim_cell::kinematics::KinematicsKind;
use trim_geom::{Point3, PointCloud, Vector3};

use crate::cell_calibration::SphereObservation;
use crate::error::CalibError;

/// Stand-off of the scanner from the sphere along its view (mm).
pub const STANDOFF_MM: f64 = 150.0;
/// Points on the sphere's cap per scan.
const CAP_POINTS: usize = 2500;
/// Points on the table plane per scan.
const TABLE_POINTS: usize = 1500;
/// Outliers, as a fraction of the scan.
const OUTLIER_FRACTION: f64 = 0.02;

/// One machine pose of the calibration: joints X, Y, Z (mm), tilt and C (degrees). The cell's
/// scan pose, as a row of poses.csv reads it (`trim_cell::scans_at_poses`).
pub type CalPose = ScanPose;

/// Where in the scanner's view the sphere is put, pose by pose (mm, scanner frame, added to
/// the stand-off): spread across the view so the scanner's rotation is determined (a sphere
/// always at one spot of the view confounds a rotation of the scanner with a translation).
const VIEW_OFFSETS_MM: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [25.0, 20.0, 15.0],
    [-25.0, 20.0, -15.0],
    [25.0, -20.0, -15.0],
    [-25.0, -20.0, 15.0],
    [30.0, 0.0, 25.0],
    [0.0, -30.0, -25.0],
    [-30.0, 10.0, 0.0],
];

/// The default pose set: tilt at −30°, 0°, +30° × C at 0°, 90°, 180°, 270°, plus four
/// in-between poses, with X, Y, Z chosen (on the nominal cell) so the sphere sits about
/// [`STANDOFF_MM`] below the scanner, at a different spot of its view from pose to pose.
#[must_use]
pub fn default_poses(nominal: &TableModel, sphere_table_mm: &Point3) -> Vec<CalPose> {
    let mut angles = Vec::new();
    for tilt in [-30.0, 0.0, 30.0] {
        for c in [0.0, 90.0, 180.0, 270.0] {
            angles.push((tilt, c));
        }
    }
    angles.extend([(-15.0, 45.0), (15.0, 135.0), (-20.0, 225.0), (20.0, 315.0)]);
    angles
        .into_iter()
        .enumerate()
        .map(|(i, (tilt_deg, c_deg))| {
            let m = nominal.machine_from_table(tilt_deg, c_deg) * sphere_table_mm;
            let v = VIEW_OFFSETS_MM[i % VIEW_OFFSETS_MM.len()];
            CalPose {
                xyz_mm: [m.x - v[0], m.y - v[1], m.z + STANDOFF_MM - v[2]],
                tilt_deg,
                c_deg,
            }
        })
        .collect()
}

/// What the calibration needs from a true cell.
#[derive(Debug, Clone)]
pub struct Artefacts {
    /// The poses, in scan order.
    pub poses: Vec<CalPose>,
    /// One scan per pose (scanner frame).
    pub scans: Vec<PointCloud>,
    /// The tool mark as the scanner saw it at the first pose (scanner frame, mm).
    pub tool_mark_mm: Point3,
}

/// The true cell and artefact the synthetic scans come from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArtefactTruth {
    /// The true rotary axes.
    pub table: TableModel,
    /// The scanner's true pose on the head.
    pub scanner: ScannerPose,
    /// The sphere's centre in the table frame (mm).
    pub sphere_table_mm: Point3,
    /// The sphere's diameter (mm).
    pub diameter_mm: f64,
    /// Where the tool mark (command 0) really lands, from the joints' tool point (mm): the
    /// head offset.
    pub tool_offset_mm: [f64; 2],
}

/// Scans of the sphere of `truth` at `poses` with `noise_mm` per coordinate, and the tool mark
/// made at the first pose, measured with 2 µm RMS (3-D) noise.
#[must_use]
pub fn synth_artefacts(
    truth: &ArtefactTruth,
    poses: &[CalPose],
    noise_mm: f64,
    seed: u64,
) -> Artefacts {
    let (table, scanner, sphere_table_mm) = (&truth.table, &truth.scanner, &truth.sphere_table_mm);
    let (diameter_mm, tool_offset_mm) = (truth.diameter_mm, truth.tool_offset_mm);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5fe2_e5ca);
    let normal = |s: f64| Normal::new(0.0, s.max(0.0)).unwrap_or_else(|_| unreachable!("σ ≥ 0"));
    let noise = normal(noise_mm);
    let r = 0.5 * diameter_mm;
    let to_scanner = |j: &[f64; 3], m: &Point3| -> Point3 {
        Point3::from(
            scanner.rotation.transpose() * (m.coords - Vector3::from(*j) - scanner.translation_mm),
        )
    };
    let mut scans = Vec::with_capacity(poses.len());
    for pose in poses {
        let motion = table.machine_from_table(pose.tilt_deg, pose.c_deg);
        let centre = to_scanner(&pose.xyz_mm, &(motion * sphere_table_mm));
        let toward_scanner = -centre.coords.normalize();
        let mut pts = Vec::with_capacity(CAP_POINTS + TABLE_POINTS);
        let jitter = |rng: &mut Xoshiro256PlusPlus, p: Point3| {
            p + Vector3::new(noise.sample(rng), noise.sample(rng), noise.sample(rng))
        };
        while pts.len() < CAP_POINTS {
            let n = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let len = n.norm();
            if !(0.1..=1.0).contains(&len) {
                continue;
            }
            let n = n / len;
            // Visible: facing the scanner by more than ~70° from grazing.
            if n.dot(&toward_scanner) < 0.35 {
                continue;
            }
            pts.push(jitter(&mut rng, centre + n * r));
        }
        // The table plane through the sphere's stem foot, around it (outside its shadow).
        let up = scanner.rotation.transpose() * (motion.rotation * Vector3::z());
        let foot = centre - up * (r + 15.0);
        let (e1, e2) = {
            let helper = if up.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let e1 = up.cross(&helper).normalize();
            (e1, up.cross(&e1))
        };
        let mut table_pts = 0;
        while table_pts < TABLE_POINTS {
            let (u, v) = (rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0));
            if f64::hypot(u, v) < 1.2 * r {
                continue;
            }
            pts.push(jitter(&mut rng, foot + e1 * u + e2 * v));
            table_pts += 1;
        }
        let outliers = (OUTLIER_FRACTION * pts.len() as f64) as usize;
        for _ in 0..outliers {
            pts.push(
                centre
                    + Vector3::new(
                        rng.random_range(-40.0..40.0),
                        rng.random_range(-40.0..40.0),
                        rng.random_range(-30.0..30.0),
                    ),
            );
        }
        scans.push(PointCloud::new(pts).unwrap_or_else(|_| unreachable!("finite points")));
    }
    // 2 µm RMS (3-D) measurement of the mark: 2/√3 µm per coordinate.
    let mark_noise = normal(crate::cell_calibration::TOOL_MARK_SIGMA_MM);
    let tool_mark_mm = poses.first().map_or(Point3::origin(), |p0| {
        let mark = Point3::new(
            p0.xyz_mm[0] + tool_offset_mm[0],
            p0.xyz_mm[1] + tool_offset_mm[1],
            p0.xyz_mm[2],
        );
        to_scanner(&p0.xyz_mm, &mark)
            + Vector3::new(
                mark_noise.sample(&mut rng),
                mark_noise.sample(&mut rng),
                mark_noise.sample(&mut rng),
            )
    });
    Artefacts {
        poses: poses.to_vec(),
        scans,
        tool_mark_mm,
    }
}

/// Observations from artefacts, fitting each sphere (for tests; the CLI reads files).
pub fn observe(
    artefacts: &Artefacts,
    diameter_mm: f64,
) -> Result<Vec<SphereObservation>, CalibError> {
    fit_observations(&artefacts.poses, &artefacts.scans, diameter_mm).map_err(|(_, e)| e)
}

/// Fits the sphere in every scan (in parallel) and pairs it with its pose. The error names the
/// index of the scan at fault.
pub fn fit_observations(
    poses: &[CalPose],
    scans: &[PointCloud],
    diameter_mm: f64,
) -> Result<Vec<SphereObservation>, (usize, CalibError)> {
    use rayon::prelude::*;
    poses
        .par_iter()
        .zip(scans)
        .enumerate()
        .map(|(i, (pose, scan))| {
            let fit = crate::sphere::fit_sphere(scan.points(), 0.5 * diameter_mm, i as u64)
                .map_err(|e| (i, e))?;
            Ok(SphereObservation {
                xyz_mm: pose.xyz_mm,
                tilt_deg: pose.tilt_deg,
                c_deg: pose.c_deg,
                centre_mm: fit.centre,
                sigma_mm: (fit.covariance.trace() / 3.0)
                    .sqrt()
                    .max(crate::cell_calibration::CENTRE_SIGMA_FLOOR_MM),
            })
        })
        .collect()
}

/// Writes the artefacts into `dir`: `spheres/pose-NN.ply` (binary), `poses.csv`
/// (`scan,x,y,z,a,c`, or `b` for B/C; scan names relative to `spheres/`) and `tool_mark.txt`
/// (`X,Y,Z`, scanner frame, mm).
pub fn write_artefacts(
    dir: &Path,
    artefacts: &Artefacts,
    kind: KinematicsKind,
) -> Result<(), CalibError> {
    let io = |path: &Path| {
        let path = path.to_owned();
        move |source| CalibError::Io {
            path: path.clone(),
            source,
        }
    };
    let spheres = dir.join("spheres");
    std::fs::create_dir_all(&spheres).map_err(io(&spheres))?;
    let poses_file = dir.join("poses.csv");
    let mut f =
        std::io::BufWriter::new(std::fs::File::create(&poses_file).map_err(io(&poses_file))?);
    let tilt = kind.tilt_axis().unwrap_or("a");
    writeln!(f, "scan,x,y,z,{tilt},c").map_err(io(&poses_file))?;
    for (i, (pose, scan)) in artefacts.poses.iter().zip(&artefacts.scans).enumerate() {
        let name = format!("pose-{i:02}.ply");
        trim_geom::formats::write_ply(
            &spheres.join(&name),
            scan,
            trim_geom::formats::PlyEncoding::BinaryLittleEndian,
        )
        .map_err(|e| CalibError::Invalid {
            key: name.clone(),
            message: e.to_string(),
        })?;
        writeln!(
            f,
            "{name},{},{},{},{},{}",
            pose.xyz_mm[0], pose.xyz_mm[1], pose.xyz_mm[2], pose.tilt_deg, pose.c_deg
        )
        .map_err(io(&poses_file))?;
    }
    f.flush().map_err(io(&poses_file))?;
    let m = artefacts.tool_mark_mm;
    let mark_file = dir.join("tool_mark.txt");
    trim_geom::fs::write_atomic(&mark_file, format!("{},{},{}\n", m.x, m.y, m.z))
        .map_err(io(&mark_file))?;
    Ok(())
}
