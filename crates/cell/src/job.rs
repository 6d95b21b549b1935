//! The Job: the planner's output and the executor's input (DESIGN.md "Data contracts").
//!
//! Serialised as JSON with serde. The keys listed in DESIGN.md are stable for tools and tests
//! outside the code; new keys may be added, existing ones keep their meaning. Units: lengths in
//! millimetres, angles in degrees (this is an edge of the program), times in seconds, delays in
//! microseconds, speeds in millimetres per second.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use trim_geom::{ContourId, Point3, Vector3};

use crate::plan_settings::PlanSettings;

/// The Job format version this code writes and reads.
pub const JOB_VERSION: u32 = 1;

/// A planned job: zones, each with its frame and layers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// The format version, [`JOB_VERSION`].
    pub version: u32,
    /// ΔH, the distance between layers along the zone axis (mm).
    pub layer_step_mm: f64,
    /// The focus processing length: the largest |z| from the focal plane that keeps the fluence
    /// within tolerance (mm).
    pub focus_half_length_mm: f64,
    /// Zones in execution order.
    pub zones: Vec<Zone>,
    /// The settings the plan was made with.
    pub settings: JobSettings,
    /// What validation found.
    pub validation: ValidationReport,
    /// The time estimate.
    pub estimate: TimeEstimate,
    /// Kerf compensation (`[trim]`): how far the lines stand out of the material and which
    /// contours were, and were not, offset. Absent when it is off (and in jobs planned before
    /// it existed: their lines lie on the edges).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kerf: Option<KerfRecord>,
}

/// What kerf compensation did to a job's lines (DESIGN.md "Planning"): every galvo point of a
/// compensated contour is its registered point moved `offset_mm` out of the material, in the
/// face the contour edges (a mitred offset of the contour: its segments stand `offset_mm` off
/// the registered ones).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KerfRecord {
    /// Half the kerf plus `trim.kerf_clearance_um`, mm.
    pub offset_mm: f64,
    /// The contours offset out of the material.
    pub compensated: Vec<ContourId>,
    /// The contours left on the edge, each with why its material side could not be told.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub uncompensated: Vec<UncompensatedContour>,
}

/// A contour kerf compensation left on its edge.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct UncompensatedContour {
    /// The contour id.
    pub contour: ContourId,
    /// Why its material side was not determined.
    pub reason: String,
}

/// One zone: contours processed from one machine orientation, in layers along its axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Zone {
    /// The zone id (0-based, unique in the job).
    pub id: usize,
    /// The zone frame's origin in the work-piece frame (mm): the zone centre.
    pub origin: [f64; 3],
    /// The zone frame's axes in the work-piece frame (right-handed, unit).
    pub frame: Frame,
    /// The ids of the input contours in this zone (a split contour's parts keep its id).
    pub contours: Vec<ContourId>,
    /// The largest angle between a contour feature vector and the zone axis (degrees).
    pub max_incidence_deg: f64,
    /// The largest angle between two contour feature vectors of the zone (degrees).
    pub max_pairwise_deg: f64,
    /// Layers, top down (index 0 first).
    pub layers: Vec<Layer>,
    /// Why no machine pose within the axis limits reaches this zone, when none does. Its layers
    /// then carry the nearest pose outside the limits (for inspection only) and the job fails
    /// validation; `trimctl run` refuses it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreachable: Option<String>,
}

/// A right-handed orthonormal frame: the axes of the zone frame in work-piece coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// The X axis (unit).
    pub x: [f64; 3],
    /// The Y axis (unit).
    pub y: [f64; 3],
    /// The Z axis (unit): the zone axis, the laser direction from the part toward the lens.
    pub z: [f64; 3],
}

impl Frame {
    /// The X axis as a vector.
    #[must_use]
    pub fn x_axis(&self) -> Vector3 {
        Vector3::from(self.x)
    }
    /// The Y axis as a vector.
    #[must_use]
    pub fn y_axis(&self) -> Vector3 {
        Vector3::from(self.y)
    }
    /// The Z axis as a vector.
    #[must_use]
    pub fn z_axis(&self) -> Vector3 {
        Vector3::from(self.z)
    }
}

/// One layer: a machine pose, a focus point, and the 2D galvo polylines marked from there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Layer {
    /// The layer index within its zone (0 = top, the first marked).
    pub index: usize,
    /// The focus point P_m in the work-piece frame (mm), paper Eq. 14.
    pub focus_point: [f64; 3],
    /// The machine axis positions that put the focus on `focus_point` with the beam along the
    /// zone axis.
    pub pose: Pose,
    /// The polylines of this layer in galvo millimetres.
    pub polylines: Vec<Polyline>,
}

