//! Machine poses for the 5+2-axis cell (DESIGN.md "Machine pose").
//!
//! # Convention (LinuxCNC `xyzac-trt-kins` / `xyzbc-trt-kins`, `trtfuncs.c`)
//!
//! Frames: the *machine* frame is fixed to the machine (the galvo head moves in it along X, Y,
//! Z; the beam leaves the head along −Z, so the tool axis from the focus toward the lens is
//! +Z). The *table* frame is fixed to the rotary table and equals the machine frame when all
//! rotary axes are at 0. The *work-piece* frame (the registered path's frame) is the table frame
//! shifted by [`MachineSettings::workpiece_origin_mm`]: `p_table = p_workpiece + origin`, axes
//! parallel (set G54 to zero and command in machine coordinates, or fold G54 into that origin).
//!
//! Rotations, both right-handed (positive = counter-clockwise looking from the positive end of
//! the axis toward the origin), C mounted on the tilting A (or B) cradle:
//! - xyzac-trt: `machine_from_table = Rx(A) · Rz(C)`
//! - xyzbc-trt: `machine_from_table = Ry(B) · Rz(C)`
//! - xyz (fixed head over a three-axis table): identity; the beam is always +Z.
//!
//! so the beam direction in the work-piece frame is `table_from_machine · (0, 0, 1)`:
//! `(sin C·sin A, cos C·sin A, cos A)` for A/C and `(−cos C·sin B, sin C·sin B, cos B)` for
//! B/C. These are exactly LinuxCNC's forward kinematics rotation (`trtfuncs.c`:
//! `x = cos C·X + sin C·cos A·Y + sin C·sin A·Z …`).
//!
//! **Pose mode `tcp`** (the default; LinuxCNC with `M428`, the TCP kinematics active): the
//! commanded X, Y, Z are the world coordinates of LinuxCNC's TCP kinematics, which are the tool
//! tip (the focus) in the *table* frame — they do not change when A/C turn, LinuxCNC moves the
//! joints to keep the focus on that table point. So X, Y, Z = focus point + work-piece origin,
//! A/C (B/C) orient the beam. **Pose mode `joints`** (`M429`, identity kinematics): the pose holds
//! joint positions, computed with LinuxCNC's inverse kinematics including the pivot offsets:
//! `J = R·(w − r − Rz(−C)·o) + r + o`, `R = machine_from_table`, `w` the world (table) point,
//! `r` = (x, y, z)-rot-point, `o` = (0, y-offset, z-offset + tool-offset) for A/C and
//! (x-offset, 0, z-offset + tool-offset) for B/C; the forward map is
//! `w = Rᵀ·(J − r − o) + Rz(−C)·o + r`. The pivot offsets only matter for joint positions (and
//! joint-limit checks and travel time), never for the TCP pose.
//!
//! The galvo head's X/Y are the machine X/Y; seen from the part at a pose, they are
//! `table_from_machine·(1,0,0)` and `table_from_machine·(0,1,0)`: [`head_frame`]. The planner
//! uses that as the zone frame, so galvo coordinates written along it land where they should.

use serde::{Deserialize, Serialize};
use trim_geom::{Point3, UnitVector3, Vector3};

use crate::cell_model::TableModel;
use crate::error::{CellError, require_positive};
use crate::frame::frame_from_axes;
use crate::job::{Frame, Pose};

/// Below this |sin(tilt)| the beam is along the rotary axis and C is free (kept at the
/// previous value).
pub const SINGULAR_SIN: f64 = 1e-9;

/// For the fixed-head machine: the largest angle (radians) between a zone axis and +Z that
/// still counts as vertical.
pub const FIXED_HEAD_TOLERANCE_RAD: f64 = 1e-9;

/// Slack on axis limits (mm or degrees) for rounding.
pub const LIMIT_SLACK: f64 = 1e-9;

/// The machine's kinematics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
pub enum KinematicsKind {
    /// Table rotary-tilting A (about X) carrying C (about Z), LinuxCNC `xyzac-trt-kins`.
    #[serde(rename = "xyzac-trt")]
    XyzacTrt,
    /// Table rotary-tilting B (about Y) carrying C, LinuxCNC `xyzbc-trt-kins`.
    #[serde(rename = "xyzbc-trt")]
    XyzbcTrt,
    /// A fixed head over a three-axis table: the beam is always +Z.
    #[serde(rename = "xyz")]
    Xyz,
}

