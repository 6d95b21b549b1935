//! The calibrated cell: the rotary axes' real lines, the scanner on the head and the lens
//! (job.toml `[calibration]`; DESIGN.md "Frames and the calibration chain").
//!
//! # Conventions
//! - **Machine frame**: fixed to the machine base, mm. The laser's tool point (the focus at the
//!   field centre) is at the linear joint positions (X, Y, Z).
//! - **Table**: the C table sits on the A (or B) cradle. A point fixed on the table, at `p` when
//!   A = C = 0, is at `Rot_A(A)·Rot_C(C)·p`, where `Rot_L(θ)` turns by θ about the line L (a point
//!   on it, a unit direction, right-hand rule); the C line is given at A = 0.
//! - **Scanner**: fixed to the head. A point `s` in the scanner frame is at `(X, Y, Z) + R·s + t`
//!   in the machine frame.
//!
//! Without `[calibration]` the lines are LinuxCNC's nominal ones from `[machine]`: the C line
//! through `rot_point_mm` along +Z, the A line through `rot_point_mm + (0, y_offset, z_offset +
//! tool_offset)` along +X (B/C: through `rot_point_mm + (x_offset, 0, z_offset + tool_offset)`
//! along +Y). That reproduces LinuxCNC's `trtfuncs.c` joint positions exactly, so an
//! uncalibrated plan is what it was; the scanner defaults to the identity.

use std::path::PathBuf;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};
use trim_geom::{Point3, UnitVector3, Vector3};

use crate::error::CellError;
use crate::kinematics::{KinematicsKind, MachineSettings};

/// Below this |sin| of the angle between the beam direction and the rotary (C) line, C is free
/// and takes the caller's hint.
pub const ORIENT_SINGULAR_SIN: f64 = 1e-9;

/// How far a calibrated axis direction may be from its nominal one (degrees) before the
/// calibration is refused as belonging to another machine.
pub const MAX_AXIS_DEVIATION_DEG: f64 = 5.0;

/// How far a scanner rotation may be from a rotation matrix (largest entry of |RᵀR − I|).
pub const ROTATION_TOLERANCE: f64 = 1e-6;

/// A rotation axis: the line through `point_mm` along the unit `direction` (right-hand rule).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisLine {
    /// A point on the line (machine frame, mm).
    pub point_mm: Point3,
    /// The unit direction.
    pub direction: UnitVector3,
}

impl AxisLine {
    /// The rotation by `angle_rad` about the line's direction (no translation).
    #[must_use]
    pub fn rotation(&self, angle_rad: f64) -> Rotation3<f64> {
        Rotation3::from_axis_angle(&self.direction, angle_rad)
    }

    /// `Rot_L(θ)` as a rigid motion: `x ↦ point + R(θ)·(x − point)`.
    #[must_use]
    pub fn motion(&self, angle_rad: f64) -> Isometry3<f64> {
        let r = self.rotation(angle_rad);
        let q = self.point_mm.coords;
        Isometry3::from_parts(
            Translation3::from(q - r * q),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    /// The distance (mm) from a point to the line.
    #[must_use]
    pub fn distance_mm(&self, p: &Point3) -> f64 {
        let d = p - self.point_mm;
        (d - self.direction.into_inner() * d.dot(&self.direction)).norm()
    }

    /// The foot of the perpendicular from `p` onto the line.
    #[must_use]
    pub fn foot_of(&self, p: &Point3) -> Point3 {
        let d = p - self.point_mm;
        self.point_mm + self.direction.into_inner() * d.dot(&self.direction)
    }
}

/// The rotary table of a cell: where its axis lines really are. For a three-axis cell (`xyz`)
/// the table never turns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableModel {
    /// The kinematics.
    pub kind: KinematicsKind,
    /// The tilting axis (A about ~X, or B about ~Y).
    pub tilt: AxisLine,
    /// The rotary axis C (about ~Z), given at tilt = 0.
    pub rotary: AxisLine,
}

impl TableModel {
    /// The nominal lines of `[machine]` (LinuxCNC's `trtfuncs.c` geometry; see the module docs).
    #[must_use]
    pub fn nominal(m: &MachineSettings) -> TableModel {
        let r = Point3::from(m.rot_point_mm);
        let dz = m.z_offset_mm + m.tool_offset_mm;
        let (offset, dir) = match m.kinematics {
            KinematicsKind::XyzbcTrt => (Vector3::new(m.x_offset_mm, 0.0, dz), Vector3::y_axis()),
            KinematicsKind::XyzacTrt | KinematicsKind::Xyz => {
                (Vector3::new(0.0, m.y_offset_mm, dz), Vector3::x_axis())
            }
        };
        TableModel {
            kind: m.kinematics,
            tilt: AxisLine {
                point_mm: r + offset,
                direction: dir,
            },
            rotary: AxisLine {
                point_mm: r,
                direction: Vector3::z_axis(),
            },
        }
    }