/// Machine axis positions by axis name (lower case: "x", "y", "z", "a", "b", "c"). Linear axes
/// in millimetres, rotary axes in degrees, as the CNC takes them.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Pose(pub BTreeMap<String, f64>);

impl Pose {
    /// The value of one axis, if the pose has it.
    #[must_use]
    pub fn axis(&self, name: &str) -> Option<f64> {
        self.0.get(name).copied()
    }
}

/// One polyline in galvo millimetres: `x = (P − focus_point)·frame.x`,
/// `y = (P − focus_point)·frame.y` for a registered point P.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Polyline {
    /// The id of the input contour this polyline is (part of).
    pub contour: ContourId,
    /// At least two points, galvo millimetres: the geometry, in the zone frame's x/y (the
    /// galvo's own axes).
    pub points: Vec<[f64; 2]>,
    /// What the galvo is sent for each point (same axes, mm, before the bits conversion): the
    /// point after the lens height term and the field correction. Empty in a job planned
    /// without them (the executor then sends `points`).
    #[serde(default)]
    pub commands: Vec<[f64; 2]>,
    /// Each point's height above the layer's focal plane, toward the lens (mm): the `h` of the
    /// height term.
    #[serde(default)]
    pub heights_mm: Vec<f64>,
    /// How many times the galvo marks it (each pass ablates [`crate::ProcessSettings`]'s depth
    /// per pass): 1 unless a measured burr needs more (absent from the JSON when 1).
    #[serde(default = "one_pass", skip_serializing_if = "is_one_pass")]
    pub passes: u32,
}

fn one_pass() -> u32 {
    1
}

#[expect(
    clippy::trivially_copy_pass_by_ref,
    reason = "serde's skip_serializing_if passes a reference"
)]
fn is_one_pass(passes: &u32) -> bool {
    *passes == 1
}

impl Polyline {
    /// A polyline of geometric points only (commands = points, heights 0): for hand-made jobs
    /// and tests.
    #[must_use]
    pub fn from_points(contour: ContourId, points: Vec<[f64; 2]>) -> Polyline {
        Polyline {
            contour,
            heights_mm: vec![0.0; points.len()],
            commands: points.clone(),
            points,
            passes: 1,
        }
    }

    /// The galvo commands of every pass, in marking order: [`Polyline::galvo_commands`]
    /// `passes` times (each pass jumps to the start and marks along).
    pub fn passes_commands(&self) -> impl Iterator<Item = &[[f64; 2]]> {
        std::iter::repeat_n(self.galvo_commands(), self.passes as usize)
    }

    /// What the galvo is sent: `commands`, or `points` for a job planned without them.
    #[must_use]
    pub fn galvo_commands(&self) -> &[[f64; 2]] {
        if self.commands.is_empty() {
            &self.points
        } else {
            &self.commands
        }
    }

    /// The polyline length (mm).
    #[must_use]
    pub fn length_mm(&self) -> f64 {
        path_length_mm(&self.points)
    }
}

/// The length (mm) of a 2-D polyline.
#[must_use]
pub fn path_length_mm(points: &[[f64; 2]]) -> f64 {
    points
        .windows(2)
        .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
        .sum()
}

/// The lens model a job's commands were computed with (`settings.lens`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LensRecord {
    /// A telecentric lens (no height term).
    pub telecentric: bool,
    /// L, the scan pivot's height above the focal plane (mm); `None` for a telecentric lens.
    pub pivot_to_focal_plane_mm: Option<f64>,
    /// The field correction file, if one was applied.
    pub field_correction: Option<FieldCorrectionRecord>,
}

/// A field correction file a job used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldCorrectionRecord {
    /// The file as named in the settings.
    pub file: String,
    /// The checksum of its bytes.
    pub checksum: String,
}

/// Galvo motion and laser timing, used for the time estimate and sent to the galvo as list
/// commands.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GalvoSettings {
    /// The usable field, width and height (mm), centred on the optical axis.
    pub field_mm: [f64; 2],
    /// Calibration: galvo bits per millimetre in the field.
    pub bits_per_mm: f64,
    /// Marking speed (mm/s).
    pub mark_speed_mm_per_s: f64,
    /// Jump speed (mm/s).
    pub jump_speed_mm_per_s: f64,
    /// Delay after the laser is switched on before the mirrors move (µs).
    pub laser_on_delay_us: f64,
    /// Delay after a mark before the laser is switched off (µs).
    pub laser_off_delay_us: f64,
    /// Settling delay after a jump (µs).
    pub jump_delay_us: f64,
    /// Settling delay after a mark (µs).
    pub mark_delay_us: f64,
    /// Delay at each polyline vertex (µs).
    pub polygon_delay_us: f64,
}