impl KinematicsKind {
    /// The name used in settings and the Job.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            KinematicsKind::XyzacTrt => "xyzac-trt",
            KinematicsKind::XyzbcTrt => "xyzbc-trt",
            KinematicsKind::Xyz => "xyz",
        }
    }

    /// The name of the tilting axis ("a" or "b"), if any.
    #[must_use]
    pub fn tilt_axis(self) -> Option<&'static str> {
        match self {
            KinematicsKind::XyzacTrt => Some("a"),
            KinematicsKind::XyzbcTrt => Some("b"),
            KinematicsKind::Xyz => None,
        }
    }

    /// The fixed beam direction of a machine without rotary axes.
    #[must_use]
    pub fn fixed_direction(self) -> Option<UnitVector3> {
        match self {
            KinematicsKind::Xyz => Some(UnitVector3::new_unchecked(Vector3::z())),
            _ => None,
        }
    }
}

/// What the pose's axis values mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PoseMode {
    /// World coordinates for TCP kinematics (LinuxCNC `M428`): X/Y/Z = focus in the table frame.
    Tcp,
    /// Joint positions (LinuxCNC identity kinematics, `M429`).
    Joints,
}

/// The machine (job.toml `[machine]`). Defaults: LinuxCNC's sim `xyzac-trt.ini`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MachineSettings {
    /// The kinematics.
    pub kinematics: KinematicsKind,
    /// What the Job's pose values are.
    pub pose_mode: PoseMode,
    /// X travel [min, max] (mm), axis and joint.
    pub x_limits_mm: [f64; 2],
    /// Y travel (mm).
    pub y_limits_mm: [f64; 2],
    /// Z travel (mm).
    pub z_limits_mm: [f64; 2],
    /// A travel (degrees).
    pub a_limits_deg: [f64; 2],
    /// B travel (degrees; the sim's joint 3 limits).
    pub b_limits_deg: [f64; 2],
    /// C travel (degrees).
    pub c_limits_deg: [f64; 2],
    /// LinuxCNC `x/y/z-rot-point` (mm).
    pub rot_point_mm: [f64; 3],
    /// LinuxCNC `x-offset` (B/C only; the sim's xyzbc-trt uses −20) (mm).
    pub x_offset_mm: f64,
    /// LinuxCNC `y-offset` (A/C only) (mm).
    pub y_offset_mm: f64,
    /// LinuxCNC `z-offset` (the sim's xyzac-trt uses 10, xyzbc-trt −15) (mm).
    pub z_offset_mm: f64,
    /// LinuxCNC `tool-offset`: the tool length of the active tool (mm).
    pub tool_offset_mm: f64,
    /// The work-piece frame's origin in the table frame (mm).
    pub workpiece_origin_mm: [f64; 3],
    /// Linear joint speed for the time estimate (mm/s).
    pub linear_speed_mm_per_s: f64,
    /// Rotary joint speed for the time estimate (degrees/s).
    pub rotary_speed_deg_per_s: f64,
    /// Time to settle in position after each move (s).
    pub settle_s: f64,
    /// How the time estimate times a move: "joints" (the slowest joint at the speeds above, no
    /// acceleration) or "coordinated" (LinuxCNC's G0 in the commanded axes: all axes start and
    /// stop together, the path speed and acceleration limited by every axis's, a trapezoidal
    /// profile). `trimctl calibrate timing` fits "coordinated".
    pub move_model: MoveModel,
    /// Linear axis acceleration for the "coordinated" move model (mm/s²).
    pub linear_accel_mm_per_s2: f64,
    /// Rotary axis acceleration for the "coordinated" move model (degrees/s²).
    pub rotary_accel_deg_per_s2: f64,
}

/// How the time estimate times a machine move ([`move_time_s`]).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum MoveModel {
    /// The slowest joint at its speed (joint distances, no acceleration).
    #[default]
    Joints,
    /// A coordinated move in the commanded axes with a trapezoidal speed profile, as LinuxCNC
    /// plans a G0 (emccanon's straight-move velocity and acceleration limits).
    Coordinated,
}

