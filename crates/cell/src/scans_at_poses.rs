//! Scans of one clamped part taken at several machine poses, as one cloud in the work-piece
//! frame (DESIGN.md "Inspection", *Merge and fit*; job.toml `[part] scans` and `poses`).
//!
//! A scanner fixed to the machine sees the part from where the machine puts it. What one pose
//! cannot see (the wall below an edge, an end face) another can, and the cell knows each pose:
//! every scan goes into the work-piece frame through the job's `[calibration]` and `[machine]`
//! at its own pose ([`ScanChain::workpiece_from_scanner`]), and the clouds are concatenated.
//!
//! - [`parse_poses`] reads poses.csv (header `scan,x,y,z,a,c`, or `scan,x,y,z,b,c` on a B/C
//!   cell; one row per scan file, named by its file name; X, Y, Z joint positions in mm, the
//!   rotary axes in degrees), the format `trimctl calibrate cell` also reads; it does no I/O
//!   itself, [`read_poses`] reads the file. Every error names the file and the line.
//! - [`merge`] carries scans held in memory; [`merge_files`] reads the scan files a poses file
//!   names and carries them.
//!
//! [`ScanChain::workpiece_from_scanner`]: crate::cell_model::ScanChain::workpiece_from_scanner

use std::path::{Path, PathBuf};

use trim_geom::formats::read_points;
use trim_geom::{GeomError, PointCloud, Similarity3};

use crate::cell_model::ScanPose;
use crate::kinematics::{KinematicsKind, MachineSettings};
use crate::plan_settings::PlanSettings;

/// The header of poses.csv on an A/C cell (a B/C cell writes `b` for `a`).
pub const POSES_HEADER: &str = "scan,x,y,z,a,c";