impl Default for GalvoSettings {
    fn default() -> Self {
        GalvoSettings {
            field_mm: [100.0, 100.0],
            bits_per_mm: 10_000.0,
            mark_speed_mm_per_s: 500.0,
            jump_speed_mm_per_s: 3_000.0,
            laser_on_delay_us: 100.0,
            laser_off_delay_us: 100.0,
            jump_delay_us: 200.0,
            mark_delay_us: 100.0,
            polygon_delay_us: 20.0,
        }
    }
}

impl GalvoSettings {
    /// Refuses out-of-range values, naming the key (`galvo.field_mm`). The time model of these
    /// speeds and delays is [`crate::galvo_timing::ListComposition`].
    pub fn validate(&self) -> Result<(), crate::CellError> {
        use crate::error::require_positive;
        require_positive("galvo.field_mm", self.field_mm[0])?;
        require_positive("galvo.field_mm", self.field_mm[1])?;
        require_positive("galvo.bits_per_mm", self.bits_per_mm)?;
        require_positive("galvo.mark_speed_mm_per_s", self.mark_speed_mm_per_s)?;
        require_positive("galvo.jump_speed_mm_per_s", self.jump_speed_mm_per_s)?;
        let delays: [(&'static str, f64); 5] = [
            ("galvo.laser_on_delay_us", self.laser_on_delay_us),
            ("galvo.laser_off_delay_us", self.laser_off_delay_us),
            ("galvo.jump_delay_us", self.jump_delay_us),
            ("galvo.mark_delay_us", self.mark_delay_us),
            ("galvo.polygon_delay_us", self.polygon_delay_us),
        ];
        for (key, v) in delays {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::CellError::setting(
                    key,
                    v,
                    "must be a finite number ≥ 0",
                ));
            }
        }
        Ok(())
    }
}

/// The settings a job was planned with (whatever the planner needs to reproduce it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobSettings {
    /// The planning settings, one key per job.toml table (`max_incidence_deg`, `beam`,
    /// `zoning`, `layers`, `field`, `machine` with its `kinematics`, `galvo`, `timing`,
    /// `calibration`).
    #[serde(flatten)]
    pub plan: PlanSettings,
    /// The lens model the commands were computed with.
    #[serde(default)]
    pub lens: LensRecord,
}

/// What validation checked and found.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ValidationReport {
    /// Whether every check passed.
    pub passed: bool,
    /// The largest distance of a planned point from its layer's focal plane (mm).
    pub max_focus_deviation_mm: f64,
    /// The largest incidence, lens ray angle included (degrees).
    pub max_incidence_deg: f64,
    /// The largest |x| or |y| of a galvo point (mm).
    pub max_field_abs_mm: f64,
    /// The largest error of mapping a galvo point back to its registered 3D point (mm).
    pub max_round_trip_error_mm: f64,
    /// The largest distance between a point and where its galvo command lands through the
    /// lens model (height term and field correction) (mm).
    #[serde(default)]
    pub max_command_error_mm: f64,
    /// The zones no machine pose within the axis limits reaches (ids).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unreachable_zones: Vec<usize>,
    /// The contours a stretch of which two polylines (or one, running back) would mark twice
    /// (ids): double ablation gouges the part, so no override starts such a job.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub double_marked_contours: Vec<ContourId>,
    /// One line per violation, naming zone, layer and contour.
    pub violations: Vec<String>,
}

/// The time estimate (seconds).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TimeEstimate {
    /// The whole job.
    pub total_s: f64,
    /// Galvo marking, delays included.
    pub marking_s: f64,
    /// Galvo jumps, delays included.
    pub jumping_s: f64,
    /// Machine moves between layers and zones, settling included.
    pub motion_s: f64,
    /// Per zone, in job order.
    pub per_zone_s: Vec<f64>,
    /// Of `motion_s`: settling after each move (`machine.settle_s` per move).
    #[serde(default)]
    pub settle_s: f64,
    /// What `[timing]` adds beyond moves and the commanded list model: per-layer and per-list
    /// overheads, the delays' excess (0 without `[timing]`).
    #[serde(default)]
    pub overhead_s: f64,
    /// The fraction of `total_s` the laser marks (`marking_s / total_s`; 0 for an empty job).
    #[serde(default)]
    pub laser_on_fraction: f64,
}

/// Identifies one layer of a job: zone id and layer index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct LayerKey {
    /// The zone id.
    pub zone: usize,
    /// The layer index in the zone.
    pub layer: usize,
}

impl std::fmt::Display for LayerKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "zone {} layer {}", self.zone, self.layer)
    }
}

impl Job {
    /// Every layer in execution order, with its zone.
    pub fn layers(&self) -> impl Iterator<Item = (LayerKey, &Zone, &Layer)> {
        self.zones.iter().flat_map(|z| {
            z.layers.iter().map(move |l| {
                (
                    LayerKey {
                        zone: z.id,
                        layer: l.index,
                    },
                    z,
                    l,
                )
            })
        })
    }