impl Default for MachineSettings {
    fn default() -> Self {
        MachineSettings {
            kinematics: KinematicsKind::XyzacTrt,
            pose_mode: PoseMode::Tcp,
            x_limits_mm: [-200.0, 200.0],
            y_limits_mm: [-100.0, 100.0],
            z_limits_mm: [-120.0, 120.0],
            a_limits_deg: [-100.0, 50.0],
            b_limits_deg: [-100.0, 50.0],
            c_limits_deg: [-36000.0, 36000.0],
            rot_point_mm: [0.0; 3],
            x_offset_mm: -20.0,
            y_offset_mm: 20.0,
            z_offset_mm: 10.0,
            tool_offset_mm: 0.0,
            workpiece_origin_mm: [0.0; 3],
            linear_speed_mm_per_s: 20.0,
            rotary_speed_deg_per_s: 30.0,
            settle_s: 0.1,
            move_model: MoveModel::Joints,
            // The sim config's MAX_ACCELERATION (xyzac-trt.ini: 300 for every axis).
            linear_accel_mm_per_s2: 300.0,
            rotary_accel_deg_per_s2: 300.0,
        }
    }
}

impl MachineSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<(), CellError> {
        let limits: [(&'static str, [f64; 2]); 6] = [
            ("machine.x_limits_mm", self.x_limits_mm),
            ("machine.y_limits_mm", self.y_limits_mm),
            ("machine.z_limits_mm", self.z_limits_mm),
            ("machine.a_limits_deg", self.a_limits_deg),
            ("machine.b_limits_deg", self.b_limits_deg),
            ("machine.c_limits_deg", self.c_limits_deg),
        ];
        for (key, [lo, hi]) in limits {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(CellError::setting(
                    key,
                    format!("[{lo}, {hi}]"),
                    "must be [min, max] with finite min ≤ max",
                ));
            }
        }
        let finite: [(&'static str, f64); 7] = [
            ("machine.x_offset_mm", self.x_offset_mm),
            ("machine.y_offset_mm", self.y_offset_mm),
            ("machine.z_offset_mm", self.z_offset_mm),
            ("machine.tool_offset_mm", self.tool_offset_mm),
            ("machine.rot_point_mm", self.rot_point_mm.iter().sum()),
            (
                "machine.workpiece_origin_mm",
                self.workpiece_origin_mm.iter().sum(),
            ),
            ("machine.settle_s", self.settle_s),
        ];
        for (key, v) in finite {
            if !v.is_finite() {
                return Err(CellError::setting(key, v, "must be finite"));
            }
        }
        if self.settle_s < 0.0 {
            return Err(CellError::setting(
                "machine.settle_s",
                self.settle_s,
                "must be ≥ 0",
            ));
        }
        require_positive("machine.linear_speed_mm_per_s", self.linear_speed_mm_per_s)?;
        require_positive(
            "machine.rotary_speed_deg_per_s",
            self.rotary_speed_deg_per_s,
        )?;
        require_positive(
            "machine.linear_accel_mm_per_s2",
            self.linear_accel_mm_per_s2,
        )?;
        require_positive(
            "machine.rotary_accel_deg_per_s2",
            self.rotary_accel_deg_per_s2,
        )?;
        Ok(())
    }

    fn pivot_offset(&self, c_rad: f64) -> (Vector3, Vector3) {
        let dz = self.z_offset_mm + self.tool_offset_mm;
        let o = match self.kinematics {
            KinematicsKind::XyzacTrt => Vector3::new(0.0, self.y_offset_mm, dz),
            KinematicsKind::XyzbcTrt => Vector3::new(self.x_offset_mm, 0.0, dz),
            KinematicsKind::Xyz => Vector3::zeros(),
        };
        (o, rot_z(-c_rad) * o)
    }
}

/// Axis values of one pose: commanded X/Y/Z (mm) and the rotary axes (degrees). For pose mode
/// `tcp` the linear values are world (table-frame) coordinates, for `joints` joint positions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisPose {
    /// X, Y, Z (mm).
    pub linear_mm: [f64; 3],
    /// A (xyzac-trt) or B (xyzbc-trt) (degrees); 0 for xyz.
    pub tilt_deg: f64,
    /// C (degrees); 0 for xyz.
    pub rotary_deg: f64,
}

impl AxisPose {
    /// The all-zero pose (home).
    pub const HOME: AxisPose = AxisPose {
        linear_mm: [0.0; 3],
        tilt_deg: 0.0,
        rotary_deg: 0.0,
    };

    /// As the Job's pose (axis name → value).
    #[must_use]
    pub fn to_job_pose(&self, kind: KinematicsKind) -> Pose {
        let mut m = std::collections::BTreeMap::new();
        for (name, v) in ["x", "y", "z"].into_iter().zip(self.linear_mm) {
            m.insert(name.to_owned(), v);
        }
        if let Some(tilt) = kind.tilt_axis() {
            m.insert(tilt.to_owned(), self.tilt_deg);
            m.insert("c".to_owned(), self.rotary_deg);
        }
        Pose(m)
    }

