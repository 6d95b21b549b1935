//! `trimctl calibrate cell`: the rotary axis lines and the scanner's pose on the head from a
//! sphere fixed on the table, scanned at many machine poses (thesis §3: sensor-to-machine and
//! rotation-centre calibration, here in one problem).
//!
//! Unknowns (17): each axis line's direction (2, small rotations of the nominal one) and point
//! (2, across the nominal direction; along the line it is no unknown), the scanner's rotation R
//! (3) and translation t (3), and the sphere's table position p (3). For pose i with the
//! sphere's centre s_i in the scanner frame:
//!
//! `Rot_A(A_i)·Rot_C(C_i)·p = J_i + R·s_i + t`   (3 residuals, weighted by the fit's σ)
//!
//! Translating t, p and both axis points together changes no residual: the spheres cannot say
//! where the tool point is. The tool mark can: a mark made at the field centre at pose 1 lies
//! at the tool point J_1, and the scanner saw it at m, so `R·m + t = 0` (3 residuals, weighted
//! as a 2 µm RMS measurement). Levenberg–Marquardt ([`crate::least_squares`]) from the nominal
//! cell; the parameters' standard deviations are `σ̂²·(JᵀJ)⁻¹`.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Unit};
use serde::Serialize;
use trim_cell::cell_model::{AxisLine, ScannerPose, TableModel};
use trim_cell::kinematics::KinematicsKind;
use trim_geom::{Point3, UnitVector3, Vector3};

use crate::error::CalibError;
use crate::least_squares;

/// Fewest poses `calibrate cell` takes.
pub const MIN_POSES: usize = 8;
/// The tool mark's measurement σ per coordinate (mm): 2 µm RMS in 3-D.
pub const TOOL_MARK_SIGMA_MM: f64 = 0.002 / 1.732_050_807_568_877_2;
/// A floor on the sphere centres' σ (mm), so a fit that claims nanometres does not dominate.
pub const CENTRE_SIGMA_FLOOR_MM: f64 = 0.0005;
/// Fewest distinct positions an axis needs to be determined.
const MIN_DISTINCT_ANGLES: usize = 3;

/// One observation: a machine pose and the sphere centre the scanner saw there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereObservation {
    /// Linear joint positions X, Y, Z (mm): the tool point in the machine frame.
    pub xyz_mm: [f64; 3],
    /// The tilting axis, A or B (degrees).
    pub tilt_deg: f64,
    /// C (degrees).
    pub c_deg: f64,
    /// The sphere's centre in the scanner frame (mm).
    pub centre_mm: Point3,
    /// Its σ (mm, isotropic).
    pub sigma_mm: f64,
}

/// The solved cell.
#[derive(Debug, Clone, PartialEq)]
pub struct CellCalibration {
    /// The rotary axes' lines.
    pub table: TableModel,
    /// The scanner's pose on the head.
    pub scanner: ScannerPose,
    /// The sphere's centre in the table frame (mm).
    pub sphere_table_mm: Point3,
    /// The report.
    pub report: CellReport,
}

/// Residuals and standard deviations of a solved cell.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellReport {
    /// Per pose: the 3-D residual (µm).
    pub pose_residual_um: Vec<f64>,
    /// RMS over the poses (µm).
    pub rms_um: f64,
    /// The tool mark's residual (µm).
    pub tool_mark_residual_um: f64,
    /// σ of the tilt axis direction (degrees).
    pub tilt_direction_sd_deg: f64,
    /// σ of the tilt axis point across the axis (µm).
    pub tilt_point_sd_um: f64,
    /// σ of the C axis direction (degrees).
    pub c_direction_sd_deg: f64,
    /// σ of the C axis point across the axis (µm).
    pub c_point_sd_um: f64,
    /// σ of the scanner rotation (degrees).
    pub scanner_rotation_sd_deg: f64,
    /// σ of the scanner translation (µm).
    pub scanner_translation_sd_um: f64,
    /// The fit's σ̂ relative to the stated measurement σ (≈ 1 when the model fits).
    pub sigma_ratio: f64,
    /// Iterations ([`least_squares::Solution::iterations`]).
    pub iterations: usize,
}