    /// Gives every polyline of a contour the passes `passes_of(contour)` says (1 to
    /// [`crate::process::MAX_PASSES`], clamped) and moves the time estimate by what the extra
    /// passes add: each layer's list model and its per-list terms as the planner computes them.
    pub fn set_passes(&mut self, passes_of: impl Fn(ContourId) -> u32) {
        use crate::galvo_timing::ListComposition;
        let (galvo, timing) = (self.settings.plan.galvo, self.settings.plan.timing);
        let e = &mut self.estimate;
        for (zi, zone) in self.zones.iter_mut().enumerate() {
            for layer in &mut zone.layers {
                let before = ListComposition::of(&layer.polylines);
                for p in &mut layer.polylines {
                    p.passes = passes_of(p.contour).clamp(1, crate::process::MAX_PASSES);
                }
                let after = ListComposition::of(&layer.polylines);
                let marking = after.marking_s(&galvo) - before.marking_s(&galvo);
                let jumping = after.jumping_s(&galvo) - before.jumping_s(&galvo);
                let overhead = timing.extra_s(&after) - timing.extra_s(&before);
                e.marking_s += marking;
                e.jumping_s += jumping;
                e.overhead_s += overhead;
                e.total_s += marking + jumping + overhead;
                if let Some(z) = e.per_zone_s.get_mut(zi) {
                    *z += marking + jumping + overhead;
                }
            }
        }
        if e.total_s > 0.0 {
            e.laser_on_fraction = e.marking_s / e.total_s;
        }
    }

    /// Reads a job from JSON text, checking the version.
    pub fn from_json(text: &str) -> Result<Job, JobFormatError> {
        let value: serde_json::Value = serde_json::from_str(text)?;
        let version = value.get("version").and_then(serde_json::Value::as_u64);
        if version != Some(u64::from(JOB_VERSION)) {
            return Err(JobFormatError::Version {
                found: version,
                expected: JOB_VERSION,
            });
        }
        let job: Job = serde_json::from_value(value)?;
        for (key, _, layer) in job.layers() {
            for (i, p) in layer.polylines.iter().enumerate() {
                if !(1..=crate::process::MAX_PASSES).contains(&p.passes) {
                    return Err(JobFormatError::Passes {
                        key,
                        polyline: i,
                        contour: p.contour,
                        passes: p.passes,
                    });
                }
            }
        }
        Ok(job)
    }

    /// The job as pretty JSON.
    pub fn to_json(&self) -> Result<String, JobFormatError> {
        Ok(serde_json::to_string_pretty(self)?)
    }
}

/// Maps a galvo point of a layer back to the work-piece frame (the inverse of the projection):
/// `P = focus_point + x·frame.x + y·frame.y` (on the focal plane).
#[must_use]
pub fn workpiece_from_galvo(zone: &Zone, layer: &Layer, xy: [f64; 2]) -> Point3 {
    Point3::from(layer.focus_point) + zone.frame.x_axis() * xy[0] + zone.frame.y_axis() * xy[1]
}

/// A job file that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum JobFormatError {
    /// Not valid JSON or not a job.
    #[error("not a valid job: {0}")]
    Json(#[from] serde_json::Error),
    /// The version is missing or not the one this code reads.
    #[error("job version {found:?} is not supported (this trimctl reads version {expected})")]
    Version {
        /// The version found, if any.
        found: Option<u64>,
        /// The version this code reads.
        expected: u32,
    },
    /// A polyline asks for a pass count outside `1..=MAX_PASSES`.
    #[error(
        "{key} polyline {polyline} (contour {contour}): passes = {passes}, must be 1 to {}",
        crate::process::MAX_PASSES
    )]
    Passes {
        /// The layer.
        key: LayerKey,
        /// The polyline's index in the layer.
        polyline: usize,
        /// Its contour.
        contour: ContourId,
        /// The pass count found.
        passes: u32,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_pass_is_left_out_of_the_json_and_more_round_trip() {
        let mut p = Polyline::from_points(4, vec![[0.0, 0.0], [1.0, 0.0]]);
        let once = serde_json::to_value(&p).unwrap();
        assert!(once.get("passes").is_none(), "{once}");
        let back: Polyline = serde_json::from_value(once).unwrap();
        assert_eq!(back.passes, 1);
        p.passes = 3;
        let thrice = serde_json::to_value(&p).unwrap();
        assert_eq!(thrice["passes"], 3);
        assert_eq!(serde_json::from_value::<Polyline>(thrice).unwrap(), p);
        assert_eq!(p.passes_commands().count(), 3);
    }
}