    /// From the Job's pose; `None` when an axis of the kinematics is missing.
    #[must_use]
    pub fn from_job_pose(pose: &Pose, kind: KinematicsKind) -> Option<AxisPose> {
        let (tilt_deg, rotary_deg) = match kind.tilt_axis() {
            Some(tilt) => (pose.axis(tilt)?, pose.axis("c")?),
            None => (0.0, 0.0),
        };
        Some(AxisPose {
            linear_mm: [pose.axis("x")?, pose.axis("y")?, pose.axis("z")?],
            tilt_deg,
            rotary_deg,
        })
    }
}

fn rot_x(a: f64) -> nalgebra::Matrix3<f64> {
    *nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), a).matrix()
}
fn rot_y(a: f64) -> nalgebra::Matrix3<f64> {
    *nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), a).matrix()
}
fn rot_z(a: f64) -> nalgebra::Matrix3<f64> {
    *nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), a).matrix()
}

/// `machine_from_table` for the rotary axis values (degrees).
#[must_use]
pub fn machine_from_table(
    kind: KinematicsKind,
    tilt_deg: f64,
    rotary_deg: f64,
) -> nalgebra::Matrix3<f64> {
    let (t, c) = (tilt_deg.to_radians(), rotary_deg.to_radians());
    match kind {
        KinematicsKind::XyzacTrt => rot_x(t) * rot_z(c),
        KinematicsKind::XyzbcTrt => rot_y(t) * rot_z(c),
        KinematicsKind::Xyz => nalgebra::Matrix3::identity(),
    }
}

/// The galvo head's axes seen from the part (work-piece frame) at a pose: the zone frame.
#[must_use]
pub fn head_frame(kind: KinematicsKind, tilt_deg: f64, rotary_deg: f64) -> Frame {
    let table_from_machine = machine_from_table(kind, tilt_deg, rotary_deg).transpose();
    frame_from_axes(
        &(table_from_machine * Vector3::x()),
        &(table_from_machine * Vector3::y()),
        &(table_from_machine * Vector3::z()),
    )
}

/// LinuxCNC's inverse kinematics: joint X/Y/Z for a world (table-frame) tool point.
#[must_use]
pub fn joints_from_world(
    m: &MachineSettings,
    world: &Vector3,
    tilt_deg: f64,
    rotary_deg: f64,
) -> Vector3 {
    let r = Vector3::from(m.rot_point_mm);
    let (o, o_c) = m.pivot_offset(rotary_deg.to_radians());
    machine_from_table(m.kinematics, tilt_deg, rotary_deg) * (world - r - o_c) + r + o
}

/// LinuxCNC's forward kinematics: the world (table-frame) tool point for joint X/Y/Z.
#[must_use]
pub fn world_from_joints(
    m: &MachineSettings,
    joints: &Vector3,
    tilt_deg: f64,
    rotary_deg: f64,
) -> Vector3 {
    let r = Vector3::from(m.rot_point_mm);
    let (o, o_c) = m.pivot_offset(rotary_deg.to_radians());
    machine_from_table(m.kinematics, tilt_deg, rotary_deg).transpose() * (joints - r - o) + o_c + r
}

/// The joint positions of a pose (X, Y, Z joints in mm; the rotary joints equal the axes).
#[must_use]
pub fn joints_of(m: &MachineSettings, pose: &AxisPose) -> Vector3 {
    match m.pose_mode {
        PoseMode::Joints => Vector3::from(pose.linear_mm),
        PoseMode::Tcp => joints_from_world(
            m,
            &Vector3::from(pose.linear_mm),
            pose.tilt_deg,
            pose.rotary_deg,
        ),
    }
}

/// Forward: where a pose puts the focus (tool tip) and which way the beam axis points, both
/// in the work-piece frame. The direction is from the focus toward the lens.
#[must_use]
pub fn forward(m: &MachineSettings, pose: &AxisPose) -> (Point3, UnitVector3) {
    let world = match m.pose_mode {
        PoseMode::Tcp => Vector3::from(pose.linear_mm),
        PoseMode::Joints => world_from_joints(
            m,
            &Vector3::from(pose.linear_mm),
            pose.tilt_deg,
            pose.rotary_deg,
        ),
    };
    let point = Point3::from(world - Vector3::from(m.workpiece_origin_mm));
    let dir =
        machine_from_table(m.kinematics, pose.tilt_deg, pose.rotary_deg).transpose() * Vector3::z();
    (point, UnitVector3::new_normalize(dir))
}