/// Two unit vectors across `d` (right-handed with it).
fn across(d: &Vector3) -> (Vector3, Vector3) {
    let helper = if d.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = d.cross(&helper).normalize();
    let e2 = d.cross(&e1);
    (e1, e2)
}

/// The parametrisation around a reference cell.
struct Model {
    kind: KinematicsKind,
    tilt0: AxisLine,
    rot0: AxisLine,
    r0: Matrix3<f64>,
}

impl Model {
    fn line(base: &AxisLine, x: &[f64]) -> AxisLine {
        let d0 = base.direction.into_inner();
        let (e1, e2) = across(&d0);
        AxisLine {
            point_mm: base.point_mm + e1 * x[2] + e2 * x[3],
            direction: UnitVector3::new_normalize(d0 + e1 * x[0] + e2 * x[1]),
        }
    }

    fn unpack(&self, x: &DVector<f64>) -> (TableModel, ScannerPose, Point3) {
        let tilt = Self::line(&self.tilt0, &x.as_slice()[0..4]);
        let rotary = Self::line(&self.rot0, &x.as_slice()[4..8]);
        let w = Vector3::new(x[8], x[9], x[10]);
        let r = Rotation3::from_scaled_axis(w).matrix() * self.r0;
        (
            TableModel {
                kind: self.kind,
                tilt,
                rotary,
            },
            ScannerPose {
                rotation: r,
                translation_mm: Vector3::new(x[11], x[12], x[13]),
            },
            Point3::new(x[14], x[15], x[16]),
        )
    }

    fn residuals(
        &self,
        x: &DVector<f64>,
        obs: &[SphereObservation],
        tool_mark: &Point3,
    ) -> DVector<f64> {
        let (table, scanner, p) = self.unpack(x);
        let mut r = DVector::zeros(3 * obs.len() + 3);
        for (i, o) in obs.iter().enumerate() {
            let pred = table.machine_from_table(o.tilt_deg, o.c_deg) * p;
            let seen = Vector3::from(o.xyz_mm)
                + scanner.rotation * o.centre_mm.coords
                + scanner.translation_mm;
            let d = (pred.coords - seen) / o.sigma_mm;
            r.fixed_rows_mut::<3>(3 * i).copy_from(&d);
        }
        let m = (scanner.rotation * tool_mark.coords + scanner.translation_mm) / TOOL_MARK_SIGMA_MM;
        r.fixed_rows_mut::<3>(3 * obs.len()).copy_from(&m);
        r
    }
}

fn distinct(values: impl Iterator<Item = f64>) -> usize {
    let mut v: Vec<i64> = values.map(|a| (a * 1e3).round() as i64).collect();
    v.sort_unstable();
    v.dedup();
    v.len()
}

/// Solves the cell from the sphere observations and the tool mark (scanner frame, seen at the
/// first pose), starting from the `nominal` table and the identity scanner.
pub fn calibrate_cell(
    nominal: &TableModel,
    observations: &[SphereObservation],
    tool_mark_mm: &Point3,
) -> Result<CellCalibration, CalibError> {
    check_poses(nominal.kind, observations)?;
    let model = Model {
        kind: nominal.kind,
        tilt0: nominal.tilt,
        rot0: nominal.rotary,
        r0: Matrix3::identity(),
    };
    let x0 = start(nominal, observations, tool_mark_mm);
    let residuals = |x: &DVector<f64>| model.residuals(x, observations, tool_mark_mm);
    let solution = least_squares::minimize(x0, &residuals);
    let (x, r, cost) = (solution.x, solution.residuals, solution.cost);

    // Observability: the normal matrix at the solution.
    let j = least_squares::jacobian(&x, &residuals);
    let jtj = j.transpose() * &j;
    check_observable(&jtj, nominal.kind)?;
    let dof = (r.len() as f64 - 17.0).max(1.0);
    let sigma2 = cost / dof;
    let cov = jtj
        .try_inverse()
        .ok_or_else(|| CalibError::Degenerate("singular normal equations".into()))?
        * sigma2;
    let (table, scanner, p) = model.unpack(&x);
    let report = cell_report(observations, &r, &cov, sigma2, solution.iterations);
    check_fit(&report)?;
    Ok(CellCalibration {
        table,
        scanner,
        sphere_table_mm: p,
        report,
    })
}