/// What can go wrong reading poses.csv or merging scans at their poses. Every variant names
/// the file (and the line) or the scan at fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScansError {
    /// The poses file cannot be read.
    #[error("cannot read {}", path.display())]
    ReadPoses {
        /// The poses file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The poses file holds no header (only blank and `#` comment lines, or nothing).
    #[error("{}: empty file: expected the header {POSES_HEADER}", path.display())]
    EmptyPoses {
        /// The poses file.
        path: PathBuf,
    },
    /// The first line is not a header this code reads.
    #[error(
        "{}:{line}: expected the header {POSES_HEADER} (or scan,x,y,z,b,c), got {header:?}",
        path.display()
    )]
    PosesHeader {
        /// The poses file.
        path: PathBuf,
        /// The header's 1-based line.
        line: usize,
        /// The header as written.
        header: String,
    },
    /// A row has another number of columns than six.
    #[error("{}:{line}: expected 6 columns, got {got}", path.display())]
    PosesColumns {
        /// The poses file.
        path: PathBuf,
        /// The row's 1-based line.
        line: usize,
        /// The columns it has.
        got: usize,
    },
    /// A value of a row is not a finite number.
    #[error(
        "{}:{line}: column {column} ({name}): {text:?} is not a finite number",
        path.display()
    )]
    PosesValue {
        /// The poses file.
        path: PathBuf,
        /// The row's 1-based line.
        line: usize,
        /// The 1-based column.
        column: usize,
        /// The column's header name (`x`, `a`, …).
        name: String,
        /// The value as written.
        text: String,
    },
    /// A row's scan name is empty, or already has a row above.
    #[error("{}:{line}: {reason}", path.display())]
    PosesScan {
        /// The poses file.
        path: PathBuf,
        /// The row's 1-based line.
        line: usize,
        /// What is wrong with the name.
        reason: String,
    },
    /// A row's pose is outside the job's `[machine]` limits: the machine cannot have stood there
    /// (a mistyped value, degrees taken for radians, or the poses of another cell).
    #[error(
        "{}:{line}: scan {scan}: {why}: outside the [machine] limits, a pose this machine cannot take",
        path.display()
    )]
    PosesLimits {
        /// The poses file.
        path: PathBuf,
        /// The row's 1-based line.
        line: usize,
        /// The row's scan name.
        scan: String,
        /// Which axis is out, and by how much.
        why: String,
    },
    /// A scan held in memory is at a pose outside the job's `[machine]` limits.
    #[error(
        "{scan}: the pose {why}: outside the [machine] limits, a pose this machine cannot take"
    )]
    PoseLimits {
        /// The scan (`scans[1]`).
        scan: String,
        /// Which axis is out, and by how much.
        why: String,
    },
    /// Two scan files given share a file name, which names their row in the poses file (the
    /// same file twice, or two folders' files of one name).
    #[error(
        "scans {} and {} share the file name {name}, which names their row in {}: give each scan once, under a name of its own",
        first.display(),
        second.display(),
        poses.display()
    )]
    SameScanName {
        /// The first file.
        first: PathBuf,
        /// The second file.
        second: PathBuf,
        /// The shared file name.
        name: String,
        /// The poses file.
        poses: PathBuf,
    },
    /// The poses file's header names another cell than the job's `[machine]`.
    #[error(
        "{}: the header names a {} cell, the job's [machine] is {}",
        path.display(),
        header.name(),
        machine.name()
    )]
    KinematicsMismatch {
        /// The poses file.
        path: PathBuf,
        /// The kinematics the header implies (`a` column: xyzac-trt, `b`: xyzbc-trt).
        header: KinematicsKind,
        /// The job's `[machine] kinematics`.
        machine: KinematicsKind,
    },
    /// A scan file has no row in the poses file.
    #[error("{}: no pose for scan {name} in {}", scan.display(), poses.display())]
    NoPose {
        /// The scan file.
        scan: PathBuf,
        /// Its file name, which a row would carry.
        name: String,
        /// The poses file.
        poses: PathBuf,
    },
    /// A scan file cannot be read.
    #[error("reading {}", path.display())]
    ReadScan {
        /// The scan file.
        path: PathBuf,
        /// What went wrong.
        #[source]
        source: GeomError,
    },
    /// A scan cannot be carried into the work-piece frame (a non-finite pose or calibration,
    /// or a point carried out of the finite range).
    #[error("{scan} through [calibration] at its pose")]
    Chain {
        /// The scan: its file, or its place in the list given (`scans[1]`).
        scan: String,
        /// What went wrong.
        #[source]
        source: GeomError,
    },
    /// A scan held in memory has no points.
    #[error("{scan}: no points")]
    EmptyScan {
        /// The scan's place in the list given (`scans[1]`).
        scan: String,
    },
    /// Nothing to merge.
    #[error("no scans to merge")]
    NoScans,
}

/// One row of poses.csv: the scan's file name and the machine pose it was taken at.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseRow {
    /// The scan's file name (no folder).
    pub scan: String,
    /// Where the machine stood: X, Y, Z joints (mm), the tilting axis and C (degrees).
    pub pose: ScanPose,
    /// The row's 1-based line in its file (blank and comment lines counted).
    pub line: usize,
}

/// A poses file: its rows in order and the cell its header implies.
#[derive(Debug, Clone, PartialEq)]
pub struct Poses {
    /// The file (named in errors).
    pub path: PathBuf,
    /// The kinematics the header implies: an `a` column xyzac-trt, a `b` column xyzbc-trt.
    pub kinematics: KinematicsKind,
    /// The rows, in file order.
    pub rows: Vec<PoseRow>,
}

impl Poses {
    /// Refuses a poses file whose header names another cell than `machine` (the job's
    /// `[machine] kinematics`).
    pub fn require_kinematics(&self, machine: KinematicsKind) -> Result<(), ScansError> {
        if self.kinematics == machine {
            Ok(())
        } else {
            Err(ScansError::KinematicsMismatch {
                path: self.path.clone(),
                header: self.kinematics,
                machine,
            })
        }
    }

    /// Refuses a row whose pose is outside `machine`'s joint limits, naming the file, the line
    /// and the axis.
    pub fn require_within(&self, machine: &MachineSettings) -> Result<(), ScansError> {
        for row in &self.rows {
            if let Some(why) = row.pose.limit_violation(machine) {
                return Err(ScansError::PosesLimits {
                    path: self.path.clone(),
                    line: row.line,
                    scan: row.scan.clone(),
                    why,
                });
            }
        }
        Ok(())
    }