/// Inverse on the nominal lines of `m`: see [`inverse_on`].
#[must_use]
pub fn inverse(
    m: &MachineSettings,
    point: &Point3,
    direction: &UnitVector3,
    c_hint_deg: f64,
) -> Vec<AxisPose> {
    inverse_on(m, &TableModel::nominal(m), point, direction, c_hint_deg)
}

/// Inverse: every pose (one per tilt branch, C in (−180°, 180°]) that puts the focus at
/// `point` with the beam along `direction` (work-piece frame, unit, from the part toward the
/// lens) on the cell whose rotary axes are `table` (calibrated or nominal lines). The joint
/// positions put the table point under the tool point; for pose mode `tcp` they are turned into
/// the world coordinates that LinuxCNC's own (nominal) kinematics maps to those joints, so a
/// calibrated cell is driven right by an uncalibrated controller. Limits are not checked here
/// ([`choose_pose`] does). At the singularity (beam along C) C is `c_hint_deg`. The fixed-head
/// machine has a pose only for +Z.
#[must_use]
pub fn inverse_on(
    m: &MachineSettings,
    table: &TableModel,
    point: &Point3,
    direction: &UnitVector3,
    c_hint_deg: f64,
) -> Vec<AxisPose> {
    let world = point.coords + Vector3::from(m.workpiece_origin_mm);
    table
        .orient(direction, c_hint_deg)
        .into_iter()
        .map(|(tilt_deg, rotary_deg)| {
            let joints =
                (table.machine_from_table(tilt_deg, rotary_deg) * Point3::from(world)).coords;
            let linear = match m.pose_mode {
                PoseMode::Joints => joints,
                PoseMode::Tcp => world_from_joints(m, &joints, tilt_deg, rotary_deg),
            };
            AxisPose {
                linear_mm: [linear.x, linear.y, linear.z],
                tilt_deg,
                rotary_deg,
            }
        })
        .collect()
}

/// Forward on the cell whose rotary axes are `table`: where a pose puts the focus and which
/// way the beam points, in the work-piece frame (the direction from the focus toward the lens).
#[must_use]
pub fn forward_on(
    m: &MachineSettings,
    table: &TableModel,
    pose: &AxisPose,
) -> (Point3, UnitVector3) {
    let joints = joints_of(m, pose);
    let table_from_machine = table
        .machine_from_table(pose.tilt_deg, pose.rotary_deg)
        .inverse();
    let point = table_from_machine * Point3::from(joints) - Vector3::from(m.workpiece_origin_mm);
    let dir = table.rotation(pose.tilt_deg, pose.rotary_deg).transpose() * Vector3::z();
    (point, UnitVector3::new_normalize(dir))
}

/// The galvo head's axes seen from the part (work-piece frame) at a pose of the cell whose
/// rotary axes are `table`: the zone frame.
#[must_use]
pub fn head_frame_on(table: &TableModel, tilt_deg: f64, rotary_deg: f64) -> Frame {
    let table_from_machine = table.rotation(tilt_deg, rotary_deg).transpose();
    frame_from_axes(
        &(table_from_machine * Vector3::x()),
        &(table_from_machine * Vector3::y()),
        &(table_from_machine * Vector3::z()),
    )
}

/// Why a pose is outside the limits, or `None` when it is inside (world and joint limits).
#[must_use]
pub fn limit_violation(m: &MachineSettings, pose: &AxisPose) -> Option<String> {
    let lim = [m.x_limits_mm, m.y_limits_mm, m.z_limits_mm];
    let world = match m.pose_mode {
        PoseMode::Tcp => Vector3::from(pose.linear_mm),
        PoseMode::Joints => world_from_joints(
            m,
            &Vector3::from(pose.linear_mm),
            pose.tilt_deg,
            pose.rotary_deg,
        ),
    };
    for (i, name) in ["X", "Y", "Z"].into_iter().enumerate() {
        if !inside_limit(world[i], lim[i]) {
            return Some(format!("{name} = {:.3} mm outside {:?}", world[i], lim[i]));
        }
    }
    let joints = joints_of(m, pose);
    joint_limit_violation(m, joints.into(), pose.tilt_deg, pose.rotary_deg)
}