    /// `machine_from_table` at the rotary positions (degrees): `Rot_tilt(T)·Rot_C(C)`.
    #[must_use]
    pub fn machine_from_table(&self, tilt_deg: f64, rotary_deg: f64) -> Isometry3<f64> {
        if self.kind == KinematicsKind::Xyz {
            return Isometry3::identity();
        }
        self.tilt.motion(tilt_deg.to_radians()) * self.rotary.motion(rotary_deg.to_radians())
    }

    /// The rotation part of [`TableModel::machine_from_table`].
    #[must_use]
    pub fn rotation(&self, tilt_deg: f64, rotary_deg: f64) -> Matrix3<f64> {
        if self.kind == KinematicsKind::Xyz {
            return Matrix3::identity();
        }
        *(self.tilt.rotation(tilt_deg.to_radians()) * self.rotary.rotation(rotary_deg.to_radians()))
            .matrix()
    }

    /// Every (tilt, C) pair (degrees; C in (−180°, 180°]) that turns the table direction
    /// `d_table` onto the machine's +Z (the beam axis, from the focus toward the lens): the
    /// Paden–Kahan subproblem 2 for `Rot_tilt(T)·Rot_C(C)·d = +Z`. Two branches in general, one
    /// where they meet, none when the cell cannot point that way. When `d` lies along the C
    /// line, C is `c_hint_deg`.
    #[must_use]
    pub fn orient(&self, d_table: &UnitVector3, c_hint_deg: f64) -> Vec<(f64, f64)> {
        let d = d_table.into_inner();
        let q = Vector3::z();
        if self.kind == KinematicsKind::Xyz {
            return if (d - q).norm() <= crate::kinematics::FIXED_HEAD_TOLERANCE_RAD {
                vec![(0.0, 0.0)]
            } else {
                Vec::new()
            };
        }
        let (w1, w2) = (
            self.tilt.direction.into_inner(),
            self.rotary.direction.into_inner(),
        );
        let c12 = w1.dot(&w2);
        let den = c12 * c12 - 1.0;
        let alpha = (c12 * w2.dot(&d) - w1.dot(&q)) / den;
        let beta = (c12 * w1.dot(&q) - w2.dot(&d)) / den;
        let cross = w1.cross(&w2);
        let gamma2 =
            (1.0 - alpha * alpha - beta * beta - 2.0 * alpha * beta * c12) / cross.norm_squared();
        // Rounding: a beam exactly on the reachable cone's rim gives a tiny negative γ².
        let gamma2 = if gamma2 < 0.0 && gamma2 > -1e-12 {
            0.0
        } else {
            gamma2
        };
        if gamma2 < 0.0 {
            return Vec::new();
        }
        let g = gamma2.sqrt();
        let signs: &[f64] = if g == 0.0 { &[1.0] } else { &[1.0, -1.0] };
        let mut out = Vec::with_capacity(2);
        for &s in signs {
            let z = w1 * alpha + w2 * beta + cross * (s * g);
            let c = subproblem1(&w2, &d, &z).unwrap_or(c_hint_deg.to_radians());
            // Rot_tilt(T)·z = q.
            let t = subproblem1(&w1, &z, &q).unwrap_or(0.0);
            out.push((t.to_degrees(), normalise_deg(c.to_degrees())));
        }
        out
    }
}

/// The angle (radians) that turns `u` onto `v` about the unit axis `w` (Paden–Kahan
/// subproblem 1), or `None` when `u` lies along `w` (any angle does).
fn subproblem1(w: &Vector3, u: &Vector3, v: &Vector3) -> Option<f64> {
    let up = u - w * w.dot(u);
    let vp = v - w * w.dot(v);
    if up.norm() < ORIENT_SINGULAR_SIN || vp.norm() < ORIENT_SINGULAR_SIN {
        return None;
    }
    Some(w.dot(&up.cross(&vp)).atan2(up.dot(&vp)))
}

fn normalise_deg(a: f64) -> f64 {
    let r = a.rem_euclid(360.0);
    if r > 180.0 { r - 360.0 } else { r }
}

/// The lens calibration (job.toml `[calibration.lens]`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LensCalibration {
    /// L: the scan pivot's height above the focal plane, mm. A point h above the focal plane is
    /// reached at (L − h)/L of its focal-plane position. Unset: the field correction's value, else
    /// beam.focal_length_mm. Ignored for a telecentric lens.
    pub pivot_to_focal_plane_mm: Option<f64>,
}