    /// The pose of the scan file `scan` (its file name names its row; names are unique).
    pub fn pose_of(&self, scan: &Path) -> Result<ScanPose, ScansError> {
        let name = scan
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        match self.rows.iter().find(|r| r.scan == name) {
            Some(row) => Ok(row.pose),
            None => Err(ScansError::NoPose {
                scan: scan.to_path_buf(),
                name,
                poses: self.path.clone(),
            }),
        }
    }
}

/// Parses poses.csv held in `text`; `path` names the file in errors. Blank lines and lines
/// starting with `#` are skipped (line numbers count them).
pub fn parse_poses(text: &str, path: &Path) -> Result<Poses, ScansError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((header_line, header)) = lines.next() else {
        return Err(ScansError::EmptyPoses {
            path: path.to_path_buf(),
        });
    };
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let kinematics = match cols.as_slice() {
        ["scan", "x", "y", "z", "a", "c"] => KinematicsKind::XyzacTrt,
        ["scan", "x", "y", "z", "b", "c"] => KinematicsKind::XyzbcTrt,
        _ => {
            return Err(ScansError::PosesHeader {
                path: path.to_path_buf(),
                line: header_line,
                header: header.to_owned(),
            });
        }
    };
    let mut rows: Vec<PoseRow> = Vec::new();
    for (line, text) in lines {
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        if fields.len() != cols.len() {
            return Err(ScansError::PosesColumns {
                path: path.to_path_buf(),
                line,
                got: fields.len(),
            });
        }
        let mut values = [0.0; 5];
        for (k, (value, text)) in values.iter_mut().zip(&fields[1..]).enumerate() {
            *value = text
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| ScansError::PosesValue {
                    path: path.to_path_buf(),
                    line,
                    column: k + 2,
                    name: cols[k + 1].to_owned(),
                    text: (*text).to_owned(),
                })?;
        }
        let scan_error = |reason: String| ScansError::PosesScan {
            path: path.to_path_buf(),
            line,
            reason,
        };
        if fields[0].is_empty() {
            return Err(scan_error("column 1 (scan): no scan file name".into()));
        }
        if let Some(first) = rows.iter().find(|r| r.scan == fields[0]).map(|r| r.line) {
            return Err(scan_error(format!(
                "scan {} already has a pose on line {first}",
                fields[0]
            )));
        }
        let [x, y, z, tilt_deg, c_deg] = values;
        rows.push(PoseRow {
            scan: fields[0].to_owned(),
            pose: ScanPose {
                xyz_mm: [x, y, z],
                tilt_deg,
                c_deg,
            },
            line,
        });
    }
    Ok(Poses {
        path: path.to_path_buf(),
        kinematics,
        rows,
    })
}

/// Reads and parses the poses file `path` ([`parse_poses`]), warning when its last row has no
/// line end (`trim_geom::formats::warn_if_unterminated`).
pub fn read_poses(path: &Path) -> Result<Poses, ScansError> {
    let text = std::fs::read_to_string(path).map_err(|source| ScansError::ReadPoses {
        path: path.to_path_buf(),
        source,
    })?;
    let poses = parse_poses(&text, path)?;
    trim_geom::formats::warn_if_unterminated(text.as_bytes(), path);
    Ok(poses)
}

/// The scan `scan_in_scanner` (scanner frame, mm), taken with the machine at `pose`, in the
/// work-piece frame through `settings`' `[calibration]` and `[machine]`. Refuses a non-finite
/// chain and a point carried out of the finite range.
pub fn workpiece_from_scanner_at(
    settings: &PlanSettings,
    pose: ScanPose,
    scan_in_scanner: &PointCloud,
) -> Result<PointCloud, GeomError> {
    let workpiece_from_scanner = settings.scan_chain(pose).workpiece_from_scanner();
    scan_in_scanner.transformed(&Similarity3::from_isometry(workpiece_from_scanner, 1.0))
}