/// Why joint positions (X, Y, Z in mm, the tilting axis and C in degrees) are outside the
/// machine's limits, or `None` when they are inside. A scan pose (poses.csv) is in joints.
#[must_use]
pub fn joint_limit_violation(
    m: &MachineSettings,
    joints_mm: [f64; 3],
    tilt_deg: f64,
    c_deg: f64,
) -> Option<String> {
    let lim = [m.x_limits_mm, m.y_limits_mm, m.z_limits_mm];
    for (i, name) in ["X", "Y", "Z"].into_iter().enumerate() {
        if !inside_limit(joints_mm[i], lim[i]) {
            return Some(format!(
                "joint {name} = {:.3} mm outside {:?}",
                joints_mm[i], lim[i]
            ));
        }
    }
    if let Some(tilt) = m.kinematics.tilt_axis() {
        let tl = if tilt == "a" {
            m.a_limits_deg
        } else {
            m.b_limits_deg
        };
        if !inside_limit(tilt_deg, tl) {
            return Some(format!(
                "{} = {tilt_deg:.3}° outside {tl:?}",
                tilt.to_uppercase()
            ));
        }
        if !inside_limit(c_deg, m.c_limits_deg) {
            return Some(format!("C = {c_deg:.3}° outside {:?}", m.c_limits_deg));
        }
    }
    None
}

/// Whether `v` is within `[lo, hi]`, with [`LIMIT_SLACK`] for rounding.
fn inside_limit(v: f64, [lo, hi]: [f64; 2]) -> bool {
    v >= lo - LIMIT_SLACK && v <= hi + LIMIT_SLACK
}

/// Moves C by whole turns to the value nearest `target_deg` within the C limits.
fn unwrap_c(c_deg: f64, target_deg: f64, limits: [f64; 2]) -> f64 {
    let k = ((target_deg - c_deg) / 360.0).round();
    let mut best = c_deg + 360.0 * k;
    if best > limits[1] {
        best -= 360.0 * ((best - limits[1]) / 360.0).ceil();
    }
    if best < limits[0] {
        best += 360.0 * ((limits[0] - best) / 360.0).ceil();
    }
    best
}

/// Rotary travel (degrees) between two poses: |Δtilt| + |ΔC|.
#[must_use]
pub fn rotary_travel_deg(a: &AxisPose, b: &AxisPose) -> f64 {
    (a.tilt_deg - b.tilt_deg).abs() + (a.rotary_deg - b.rotary_deg).abs()
}

/// The candidate within limits with the least rotary travel from `previous` (C unwrapped by
/// whole turns toward it; ties: the smaller |tilt|). `Err` says why none fits.
pub fn choose_pose(
    m: &MachineSettings,
    candidates: &[AxisPose],
    previous: &AxisPose,
) -> Result<AxisPose, String> {
    let mut best: Option<AxisPose> = None;
    let mut reasons = Vec::new();
    for cand in candidates {
        let mut p = *cand;
        if m.kinematics.tilt_axis().is_some() {
            p.rotary_deg = unwrap_c(p.rotary_deg, previous.rotary_deg, m.c_limits_deg);
            if m.pose_mode == PoseMode::Joints {
                // Joint X/Y/Z depend on C only through whole turns: unchanged.
                let world = world_from_joints(
                    m,
                    &Vector3::from(cand.linear_mm),
                    cand.tilt_deg,
                    cand.rotary_deg,
                );
                let j = joints_from_world(m, &world, p.tilt_deg, p.rotary_deg);
                p.linear_mm = [j.x, j.y, j.z];
            }
        }
        if let Some(why) = limit_violation(m, &p) {
            reasons.push(why);
            continue;
        }
        let better = best.is_none_or(|b| {
            let (tb, tp) = (
                rotary_travel_deg(&b, previous),
                rotary_travel_deg(&p, previous),
            );
            tp < tb - 1e-12 || ((tp - tb).abs() <= 1e-12 && p.tilt_deg.abs() < b.tilt_deg.abs())
        });
        if better {
            best = Some(p);
        }
    }
    best.ok_or_else(|| {
        if reasons.is_empty() {
            "the kinematics cannot point the beam that way".to_owned()
        } else {
            reasons.join("; ")
        }
    })
}