/// job.toml `[calibration]`: the cell as measured by `trimctl calibrate`. Every key is
/// optional; a missing axis line is the nominal one of `[machine]`, a missing scanner pose the
/// identity, a missing field correction none.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Calibration {
    /// A point on the A line at A = C = 0, machine frame, mm (xyzac-trt).
    pub a_axis_point_mm: Option<[f64; 3]>,
    /// The A line's unit direction (right-hand rule); nominal +X.
    pub a_axis_direction: Option<[f64; 3]>,
    /// A point on the B line at B = C = 0, machine frame, mm (xyzbc-trt).
    pub b_axis_point_mm: Option<[f64; 3]>,
    /// The B line's unit direction; nominal +Y.
    pub b_axis_direction: Option<[f64; 3]>,
    /// A point on the C line, given at A (B) = 0, machine frame, mm.
    pub c_axis_point_mm: Option<[f64; 3]>,
    /// The C line's unit direction; nominal +Z.
    pub c_axis_direction: Option<[f64; 3]>,
    /// R of the scanner on the head (3×3, rows): a scanner point s is at (X, Y, Z) + R·s + t.
    pub scanner_rotation: Option<[[f64; 3]; 3]>,
    /// t of the scanner on the head, mm.
    pub scanner_translation_mm: Option<[f64; 3]>,
    /// The galvo field correction from `trimctl calibrate field` (field.json), relative to this
    /// file.
    pub field_correction: Option<PathBuf>,
    /// The lens.
    pub lens: LensCalibration,
}

impl Calibration {
    /// Whether nothing is calibrated (every key missing).
    #[must_use]
    pub fn is_nominal(&self) -> bool {
        *self == Calibration::default()
    }