/// The tilt axis's name, upper case ("A" or "B").
fn tilt_name(kind: KinematicsKind) -> String {
    kind.tilt_axis().unwrap_or("a").to_uppercase()
}

/// Refuses poses that cannot determine the cell: a three-axis cell, too few poses, too few
/// distinct tilt or C positions.
fn check_poses(kind: KinematicsKind, observations: &[SphereObservation]) -> Result<(), CalibError> {
    if kind == KinematicsKind::Xyz {
        return Err(CalibError::Invalid {
            key: "kinematics".into(),
            message: "a three-axis (xyz) cell has no rotary axes to calibrate".into(),
        });
    }
    if observations.len() < MIN_POSES {
        return Err(CalibError::TooFew {
            what: "poses".into(),
            needed: MIN_POSES,
            got: observations.len(),
        });
    }
    let tilt_name = tilt_name(kind);
    if distinct(observations.iter().map(|o| o.tilt_deg)) < MIN_DISTINCT_ANGLES {
        return Err(CalibError::Degenerate(format!(
            "the poses hold fewer than {MIN_DISTINCT_ANGLES} distinct {tilt_name} positions: the {tilt_name} line is not determined (scan at several {tilt_name} angles)"
        )));
    }
    if distinct(observations.iter().map(|o| o.c_deg.rem_euclid(360.0))) < MIN_DISTINCT_ANGLES {
        return Err(CalibError::Degenerate(format!(
            "the poses hold fewer than {MIN_DISTINCT_ANGLES} distinct C positions: the C line is not determined (scan at several C angles)"
        )));
    }
    Ok(())
}

/// The start: nominal lines, identity scanner, t from the tool mark, the sphere from the first
/// pose.
fn start(
    nominal: &TableModel,
    observations: &[SphereObservation],
    tool_mark_mm: &Point3,
) -> DVector<f64> {
    let mut x = DVector::zeros(17);
    let t0 = -tool_mark_mm.coords;
    x.fixed_rows_mut::<3>(11).copy_from(&t0);
    let o0 = &observations[0];
    let seen0 = Point3::from(Vector3::from(o0.xyz_mm) + o0.centre_mm.coords + t0);
    let p0 = nominal.machine_from_table(o0.tilt_deg, o0.c_deg).inverse() * seen0;
    x.fixed_rows_mut::<3>(14).copy_from(&p0.coords);
    x
}

/// What each of the 17 unknowns is, for the degeneracy message.
const UNKNOWN_NAMES: [&str; 17] = [
    "tilt direction",
    "tilt direction",
    "tilt point",
    "tilt point",
    "C direction",
    "C direction",
    "C point",
    "C point",
    "scanner rotation",
    "scanner rotation",
    "scanner rotation",
    "scanner translation",
    "scanner translation",
    "scanner translation",
    "sphere position",
    "sphere position",
    "sphere position",
];

/// Refuses a solution the poses do not determine: a near-zero eigenvalue of the normal matrix
/// `jtj`, naming the unknowns its eigenvector moves.
fn check_observable(jtj: &DMatrix<f64>, kind: KinematicsKind) -> Result<(), CalibError> {
    let eig = jtj.clone().symmetric_eigen();
    let max_eig = eig.eigenvalues.amax();
    for (k, &e) in eig.eigenvalues.iter().enumerate() {
        if e < 1e-12 * max_eig {
            let v = eig.eigenvectors.column(k);

            let mut parts: Vec<&str> = (0..17)
                .filter(|&i| v[i].abs() > 0.3)
                .map(|i| UNKNOWN_NAMES[i])
                .collect();
            parts.dedup();
            return Err(CalibError::Degenerate(format!(
                "the poses do not determine: {} (add poses that move those axes further)",
                parts.join(", ").replace("tilt", &tilt_name(kind))
            )));
        }
    }
    Ok(())
}

/// The most the fit's σ̂ may exceed the sphere fits' own σ: a cell whose model fits gives about
/// 1 (the twin's cells 0.7–1.3), a wrong sphere diameter 200.
pub const MAX_SIGMA_RATIO: f64 = 20.0;