/// The time (s) to move between two poses, settling included (0 when nothing moves), by
/// `m.move_model`: [`MoveModel::Joints`] the slowest joint at its speed;
/// [`MoveModel::Coordinated`] [`coordinated_move_s`].
#[must_use]
pub fn move_time_s(m: &MachineSettings, from: &AxisPose, to: &AxisPose) -> f64 {
    let moving = match m.move_model {
        MoveModel::Joints => {
            let (ja, jb) = (joints_of(m, from), joints_of(m, to));
            let linear = (jb - ja).amax() / m.linear_speed_mm_per_s;
            let rotary = (from.tilt_deg - to.tilt_deg)
                .abs()
                .max((from.rotary_deg - to.rotary_deg).abs())
                / m.rotary_speed_deg_per_s;
            linear.max(rotary)
        }
        MoveModel::Coordinated => coordinated_move_s(m, from, to),
    };
    if moving > 0.0 {
        moving + m.settle_s
    } else {
        0.0
    }
}

/// The time (s) of a coordinated straight move in the commanded axes, without settling: as
/// LinuxCNC's emccanon limits a G0, the slowest axis decides both the path speed
/// (`t_v = max_i |Δ_i|/v_i`) and the path acceleration (`t_a = max_i |Δ_i|/a_i`, s²), every
/// axis moving together; a trapezoidal profile over the path then takes `t_v + t_a/t_v`, or
/// `2·√t_a` when the move is too short to reach the speed (`t_v² < t_a`). Axis values as
/// commanded (world X/Y/Z with TCP kinematics, which LinuxCNC plans in).
#[must_use]
pub fn coordinated_move_s(m: &MachineSettings, from: &AxisPose, to: &AxisPose) -> f64 {
    let linear = (0..3).map(|i| (to.linear_mm[i] - from.linear_mm[i]).abs());
    let rotary = [
        (to.tilt_deg - from.tilt_deg).abs(),
        (to.rotary_deg - from.rotary_deg).abs(),
    ];
    let (mut t_v, mut t_a) = (0.0_f64, 0.0_f64);
    for d in linear {
        t_v = t_v.max(d / m.linear_speed_mm_per_s);
        t_a = t_a.max(d / m.linear_accel_mm_per_s2);
    }
    for d in rotary {
        t_v = t_v.max(d / m.rotary_speed_deg_per_s);
        t_a = t_a.max(d / m.rotary_accel_deg_per_s2);
    }
    trapezoid_s(t_v, t_a)
}