    /// Refuses unusable values, naming the key: non-finite numbers, zero directions, directions
    /// more than [`MAX_AXIS_DEVIATION_DEG`] from nominal, lines of the wrong axis for the
    /// kinematics, a scanner rotation that is not a rotation, L ≤ 0.
    pub fn validate(&self, kind: KinematicsKind) -> Result<(), CellError> {
        let lines: [(&'static str, Option<[f64; 3]>, Vector3, bool); 6] = [
            (
                "calibration.a_axis_direction",
                self.a_axis_direction,
                Vector3::x(),
                true,
            ),
            (
                "calibration.b_axis_direction",
                self.b_axis_direction,
                Vector3::y(),
                true,
            ),
            (
                "calibration.c_axis_direction",
                self.c_axis_direction,
                Vector3::z(),
                true,
            ),
            (
                "calibration.a_axis_point_mm",
                self.a_axis_point_mm,
                Vector3::zeros(),
                false,
            ),
            (
                "calibration.b_axis_point_mm",
                self.b_axis_point_mm,
                Vector3::zeros(),
                false,
            ),
            (
                "calibration.c_axis_point_mm",
                self.c_axis_point_mm,
                Vector3::zeros(),
                false,
            ),
        ];
        for (key, value, nominal, is_direction) in lines {
            let Some(v) = value else { continue };
            let v = Vector3::from(v);
            if !v.iter().all(|x| x.is_finite()) {
                return Err(CellError::setting(key, format!("{v:?}"), "must be finite"));
            }
            if is_direction {
                if v.norm() < 1e-9 {
                    return Err(CellError::setting(
                        key,
                        format!("{:?}", v.as_slice()),
                        "must not be zero",
                    ));
                }
                let angle = v
                    .normalize()
                    .dot(&nominal)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees();
                if angle > MAX_AXIS_DEVIATION_DEG {
                    return Err(CellError::setting(
                        key,
                        format!("{:?}", v.as_slice()),
                        format!(
                            "is {angle:.2}° from its nominal direction {:?}; more than {MAX_AXIS_DEVIATION_DEG}° is another machine",
                            nominal.as_slice()
                        ),
                    ));
                }
            }
        }
        let (wrong, right) = match kind {
            KinematicsKind::XyzacTrt => ("b", "a"),
            KinematicsKind::XyzbcTrt => ("a", "b"),
            KinematicsKind::Xyz => ("", ""),
        };
        if kind == KinematicsKind::Xyz {
            if self.a_axis_point_mm.is_some()
                || self.b_axis_point_mm.is_some()
                || self.c_axis_point_mm.is_some()
                || self.a_axis_direction.is_some()
                || self.b_axis_direction.is_some()
                || self.c_axis_direction.is_some()
            {
                return Err(CellError::setting(
                    "calibration",
                    "axis lines",
                    "a three-axis (xyz) machine has no rotary axes to calibrate",
                ));
            }
        } else {
            let (p, d) = if wrong == "b" {
                (self.b_axis_point_mm, self.b_axis_direction)
            } else {
                (self.a_axis_point_mm, self.a_axis_direction)
            };
            if p.is_some() || d.is_some() {
                return Err(CellError::setting(
                    if wrong == "b" {
                        "calibration.b_axis_point_mm"
                    } else {
                        "calibration.a_axis_point_mm"
                    },
                    "given",
                    format!(
                        "the machine is {}: calibrate the {right} axis instead",
                        kind.name()
                    ),
                ));
            }
        }
        if let Some(r) = self.scanner_rotation {
            let m = Matrix3::from_row_slice(&r.concat());
            if !m.iter().all(|x| x.is_finite()) {
                return Err(CellError::setting(
                    "calibration.scanner_rotation",
                    format!("{r:?}"),
                    "must be finite",
                ));
            }
            let err = (m.transpose() * m - Matrix3::identity()).amax();
            if err > ROTATION_TOLERANCE || m.determinant() < 0.0 {
                return Err(CellError::setting(
                    "calibration.scanner_rotation",
                    format!("{r:?}"),
                    format!("must be a rotation (orthonormal rows, det +1); |RᵀR − I| = {err:.2e}"),
                ));
            }
        }
        if let Some(t) = self.scanner_translation_mm
            && !t.iter().all(|x| x.is_finite())
        {
            return Err(CellError::setting(
                "calibration.scanner_translation_mm",
                format!("{t:?}"),
                "must be finite",
            ));
        }
        if let Some(l) = self.lens.pivot_to_focal_plane_mm
            && !(l.is_finite() && l > 0.0)
        {
            return Err(CellError::setting(
                "calibration.lens.pivot_to_focal_plane_mm",
                l,
                "must be a finite number > 0",
            ));
        }
        Ok(())
    }

    /// The table model: the calibrated lines where given, the nominal ones of `m` otherwise.
    #[must_use]
    pub fn table(&self, m: &MachineSettings) -> TableModel {
        let mut t = TableModel::nominal(m);
        let (tilt_point, tilt_dir) = match m.kinematics {
            KinematicsKind::XyzbcTrt => (self.b_axis_point_mm, self.b_axis_direction),
            _ => (self.a_axis_point_mm, self.a_axis_direction),
        };
        if let Some(p) = tilt_point {
            t.tilt.point_mm = Point3::from(p);
        }
        if let Some(d) = tilt_dir {
            t.tilt.direction = UnitVector3::new_normalize(Vector3::from(d));
        }
        if let Some(p) = self.c_axis_point_mm {
            t.rotary.point_mm = Point3::from(p);
        }
        if let Some(d) = self.c_axis_direction {
            t.rotary.direction = UnitVector3::new_normalize(Vector3::from(d));
        }
        t
    }

    /// The scanner's pose on the head as (R, t): a scanner point s is at (X, Y, Z) + R·s + t.
    #[must_use]
    pub fn scanner(&self) -> ScannerPose {
        ScannerPose {
            rotation: self
                .scanner_rotation
                .map_or_else(Matrix3::identity, |r| Matrix3::from_row_slice(&r.concat())),
            translation_mm: self
                .scanner_translation_mm
                .map_or_else(Vector3::zeros, Vector3::from),
        }
    }

    /// Writes the table and scanner of a solved cell into the keys (the lines of the
    /// kinematics' axes, R and t).
    pub fn set_cell(&mut self, table: &TableModel, scanner: &ScannerPose) {
        let line = |l: &AxisLine| {
            (
                [l.point_mm.x, l.point_mm.y, l.point_mm.z],
                [l.direction.x, l.direction.y, l.direction.z],
            )
        };
        let (tp, td) = line(&table.tilt);
        let (cp, cd) = line(&table.rotary);
        match table.kind {
            KinematicsKind::XyzbcTrt => {
                self.b_axis_point_mm = Some(tp);
                self.b_axis_direction = Some(td);
            }
            KinematicsKind::XyzacTrt => {
                self.a_axis_point_mm = Some(tp);
                self.a_axis_direction = Some(td);
            }
            KinematicsKind::Xyz => {}
        }
        if table.kind != KinematicsKind::Xyz {
            self.c_axis_point_mm = Some(cp);
            self.c_axis_direction = Some(cd);
        }
        let r = scanner.rotation;
        self.scanner_rotation = Some([
            [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
            [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
            [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
        ]);
        let t = scanner.translation_mm;
        self.scanner_translation_mm = Some([t.x, t.y, t.z]);
    }
}

/// The scanner's pose on the head: a scanner point `s` is at `(X, Y, Z) + R·s + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannerPose {
    /// R.
    pub rotation: Matrix3<f64>,
    /// t (mm).
    pub translation_mm: Vector3,
}

impl ScannerPose {
    /// The identity pose (the nominal assumption before calibration).
    #[must_use]
    pub fn identity() -> ScannerPose {
        ScannerPose {
            rotation: Matrix3::identity(),
            translation_mm: Vector3::zeros(),
        }
    }
}

/// Where the scanner was when it took a scan: the machine's joint positions (X, Y, Z in mm,
/// the tool point in the machine frame) and rotary axes (degrees). job.toml `[part.scan_pose]`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ScanPose {
    /// X, Y, Z joint positions, mm.
    pub xyz_mm: [f64; 3],
    /// The tilting axis (A, or B on a B/C cell), degrees.
    pub tilt_deg: f64,
    /// C, degrees.
    pub c_deg: f64,
}

impl ScanPose {
    /// Refuses a NaN or infinite position or angle, naming its job.toml key
    /// (`part.scan_pose.xyz_mm`): a non-finite pose would carry every scan point to NaN.
    pub fn validate(&self) -> Result<(), CellError> {
        for (key, v) in [
            ("part.scan_pose.xyz_mm", self.xyz_mm.to_vec()),
            ("part.scan_pose.tilt_deg", vec![self.tilt_deg]),
            ("part.scan_pose.c_deg", vec![self.c_deg]),
        ] {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(CellError::setting(key, format!("{v:?}"), "must be finite"));
            }
        }
        Ok(())
    }

    /// Why this pose is outside `machine`'s joint limits (`joint X = 250.000 mm outside
    /// [-200.0, 200.0]`), or `None` when the machine can stand there.
    #[must_use]
    pub fn limit_violation(&self, machine: &MachineSettings) -> Option<String> {
        crate::kinematics::joint_limit_violation(machine, self.xyz_mm, self.tilt_deg, self.c_deg)
    }
}

/// The whole chain from the scanner to the work-piece frame at one scan pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanChain {
    /// The table.
    pub table: TableModel,
    /// The scanner on the head.
    pub scanner: ScannerPose,
    /// The pose the scan was taken at.
    pub pose: ScanPose,
    /// The work-piece origin in the table frame (mm), `[machine] workpiece_origin_mm`.
    pub workpiece_origin_mm: Vector3,
}