/// Scans held in memory (scanner frame, mm), each with the pose it was taken at, as one cloud
/// in the work-piece frame (points only; normals are dropped). Errors name a scan by its place
/// in `scans` (`scans[1]`).
pub fn merge(
    scans: &[(ScanPose, PointCloud)],
    settings: &PlanSettings,
) -> Result<PointCloud, ScansError> {
    if scans.is_empty() {
        return Err(ScansError::NoScans);
    }
    let mut points = Vec::with_capacity(scans.iter().map(|(_, s)| s.len()).sum());
    for (k, (pose, scan)) in scans.iter().enumerate() {
        let label = || format!("scans[{k}]");
        if scan.is_empty() {
            return Err(ScansError::EmptyScan { scan: label() });
        }
        // A NaN or infinite pose is the chain's to refuse, below, as not finite.
        let finite = pose.validate().is_ok();
        if let Some(why) = pose.limit_violation(&settings.machine).filter(|_| finite) {
            return Err(ScansError::PoseLimits { scan: label(), why });
        }
        let moved = workpiece_from_scanner_at(settings, *pose, scan).map_err(|source| {
            ScansError::Chain {
                scan: label(),
                source,
            }
        })?;
        points.extend_from_slice(moved.points());
    }
    cloud(points)
}

/// The scan files `files`, each at the pose its file name has in `poses`, as one cloud in the
/// work-piece frame (points only). The caller checks `poses` against the job's `[machine]`
/// kinematics ([`Poses::require_kinematics`]); a row outside its limits, and a file without a
/// row, are refused before any scan is read.
pub fn merge_files(
    files: &[PathBuf],
    poses: &Poses,
    settings: &PlanSettings,
) -> Result<PointCloud, ScansError> {
    if files.is_empty() {
        return Err(ScansError::NoScans);
    }
    poses.require_within(&settings.machine)?;
    let name = |f: &PathBuf| f.file_name().map(|n| n.to_string_lossy().into_owned());
    for (k, second) in files.iter().enumerate() {
        if let Some(first) = files[..k].iter().find(|f| name(f) == name(second)) {
            return Err(ScansError::SameScanName {
                first: first.clone(),
                second: second.clone(),
                name: name(second).unwrap_or_default(),
                poses: poses.path.clone(),
            });
        }
    }
    let at: Vec<ScanPose> = files
        .iter()
        .map(|f| poses.pose_of(f))
        .collect::<Result<_, _>>()?;
    let mut points = Vec::new();
    for (file, pose) in files.iter().zip(at) {
        let scan = read_points(file).map_err(|source| ScansError::ReadScan {
            path: file.clone(),
            source,
        })?;
        let moved = workpiece_from_scanner_at(settings, pose, &scan).map_err(|source| {
            ScansError::Chain {
                scan: file.display().to_string(),
                source,
            }
        })?;
        points.extend_from_slice(moved.points());
    }
    cloud(points)
}