/// A trapezoidal (or, short of the speed, triangular) profile's duration from its speed-limited
/// time `t_v` (s) and acceleration term `t_a` (distance over acceleration, s²).
#[must_use]
pub fn trapezoid_s(t_v: f64, t_a: f64) -> f64 {
    if t_v <= 0.0 {
        0.0
    } else if t_v * t_v >= t_a {
        t_v + t_a / t_v
    } else {
        2.0 * t_a.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(kind: KinematicsKind, mode: PoseMode) -> MachineSettings {
        MachineSettings {
            kinematics: kind,
            pose_mode: mode,
            rot_point_mm: [1.5, -2.0, 3.0],
            tool_offset_mm: 4.0,
            workpiece_origin_mm: [5.0, -6.0, 7.0],
            ..MachineSettings::default()
        }
    }

    #[test]
    fn matches_linuxcnc_sim_transcript() {
        // LINUXCNC.md §5: with M428 (TCP, y-offset 20, z-offset 10), `G0 X10 Y20 Z-5 A15 C30`
        // ends with JOINT_POS -1.339746 26.123724 -3.888296 15 30.
        let m = MachineSettings::default();
        let j = joints_from_world(&m, &Vector3::new(10.0, 20.0, -5.0), 15.0, 30.0);
        assert!(
            (j - Vector3::new(-1.339746, 26.123724, -3.888296)).amax() < 1e-6,
            "{j}"
        );
        let w = world_from_joints(&m, &j, 15.0, 30.0);
        assert!((w - Vector3::new(10.0, 20.0, -5.0)).amax() < 1e-12);
    }

    #[test]
    fn forward_of_inverse_is_identity_for_all_kinematics() {
        let point = Point3::new(12.0, -7.5, 30.0);
        for kind in [KinematicsKind::XyzacTrt, KinematicsKind::XyzbcTrt] {
            for mode in [PoseMode::Tcp, PoseMode::Joints] {
                let m = settings(kind, mode);
                for dir in [
                    Vector3::new(0.752, -0.644, 0.136),
                    Vector3::new(-0.3, 0.2, 0.93),
                    Vector3::new(0.0, 0.0, 1.0),
                    Vector3::new(0.1, 0.9, -0.2),
                ] {
                    let d = UnitVector3::new_normalize(dir);
                    let cands = inverse(&m, &point, &d, 17.0);
                    assert!(!cands.is_empty());
                    for pose in &cands {
                        let (p, back) = forward(&m, pose);
                        assert!((p - point).norm() < 1e-9, "{kind:?} {mode:?} {pose:?}");
                        assert!(
                            (back.into_inner() - d.into_inner()).norm() < 1e-12,
                            "{kind:?} {pose:?}"
                        );
                        let f = head_frame(kind, pose.tilt_deg, pose.rotary_deg);
                        assert!(crate::frame::orthonormality_error(&f) < 1e-12);
                        assert!((f.z_axis() - d.into_inner()).norm() < 1e-12);
                    }
                }
            }
        }
        let m = settings(KinematicsKind::Xyz, PoseMode::Tcp);
        let up = UnitVector3::new_normalize(Vector3::z());
        let pose = inverse(&m, &point, &up, 0.0)[0];
        assert!((forward(&m, &pose).0 - point).norm() < 1e-12);
        let tilted = UnitVector3::new_normalize(Vector3::new(0.1, 0.0, 1.0));
        assert!(inverse(&m, &point, &tilted, 0.0).is_empty());
    }

    #[test]
    fn a_positive_tilts_beam_toward_plus_y() {
        // Table tilted by +A about X: the machine +Z seen from the table leans to +Y_table.
        let m = MachineSettings::default();
        let pose = AxisPose {
            linear_mm: [0.0; 3],
            tilt_deg: 30.0,
            rotary_deg: 0.0,
        };
        let (_, d) = forward(&m, &pose);
        assert!((d.into_inner() - Vector3::new(0.0, 0.5, 3f64.sqrt() / 2.0)).norm() < 1e-12);
    }

    #[test]
    fn chooses_in_limits_with_least_travel_and_refuses_otherwise() {
        let m = MachineSettings::default();
        // Steep axis: A = ±82°, only −82° is within −100..50.
        let d = UnitVector3::new_normalize(Vector3::new(0.752, -0.644, 0.136));
        let cands = inverse(&m, &Point3::new(10.0, 5.0, 20.0), &d, 0.0);
        let prev = AxisPose {
            linear_mm: [0.0; 3],
            tilt_deg: 0.0,
            rotary_deg: 720.0,
        };
        let pose = choose_pose(&m, &cands, &prev).unwrap();
        assert!(pose.tilt_deg < 0.0);
        assert!(
            (pose.rotary_deg - 720.0).abs() <= 180.0,
            "C unwrapped toward 720: {}",
            pose.rotary_deg
        );
        // Pointing down (−Z) needs A = ±180°: out of limits.
        let down = UnitVector3::new_normalize(-Vector3::z());
        let cands = inverse(&m, &Point3::origin(), &down, 0.0);
        let e = choose_pose(&m, &cands, &AxisPose::HOME).unwrap_err();
        assert!(e.contains('A'), "{e}");
    }

    #[test]
    fn coordinated_move_is_limited_by_the_slowest_axis_with_a_trapezoid() {
        let m = MachineSettings {
            move_model: MoveModel::Coordinated,
            settle_s: 0.0,
            ..MachineSettings::default()
        };
        // LINUXCNC.md §5's G0 X10 Y20 Z-5 A15 C30 from home: Y and C need 1 s at speed, C's
        // 30° at 300°/s² adds t_a/t_v = 0.1 s.
        let to = AxisPose {
            linear_mm: [10.0, 20.0, -5.0],
            tilt_deg: 15.0,
            rotary_deg: 30.0,
        };
        assert!((move_time_s(&m, &AxisPose::HOME, &to) - 1.1).abs() < 1e-12);
        // A 0.6 mm layer step never reaches 20 mm/s at 300 mm/s²: 2·√(0.6/300).
        let step = AxisPose {
            linear_mm: [0.0, 0.0, 0.6],
            ..AxisPose::HOME
        };
        let t = move_time_s(&m, &AxisPose::HOME, &step);
        assert!((t - 2.0 * (0.6_f64 / 300.0).sqrt()).abs() < 1e-12, "{t}");
        // Continuous where the profile turns from triangle to trapezoid (t_v² = t_a).
        assert!((trapezoid_s(0.1, 0.01 - 1e-12) - trapezoid_s(0.1, 0.01 + 1e-12)).abs() < 1e-9);
        // Settling is added to a move, not to standing still.
        let settled = MachineSettings {
            settle_s: 0.25,
            ..m
        };
        assert!((move_time_s(&settled, &AxisPose::HOME, &to) - 1.35).abs() < 1e-12);
        assert_eq!(move_time_s(&settled, &to, &to), 0.0);
    }
}