impl ScanChain {
    /// `workpiece_from_scanner`: table point = `(Rot_T·Rot_C)⁻¹ · ((X, Y, Z) + R·s + t)`, minus
    /// the work-piece origin.
    #[must_use]
    pub fn workpiece_from_scanner(&self) -> Isometry3<f64> {
        let machine_from_scanner = Isometry3::from_parts(
            Translation3::from(Vector3::from(self.pose.xyz_mm) + self.scanner.translation_mm),
            UnitQuaternion::from_matrix(&self.scanner.rotation),
        );
        let table_from_machine = self
            .table
            .machine_from_table(self.pose.tilt_deg, self.pose.c_deg)
            .inverse();
        Translation3::from(-self.workpiece_origin_mm) * table_from_machine * machine_from_scanner
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{joints_from_world, machine_from_table};

    fn tilted_table(kind: KinematicsKind) -> TableModel {
        let m = MachineSettings {
            kinematics: kind,
            ..MachineSettings::default()
        };
        let mut t = TableModel::nominal(&m);
        t.tilt.direction = UnitVector3::new_normalize(
            t.tilt.direction.into_inner() + Vector3::new(0.0, 3e-4, -2e-4),
        );
        t.rotary.direction = UnitVector3::new_normalize(Vector3::new(4e-4, -1e-4, 1.0));
        t.tilt.point_mm += Vector3::new(0.05, -0.08, 0.03);
        t.rotary.point_mm += Vector3::new(-0.04, 0.06, 0.0);
        t
    }

    #[test]
    fn nominal_lines_reproduce_linuxcnc_joints() {
        for kind in [KinematicsKind::XyzacTrt, KinematicsKind::XyzbcTrt] {
            let m = MachineSettings {
                kinematics: kind,
                rot_point_mm: [1.5, -2.0, 3.0],
                tool_offset_mm: 4.0,
                ..MachineSettings::default()
            };
            let t = TableModel::nominal(&m);
            for (tilt, c) in [(15.0, 30.0), (-40.0, 200.0), (0.0, -75.0)] {
                let w = Vector3::new(10.0, 20.0, -5.0);
                let j = joints_from_world(&m, &w, tilt, c);
                let via_lines = t.machine_from_table(tilt, c) * Point3::from(w);
                assert!((j - via_lines.coords).amax() < 1e-12, "{kind:?} {tilt} {c}");
                let r = t.rotation(tilt, c);
                assert!((r - machine_from_table(kind, tilt, c)).amax() < 1e-15);
            }
        }
    }

    #[test]
    fn orient_points_every_reachable_direction_at_plus_z() {
        for kind in [KinematicsKind::XyzacTrt, KinematicsKind::XyzbcTrt] {
            for table in [
                TableModel::nominal(&MachineSettings {
                    kinematics: kind,
                    ..MachineSettings::default()
                }),
                tilted_table(kind),
            ] {
                for d in [
                    Vector3::new(0.1, -0.2, 0.97),
                    Vector3::new(-0.5, 0.3, 0.8),
                    Vector3::new(0.0, 0.0, 1.0),
                    Vector3::new(0.7, 0.7, 0.1),
                ] {
                    let d = UnitVector3::new_normalize(d);
                    let sols = table.orient(&d, 12.0);
                    assert!(!sols.is_empty(), "{kind:?} {d:?}");
                    for (t, c) in sols {
                        let z = table.rotation(t, c) * d.into_inner();
                        assert!((z - Vector3::z()).norm() < 1e-12, "{kind:?} {t} {c}: {z}");
                    }
                }
            }
        }
    }

    #[test]
    fn orient_matches_the_nominal_closed_form() {
        // Nominal A/C: beam (sin C·sin A, cos C·sin A, cos A).
        let t = TableModel::nominal(&MachineSettings::default());
        let (a, c) = (23.0_f64.to_radians(), 117.0_f64.to_radians());
        let d =
            UnitVector3::new_normalize(Vector3::new(c.sin() * a.sin(), c.cos() * a.sin(), a.cos()));
        let sols = t.orient(&d, 0.0);
        assert!(
            sols.iter()
                .any(|(ta, tc)| (ta - 23.0).abs() < 1e-9 && (tc - 117.0).abs() < 1e-9),
            "{sols:?}"
        );
    }

    #[test]
    fn scan_chain_takes_scanner_points_to_the_table() {
        let table = tilted_table(KinematicsKind::XyzacTrt);
        let scanner = ScannerPose {
            rotation: *Rotation3::from_euler_angles(0.01, -0.02, 0.03).matrix(),
            translation_mm: Vector3::new(1.0, -2.0, 150.0),
        };
        let pose = ScanPose {
            xyz_mm: [3.0, 4.0, 5.0],
            tilt_deg: -10.0,
            c_deg: 30.0,
        };
        let chain = ScanChain {
            table,
            scanner,
            pose,
            workpiece_origin_mm: Vector3::new(0.5, 0.0, -1.0),
        };
        let p_work = Point3::new(12.0, -3.0, 2.0);
        let p_machine =
            table.machine_from_table(-10.0, 30.0) * (p_work + chain.workpiece_origin_mm);
        let s = scanner.rotation.transpose()
            * (p_machine.coords - Vector3::from(pose.xyz_mm) - scanner.translation_mm);
        let back = chain.workpiece_from_scanner() * Point3::from(s);
        assert!((back - p_work).norm() < 1e-12);
    }

    #[test]
    fn validation_names_the_key() {
        let cal = Calibration {
            b_axis_direction: Some([0.0, 1.0, 0.0]),
            ..Calibration::default()
        };
        let e = cal
            .validate(KinematicsKind::XyzacTrt)
            .unwrap_err()
            .to_string();
        assert!(e.contains("calibration.b_axis"), "{e}");
        let cal = Calibration {
            a_axis_direction: Some([1.0, 0.5, 0.0]),
            ..Calibration::default()
        };
        let e = cal
            .validate(KinematicsKind::XyzacTrt)
            .unwrap_err()
            .to_string();
        assert!(e.contains("calibration.a_axis_direction"), "{e}");
        let cal = Calibration {
            scanner_rotation: Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]]),
            ..Calibration::default()
        };
        assert!(
            cal.validate(KinematicsKind::XyzacTrt)
                .unwrap_err()
                .to_string()
                .contains("scanner_rotation")
        );
        assert!(
            Calibration::default()
                .validate(KinematicsKind::XyzacTrt)
                .is_ok()
        );
    }
}