/// The merged points as a cloud (they are finite: each scan's were checked when carried).
fn cloud(points: Vec<trim_geom::Point3>) -> Result<PointCloud, ScansError> {
    PointCloud::new(points).map_err(|source| ScansError::Chain {
        scan: "the merged scans".to_owned(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use nalgebra::Rotation3;
    use trim_geom::formats::{PlyEncoding, write_ply};
    use trim_geom::{Point3, Vector3};

    use super::*;
    use crate::cell_model::Calibration;
    use crate::kinematics::MachineSettings;

    /// How close a merged point lands on the work-piece point it was made from, mm.
    const SAME_POINT_MM: f64 = 1e-9;

    /// A calibrated A/C cell, off its nominal lines and with the scanner turned and shifted on
    /// the head, with the work piece off the table's origin: a merge that left any of it out
    /// misses by millimetres.
    fn calibrated() -> PlanSettings {
        let mut s = PlanSettings {
            machine: MachineSettings {
                workpiece_origin_mm: [2.0, -1.5, 4.0],
                ..MachineSettings::default()
            },
            ..PlanSettings::default()
        };
        let r = Rotation3::from_euler_angles(0.01, -0.02, 0.03);
        let row = |i: usize| [r[(i, 0)], r[(i, 1)], r[(i, 2)]];
        s.calibration = Calibration {
            a_axis_point_mm: Some([0.05, 20.08, 9.97]),
            a_axis_direction: Some([1.0, 0.0003, -0.0002]),
            c_axis_point_mm: Some([-0.04, 0.06, 0.0]),
            c_axis_direction: Some([0.0004, -0.0001, 1.0]),
            scanner_rotation: Some([row(0), row(1), row(2)]),
            scanner_translation_mm: Some([1.0, -2.0, 150.0]),
            ..Calibration::default()
        };
        s.calibration
            .validate(s.machine.kinematics)
            .expect("a valid calibration");
        s
    }

    /// Where the scanner sees the work-piece point `p` with the machine at `pose`, written out
    /// from the chain's definition (DESIGN.md "Frames"): the table point `p + origin` is at
    /// `Rot_A·Rot_C·(p + origin)` in the machine frame, and there at `(X, Y, Z) + R·s + t`.
    fn seen_at(settings: &PlanSettings, pose: &ScanPose, p: &Point3) -> Point3 {
        let origin = Vector3::from(settings.machine.workpiece_origin_mm);
        let in_machine = settings
            .table()
            .machine_from_table(pose.tilt_deg, pose.c_deg)
            * (p + origin);
        let scanner = settings.calibration.scanner();
        Point3::from(
            scanner.rotation.transpose()
                * (in_machine.coords - Vector3::from(pose.xyz_mm) - scanner.translation_mm),
        )
    }

    fn two_sides() -> (Vec<Point3>, Vec<Point3>, [ScanPose; 2]) {
        // A seeded spread of points over a 40 × 12 × 6 mm block, split into two sides.
        let mut state = 0x5eed_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let points: Vec<Point3> = (0..400)
            .map(|_| Point3::new(40.0 * next(), 12.0 * next(), 6.0 * next()))
            .collect();
        let (top, bottom) = points.iter().partition(|p| p.z >= 0.0);
        let poses = [
            ScanPose {
                xyz_mm: [5.0, -3.0, 20.0],
                tilt_deg: 0.0,
                c_deg: 0.0,
            },
            ScanPose {
                xyz_mm: [-12.0, 8.0, 35.0],
                tilt_deg: -25.0,
                c_deg: 140.0,
            },
        ];
        (top, bottom, poses)
    }

    /// Each side as the scanner at its pose sees it through `settings`, and the work-piece
    /// points the merge must give back (the sides in order).
    fn seen_at_poses(
        settings: &PlanSettings,
        top: &[Point3],
        bottom: &[Point3],
        poses: &[ScanPose; 2],
    ) -> (Vec<(ScanPose, PointCloud)>, Vec<Point3>) {
        let scans = [(&poses[0], top), (&poses[1], bottom)]
            .into_iter()
            .map(|(pose, side)| {
                let seen = side.iter().map(|p| seen_at(settings, pose, p)).collect();
                (*pose, PointCloud::new(seen).expect("finite points"))
            })
            .collect();
        (scans, top.iter().chain(bottom).copied().collect())
    }

    fn worst_mm(merged: &PointCloud, expected: &[Point3]) -> f64 {
        assert_eq!(merged.len(), expected.len());
        merged
            .points()
            .iter()
            .zip(expected)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max)
    }

    #[test]
    fn two_scans_at_two_poses_merge_onto_the_same_workpiece_points() {
        let settings = calibrated();
        let (top, bottom, poses) = two_sides();
        let (scans, expected) = seen_at_poses(&settings, &top, &bottom, &poses);
        let merged = merge(&scans, &settings).expect("merges");
        let worst = worst_mm(&merged, &expected);
        assert!(worst < SAME_POINT_MM, "{worst:e} mm off");
        // The calibration is used: through the nominal cell the same scans land elsewhere.
        let nominal = merge(&scans, &PlanSettings::default()).expect("merges");
        assert!(worst_mm(&nominal, &expected) > 1.0);

        // The same scans as files named in poses.csv (in another order than the rows), read
        // and merged the same way.
        let dir = std::env::temp_dir().join(format!("trim-scans-at-poses-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let mut csv = format!("# two sides\n{POSES_HEADER}\n");
        let mut files = Vec::new();
        for (k, (pose, scan)) in scans.iter().enumerate() {
            let file = dir.join(format!("side{k}.ply"));
            write_ply(&file, scan, PlyEncoding::BinaryLittleEndian).expect("written");
            files.push(file);
            let [x, y, z] = pose.xyz_mm;
            csv.push_str(&format!(
                "side{k}.ply,{x},{y},{z},{},{}\n",
                pose.tilt_deg, pose.c_deg
            ));
        }
        let poses_file = dir.join("poses.csv");
        trim_geom::fs::write_atomic(&poses_file, csv).expect("written");
        let poses = read_poses(&poses_file).expect("reads");
        assert_eq!(poses.kinematics, KinematicsKind::XyzacTrt);
        poses
            .require_kinematics(settings.machine.kinematics)
            .expect("an A/C cell");
        let from_files = merge_files(&files, &poses, &settings).expect("merges");
        let worst = worst_mm(&from_files, &expected);
        assert!(worst < SAME_POINT_MM, "{worst:e} mm off");

        // A scan without a row is refused by name before anything is read.
        let stray = dir.join("side9.ply");
        let e = merge_files(&[files[0].clone(), stray], &poses, &settings)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no pose for scan side9.ply"), "{e}");
        let e = poses
            .require_kinematics(KinematicsKind::XyzbcTrt)
            .unwrap_err()
            .to_string();
        assert!(e.contains("header names a xyzac-trt cell"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_bc_cell_merges_through_its_own_lines() {
        let settings = PlanSettings {
            machine: MachineSettings {
                kinematics: KinematicsKind::XyzbcTrt,
                workpiece_origin_mm: [0.5, 0.0, -1.0],
                ..MachineSettings::default()
            },
            ..PlanSettings::default()
        };
        let (top, bottom, poses) = two_sides();
        let (scans, expected) = seen_at_poses(&settings, &top, &bottom, &poses);
        let worst = worst_mm(&merge(&scans, &settings).expect("merges"), &expected);
        assert!(worst < SAME_POINT_MM, "{worst:e} mm off");
        let poses = parse_poses("scan,x,y,z,b,c\n", Path::new("p.csv")).expect("parses");
        assert_eq!(poses.kinematics, KinematicsKind::XyzbcTrt);
    }

    #[test]
    fn a_pose_outside_the_machine_limits_is_refused_naming_the_line_and_the_axis() {
        let settings = PlanSettings::default();
        let file = Path::new("cell/poses.csv");
        let poses = parse_poses(
            "scan,x,y,z,a,c\na.ply,0,0,0,-30,90\n# A past its stop\nb.ply,0,0,0,120,0\n",
            file,
        )
        .unwrap();
        let e = poses
            .require_within(&settings.machine)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "cell/poses.csv:4: scan b.ply: A = 120.000° outside [-100.0, 50.0]: outside the \
             [machine] limits, a pose this machine cannot take"
        );
        // merge_files refuses it before reading any scan (the files need not exist).
        let e = merge_files(&[PathBuf::from("/nonexistent/a.ply")], &poses, &settings)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("cell/poses.csv:4: scan b.ply: A = 120.000°"),
            "{e}"
        );
        // In memory, the scan is named by its place.
        let far = ScanPose {
            xyz_mm: [250.0, 0.0, 0.0],
            tilt_deg: 0.0,
            c_deg: 0.0,
        };
        let scan = PointCloud::new(vec![Point3::origin()]).unwrap();
        let e = merge(&[(far, scan)], &settings).unwrap_err().to_string();
        assert_eq!(
            e,
            "scans[0]: the pose joint X = 250.000 mm outside [-200.0, 200.0]: outside the \
             [machine] limits, a pose this machine cannot take"
        );
        // Within the limits, both pass.
        parse_poses("scan,x,y,z,a,c\na.ply,199,-99,119,-100,35999\n", file)
            .unwrap()
            .require_within(&settings.machine)
            .unwrap();
    }

    #[test]
    fn bad_poses_rows_are_refused_naming_the_file_and_line() {
        let file = Path::new("cell/poses.csv");
        for (text, expected) in [
            (
                "",
                "cell/poses.csv: empty file: expected the header scan,x,y,z,a,c",
            ),
            ("# only a comment\n\n", "cell/poses.csv: empty file"),
            (
                "# poses\nscan,x,y,z,t,c\n",
                "cell/poses.csv:2: expected the header scan,x,y,z,a,c (or scan,x,y,z,b,c), got \"scan,x,y,z,t,c\"",
            ),
            (
                "scan,x,y,z,a,c\na.ply,1,2,3,4,5\n\nb.ply,1,2,3,4\n",
                "cell/poses.csv:4: expected 6 columns, got 5",
            ),
            (
                "scan,x,y,z,a,c\na.ply,1,2,3,4,5,6\n",
                "cell/poses.csv:2: expected 6 columns, got 7",
            ),
            (
                "scan,x,y,z,a,c\na.ply,1,2,3,4,5\nb.ply,1,two,3,4,5\n",
                "cell/poses.csv:3: column 3 (y): \"two\" is not a finite number",
            ),
            (
                "scan,x,y,z,b,c\n# a note\na.ply,1,2,3,NaN,5\n",
                "cell/poses.csv:3: column 5 (b): \"NaN\" is not a finite number",
            ),
            (
                "scan,x,y,z,a,c\na.ply,1,2,3,4,inf\n",
                "cell/poses.csv:2: column 6 (c): \"inf\" is not a finite number",
            ),
            (
                "scan,x,y,z,a,c\na.ply,1,2,3,4,5\n# again\na.ply,1,2,3,4,6\n",
                "cell/poses.csv:4: scan a.ply already has a pose on line 2",
            ),
            (
                "scan,x,y,z,a,c\n ,1,2,3,4,5\n",
                "cell/poses.csv:2: column 1 (scan): no scan file name",
            ),
        ] {
            let e = parse_poses(text, file).unwrap_err().to_string();
            assert!(e.starts_with(expected), "{text:?}: {e}");
        }
        let poses = parse_poses("scan, x, y, z, a, c\n a.ply , 1, 2.5, -3, 10, 200\n", file)
            .expect("spaces around fields are fine");
        assert_eq!(
            poses.rows,
            vec![PoseRow {
                scan: "a.ply".to_owned(),
                pose: ScanPose {
                    xyz_mm: [1.0, 2.5, -3.0],
                    tilt_deg: 10.0,
                    c_deg: 200.0,
                },
                line: 2,
            }]
        );
        let e = read_poses(Path::new("/nonexistent/poses.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot read /nonexistent/poses.csv"), "{e}");
    }

    #[test]
    fn scans_sharing_a_file_name_are_refused_before_any_is_read() {
        let poses = parse_poses(
            "scan,x,y,z,a,c\nscan.ply,0,0,0,0,0\n",
            Path::new("cell/poses.csv"),
        )
        .expect("poses");
        let settings = PlanSettings::default();
        for files in [
            ["day1/scan.ply", "day1/scan.ply"],
            ["day1/scan.ply", "day2/scan.ply"],
        ] {
            let files: Vec<PathBuf> = files.iter().map(PathBuf::from).collect();
            let e = merge_files(&files, &poses, &settings)
                .unwrap_err()
                .to_string();
            assert_eq!(
                e,
                format!(
                    "scans {} and {} share the file name scan.ply, which names their row in cell/poses.csv: give each scan once, under a name of its own",
                    files[0].display(),
                    files[1].display()
                )
            );
        }
    }

    #[test]
    fn bad_scans_in_memory_are_refused_naming_the_scan() {
        let settings = PlanSettings::default();
        let pose = ScanPose::default();
        let one = PointCloud::new(vec![Point3::new(1.0, 2.0, 3.0)]).expect("a point");
        let empty = PointCloud::new(Vec::new()).expect("an empty cloud");
        assert!(matches!(merge(&[], &settings), Err(ScansError::NoScans)));
        let e = merge(&[(pose, one.clone()), (pose, empty)], &settings)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "scans[1]: no points");
        let bad = ScanPose {
            c_deg: f64::NAN,
            ..pose
        };
        let e = merge(&[(pose, one.clone()), (bad, one)], &settings).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("scans[1] through [calibration] at its pose"),
            "{e}"
        );
    }
}