/// Refuses a solution that is not finite (a tool mark of 1e300 wrote `NaN` standard deviations
/// with exit 0) or whose poses disagree with the model by more than [`MAX_SIGMA_RATIO`] times
/// the sphere fits' σ (a 100 mm sphere diameter for a 25.4 mm sphere wrote a calibration with
/// an 18 mm RMS, exit 0).
fn check_fit(r: &CellReport) -> Result<(), CalibError> {
    let figures = [
        r.rms_um,
        r.tool_mark_residual_um,
        r.tilt_direction_sd_deg,
        r.tilt_point_sd_um,
        r.c_direction_sd_deg,
        r.c_point_sd_um,
        r.scanner_rotation_sd_deg,
        r.scanner_translation_sd_um,
        r.sigma_ratio,
    ];
    if !figures.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Inconsistent(
            "the solution is not finite: check the tool mark (scanner frame, mm) and the poses \
             file's rows"
                .into(),
        ));
    }
    if r.sigma_ratio > MAX_SIGMA_RATIO {
        let worst = r
            .pose_residual_um
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(i, _)| i);
        return Err(CalibError::Inconsistent(format!(
            "the poses disagree with the cell model by an RMS of {:.1} µm, {:.0} × what the \
             sphere fits allow (at most {MAX_SIGMA_RATIO} ×; the worst is pose {worst}, {:.1} \
             µm): check the sphere's diameter, the poses file's rows and units, and that the \
             sphere did not move on the table",
            r.rms_um, r.sigma_ratio, r.pose_residual_um[worst]
        )));
    }
    Ok(())
}

/// The fit's report: residuals per pose (µm) and the standard deviations from the covariance
/// `cov` (already scaled by `sigma2`).
fn cell_report(
    observations: &[SphereObservation],
    r: &DVector<f64>,
    cov: &DMatrix<f64>,
    sigma2: f64,
    iterations: usize,
) -> CellReport {
    let sd = |a: usize, b: usize| (cov[(a, a)] + cov[(b, b)]).sqrt();
    let pose_residual_um: Vec<f64> = (0..observations.len())
        .map(|i| r.fixed_rows::<3>(3 * i).norm() * observations[i].sigma_mm * 1e3)
        .collect();
    let rms_um = (pose_residual_um.iter().map(|v| v * v).sum::<f64>()
        / pose_residual_um.len() as f64)
        .sqrt();
    CellReport {
        tool_mark_residual_um: r.fixed_rows::<3>(3 * observations.len()).norm()
            * TOOL_MARK_SIGMA_MM
            * 1e3,
        pose_residual_um,
        rms_um,
        tilt_direction_sd_deg: sd(0, 1).to_degrees(),
        tilt_point_sd_um: sd(2, 3) * 1e3,
        c_direction_sd_deg: sd(4, 5).to_degrees(),
        c_point_sd_um: sd(6, 7) * 1e3,
        scanner_rotation_sd_deg: (cov[(8, 8)] + cov[(9, 9)] + cov[(10, 10)])
            .sqrt()
            .to_degrees(),
        scanner_translation_sd_um: (cov[(11, 11)] + cov[(12, 12)] + cov[(13, 13)]).sqrt() * 1e3,
        sigma_ratio: sigma2.sqrt(),
        iterations,
    }
}

/// The angle between two directions (degrees).
#[must_use]
pub fn direction_error_deg(a: &UnitVector3, b: &UnitVector3) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
}

/// How far apart two nearly parallel lines are near `at` (mm): the distance between their
/// points nearest `at`, across the first line.
#[must_use]
pub fn line_offset_mm(a: &AxisLine, b: &AxisLine, at: &Point3) -> f64 {
    let pa = a.foot_of(at);
    let pb = b.foot_of(&pa);
    let d = pb - pa;
    (d - a.direction.into_inner() * d.dot(&a.direction)).norm()
}

/// The rotation angle between two rotations (degrees).
#[must_use]
pub fn rotation_error_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let r = Rotation3::from_matrix_unchecked(a.transpose() * b);
    r.angle().to_degrees()
}

/// A rotation by `angle_deg` about `axis` as a matrix (for tests and artefacts).
#[must_use]
pub fn rotation_about(axis: &Vector3, angle_deg: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Unit::new_normalize(*axis), angle_deg.to_radians()).matrix()
}
