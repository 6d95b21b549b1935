//! The planner: from a registered path to a validated, ordered [`Job`] (DESIGN.md "The flow",
//! paper §2.3–2.5).
//!
//! Steps: (1) contours → pieces, splitting contours whose feature vectors spread wider than the
//! zoning limit ([`crate::piece`]); (2) k-means zoning with automatic k ([`crate::zoning`]);
//! (3) scan-field sections ([`crate::scan_field`]) — or, with `zoning.method = "cover"` (the
//! default), (1–3) pose selection as covering, each pose one section ([`crate::cover`]);
//! (4) layers by paper Eq. 14 ([`crate::layer`]);
//! (5) zone order (nearest neighbour + 2-opt on machine move time, [`crate::order`]) and machine
//! poses, the tilt branch chosen per zone within the axis limits with the least rotary travel
//! ([`trim_cell::kinematics`]); (6) the zone frame is the galvo head's frame at that pose (its Z is
//! the zone axis; X/Y are where the galvo's x/y point), and the galvo polylines are the points'
//! (x, y) in it relative to the layer's focus point; (7) validation and the time estimate.
//!
//! With kerf compensation (`[trim]`, [`crate::kerf`]) the path planned is the registered path
//! with each contour whose material side is known offset out of the material by half the kerf
//! (plus the clearance); "registered point" below means that offset point, and validation also
//! checks the offset against the registered path.
//!
//! # What the round trip guarantees
//!
//! A galvo point (x, y) of a layer is the projection of its registered point P along the zone
//! axis onto the layer's focal plane: `job::workpiece_from_galvo(zone, layer, (x, y))` is
//! `P − h·Z` with h = (P − F)·Z its height over the focal plane, |h| ≤ ΔH/2 ≤ the focus
//! processing length. Validation recomputes P independently from the input path (each planned
//! point remembers where on its contour it lies: original vertices, or points interpolated on a
//! segment where a layer boundary or a section seam cuts it) and checks
//! `|workpiece_from_galvo(x, y) + h·Z − P| ≤ 1 µm` for every galvo point, with h kept from the
//! planning. Equivalently: in the focal plane, the galvo point is P's projection to 1 µm, and
//! along the beam the point is within ΔH/2 of the focus — which the Job JSON alone (without h)
//! can state but not undo. It also checks that every contour is marked exactly once: the
//! polylines of a contour partition it along its arc length, no stretch marked twice (by two
//! polylines, or by one running back) and none left out ([`crate::partition`], issue 24 point
//! 12); a contour marked twice anywhere is listed in `double_marked_contours`, which no
//! override starts.

use serde::{Deserialize, Serialize};
use trim_geom::{ContourId, Path, Point3, UnitVector3, Vector3};

use crate::error::PlanError;
use crate::layer::{ZoneLayers, layer_pieces, project};
use crate::partition::{At, Span};
use crate::piece::{Piece, angle_rad, pieces_of};
use crate::scan_field::{Lens, Section, sections};
use crate::zoning::{ZoneGroup, Zoning, ZoningMethod, make_group, zone_pieces};
use trim_cell::cell_model::TableModel;
use trim_cell::galvo_timing::ListComposition;
use trim_cell::job::{
    JOB_VERSION, Job, JobSettings, Layer, LensRecord, Polyline, TimeEstimate, ValidationReport,
    Zone, workpiece_from_galvo,
};
use trim_cell::kinematics::{
    AxisPose, MachineSettings, choose_pose, forward_on, head_frame_on, inverse_on, limit_violation,
    move_time_s,
};
use trim_cell::lens::LensModel;
pub use trim_cell::plan_settings::PlanSettings;

/// The round-trip tolerance (mm): 1 µm.
pub const ROUND_TRIP_TOLERANCE_MM: f64 = 1e-3;

/// Slack (mm or radians) on the focus, field and incidence checks for rounding.
pub const CHECK_SLACK: f64 = 1e-9;

/// How close `forward(pose)` must come to the focus point (mm) and zone axis (radians).
pub const POSE_TOLERANCE: f64 = 1e-6;

/// At most this many violation lines are listed; the rest are counted.
pub const MAX_VIOLATION_LINES: usize = 200;

/// The lens the incidence check sees: the settings' telecentricity and focal length.
fn lens_of(settings: &PlanSettings) -> Lens {
    Lens {
        telecentric: settings.field.telecentric,
        focal_length_mm: settings.beam.focal_length_mm,
    }
}

/// One row of the zone table (paper Table 1), per job zone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZoneRow {
    /// The job zone id (execution order).
    pub zone: usize,
    /// The k-means zone it is a section of.
    pub cluster: usize,
    /// Centre (x, y, z) in mm and axis (u, v, w), work-piece frame.
    pub centre: [f64; 6],
    /// The largest angle between two contour feature vectors of the zone (degrees).
    pub max_pairwise_deg: f64,
    /// The largest angle between a feature vector and the zone axis (degrees).
    pub max_incidence_deg: f64,
    /// The same with the lens ray angle (degrees).
    pub max_incidence_with_lens_deg: f64,
    /// Number of layers.
    pub layers: usize,
    /// Input contour ids.
    pub contours: Vec<ContourId>,
}

/// Everything planning produced: the Job plus the zoning summary and zone table.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanOutput {
    /// The job.
    pub job: Job,
    /// The k-means k used.
    pub k: usize,
    /// Whether k was chosen automatically.
    pub automatic_k: bool,
    /// The number of k-means zones after greedy splits (before sectioning).
    pub clusters: usize,
    /// Greedy splits after k-means.
    pub greedy_splits: usize,
    /// Zone merges after k-means.
    pub merges: usize,
    /// How many pieces the contours became.
    pub pieces: usize,
    /// One row per job zone, in job order.
    pub table: Vec<ZoneRow>,
    /// With `zoning.method = "cover"`: the covering's figures (its lower bound on the poses).
    pub cover: Option<crate::cover::CoverReport>,
}

/// Where every planned point came from, for validation: per job zone, per layer, per polyline.
#[derive(Debug, Clone, PartialEq)]
struct Trace {
    source: Vec<f64>,
    features: Vec<Vector3>,
    height_mm: Vec<f64>,
}

/// A section with its layers and zone axis, before ordering.
struct Planned {
    cluster: usize,
    axis: UnitVector3,
    section: Section,
    layers: ZoneLayers,
}

/// Plans a job from a (registered) path. See the module docs.
pub fn plan(path: &Path, settings: &PlanSettings) -> Result<Job, PlanError> {
    Ok(plan_with_report(path, settings)?.job)
}

/// [`plan`], also returning the zoning summary and the zone table. Kerf compensation takes
/// each contour's material side from `path` itself ([`crate::kerf::material_sides`]).
pub fn plan_with_report(path: &Path, settings: &PlanSettings) -> Result<PlanOutput, PlanError> {
    plan_with_sides(path, settings, None)
}

/// [`plan_with_report`] with the material sides given: those of a fuller path when `path` is
/// some of its contours (a retrim plans the failing contours alone, and a lone hole does not
/// say where its material is; the whole registered path does). `None`: from `path`.
///
/// With `trim.kerf_compensation` (the default) every contour whose side is known is offset by
/// [`PlanSettings::kerf_offset_mm`] out of the material ([`crate::kerf::compensate`]) and the
/// offset path is planned; the Job records what moved (`kerf`), and validation checks the
/// round trip against the offset path and the offset against `path`.
pub fn plan_with_sides(
    path: &Path,
    settings: &PlanSettings,
    sides: Option<&crate::kerf::MaterialSides>,
) -> Result<PlanOutput, PlanError> {
    settings.validate()?;
    let Some(offset_mm) = settings.kerf_offset_mm() else {
        return plan_line(path, settings);
    };
    let own;
    let sides = match sides {
        Some(s) => s,
        None => {
            own = crate::kerf::material_sides(path);
            &own
        }
    };
    let (line, record) = crate::kerf::compensate(path, sides, offset_mm)?;
    let mut out = plan_line(&line, settings)?;
    check_kerf(&mut out.job.validation, path, &line, &record);
    out.job.kerf = Some(record);
    Ok(out)
}

/// Kerf validation: every vertex of a compensated contour stands between the offset and
/// [`crate::kerf::MAX_MITER`] offsets from its registered point, in the face (normal to its
/// feature vector); every other contour's vertices are where they were.
fn check_kerf(
    report: &mut ValidationReport,
    path: &Path,
    line: &Path,
    record: &trim_cell::job::KerfRecord,
) {
    let d = record.offset_mm;
    let mut lines = Vec::new();
    for c in path.contours() {
        let Some(moved) = line.get(c.id()) else {
            lines.push(format!("contour {}: not in the offset path", c.id()));
            continue;
        };
        let compensated = record.compensated.contains(&c.id());
        let (lo, hi) = if compensated {
            (d, crate::kerf::MAX_MITER * d)
        } else {
            (0.0, 0.0)
        };
        let bad = c
            .points()
            .iter()
            .zip(moved.points())
            .zip(c.features())
            .position(|((p, q), f)| {
                let delta = q - p;
                let norm = delta.norm();
                norm < lo - CHECK_SLACK
                    || norm > hi + CHECK_SLACK
                    || delta.dot(f).abs() > CHECK_SLACK
            });
        if let Some(i) = bad.or((moved.points().len() != c.points().len()).then_some(0)) {
            lines.push(format!(
                "contour {} point {i}: kerf offset {:.6} mm, expected {} (in the face)",
                c.id(),
                moved
                    .points()
                    .get(i)
                    .map_or(f64::NAN, |q| (q - c.points()[i]).norm()),
                if compensated {
                    format!("{lo:.6}–{hi:.6} mm")
                } else {
                    "none".to_owned()
                }
            ));
        }
    }
    if !lines.is_empty() {
        report.passed = false;
        report.violations.extend(lines);
    }
}

/// Plans `path` as given: the line the beam is to draw (the registered path, or its
/// kerf-compensated offset).
fn plan_line(path: &Path, settings: &PlanSettings) -> Result<PlanOutput, PlanError> {
    Ok(plan_line_traced(path, settings)?.0)
}

/// Per job zone, per layer, per polyline: where its points came from.
type Traces = Vec<Vec<Vec<Trace>>>;

/// [`plan_line`], also returning the traces validation checked the Job by.
fn plan_line_traced(
    path: &Path,
    settings: &PlanSettings,
) -> Result<(PlanOutput, Traces), PlanError> {
    settings.validate()?;
    let limit_rad = settings.max_incidence_deg.to_radians();
    let zoning_limit_rad = settings.field.zoning_limit_rad(limit_rad);
    let focus_half_length_mm = settings.beam.focus_half_length_mm();
    let step_mm = settings.layers.step_for(focus_half_length_mm)?;
    let lens = lens_of(settings);
    let (lens_model, lens_record) = settings.lens_model()?;
    let field_radius_mm = 0.5 * settings.galvo.field_mm[0].min(settings.galvo.field_mm[1]);

    // (1) pieces; (2) zoning.
    let machine = &settings.machine;
    let rotary = settings.table();
    // A fixed k is a number of k-means zones, whatever the method.
    if settings.zoning.method == ZoningMethod::Cover && settings.zoning.k.is_none() {
        // (2–4) covering: poses checked with the real ray; each pose is one section.
        let reachable = |axis: &UnitVector3, centre: &Point3| {
            let cands = inverse_on(machine, &rotary, centre, axis, 0.0);
            choose_pose(machine, &cands, &AxisPose::HOME).is_ok()
        };
        let cover = crate::cover::cover(
            path,
            &crate::cover::CoverProblem {
                limit_rad,
                field_radius_mm: field_radius_mm
                    - crate::cover::FIELD_MARGIN_MM
                    - if settings.field.telecentric {
                        0.0
                    } else {
                        0.5 * step_mm * field_radius_mm / lens_model.pivot_to_focal_plane_mm
                    },
                lens,
                fixed_axis: machine.kinematics.fixed_direction(),
                reachable: &reachable,
            },
        )?;
        let planned = cover
            .zones
            .into_iter()
            .enumerate()
            .map(|(cluster, z)| {
                let layers = layer_pieces(&z.pieces, &z.origin, &z.axis, step_mm)?;
                Ok(Planned {
                    cluster,
                    axis: z.axis,
                    section: Section {
                        pieces: z.pieces,
                        origin: z.origin,
                    },
                    layers,
                })
            })
            .collect::<Result<Vec<_>, PlanError>>()?;
        let zoning = Zoning {
            groups: Vec::new(),
            k: cover.report.poses,
            automatic: true,
            greedy_splits: 0,
            merges: cover.report.merges,
        };
        let counts = (cover.report.poses, cover.report.atoms);
        return finish_plan(
            path,
            settings,
            (lens_model, lens_record),
            planned,
            &zoning,
            counts,
            Some(cover.report),
        );
    }
    let pieces = pieces_of(path, zoning_limit_rad, zoning_limit_rad)?;
    let merge_radius_mm = if settings.field.telecentric {
        field_radius_mm
    } else {
        field_radius_mm.min(
            settings.beam.focal_length_mm * settings.field.lens_ray_budget_deg.to_radians().tan(),
        )
    };
    let zoning = match settings.machine.kinematics.fixed_direction() {
        Some(axis) => fixed_direction_zoning(&pieces, axis),
        None => zone_pieces(&pieces, zoning_limit_rad, &settings.zoning, merge_radius_mm)?,
    };

    // (3) sections; (4) layers.
    let mut planned = Vec::new();
    for (cluster, group) in zoning.groups.iter().enumerate() {
        crate::error::check_cancel()?;
        let members: Vec<Piece> = group.pieces.iter().map(|&i| pieces[i].clone()).collect();
        for section in sections(
            members,
            &group.centre,
            &group.axis,
            field_radius_mm,
            limit_rad,
            &lens,
        ) {
            let layers = layer_pieces(&section.pieces, &section.origin, &group.axis, step_mm)?;
            planned.push(Planned {
                cluster,
                axis: group.axis,
                section,
                layers,
            });
        }
    }

    let clusters = zoning.groups.len();
    let pieces = pieces.len();
    finish_plan(
        path,
        settings,
        (lens_model, lens_record),
        planned,
        &zoning,
        (clusters, pieces),
        None,
    )
}

/// Steps (5)–(7) of [`plan_with_report`] on the planned sections: the zone order, then each
/// zone's poses, frame, layers and table row, the estimate's totals, and validation.
fn finish_plan(
    path: &Path,
    settings: &PlanSettings,
    (lens_model, lens_record): (LensModel, LensRecord),
    planned: Vec<Planned>,
    zoning: &Zoning,
    (clusters, pieces): (usize, usize),
    cover: Option<crate::cover::CoverReport>,
) -> Result<(PlanOutput, Traces), PlanError> {
    let focus_half_length_mm = settings.beam.focus_half_length_mm();
    let step_mm = settings.layers.step_for(focus_half_length_mm)?;
    // (5) order and poses.
    let order = zone_order(&planned, &settings.machine, &settings.table());
    let mut zones = Vec::with_capacity(planned.len());
    let mut traces: Traces = Vec::with_capacity(planned.len());
    let mut table = Vec::with_capacity(planned.len());
    let mut previous = AxisPose::HOME;
    let mut estimate = TimeEstimate::default();
    crate::error::check_cancel()?;
    for (zone_id, &idx) in order.iter().enumerate() {
        crate::error::check_cancel()?;
        let p = &planned[idx];
        let (zone, zone_traces) = plan_zone(
            zone_id,
            p,
            settings,
            &lens_model,
            &mut previous,
            &mut estimate,
        );
        table.push(zone_row(p, &zone, &zone_traces, &lens_of(settings)));
        zones.push(zone);
        traces.push(zone_traces);
    }
    estimate.total_s =
        estimate.marking_s + estimate.jumping_s + estimate.motion_s + estimate.overhead_s;
    if estimate.total_s > 0.0 {
        estimate.laser_on_fraction = estimate.marking_s / estimate.total_s;
    }

    // (7) validation.
    let mut job = Job {
        version: JOB_VERSION,
        layer_step_mm: step_mm,
        focus_half_length_mm,
        zones,
        settings: JobSettings {
            plan: settings.clone(),
            lens: lens_record,
        },
        validation: ValidationReport::default(),
        estimate,
        kerf: None,
    };
    job.validation = validate(&job, &traces, path, settings, &lens_model);
    let out = PlanOutput {
        job,
        k: zoning.k,
        automatic_k: zoning.automatic,
        clusters,
        greedy_splits: zoning.greedy_splits,
        merges: zoning.merges,
        pieces,
        table,
        cover,
    };
    Ok((out, traces))
}

/// One zone in execution order: its poses from the `previous` pose (the nearest outside the
/// limits when none is within them: an unreachable zone is planned all the same, so that the
/// plan and its SVG show it; validation fails and `run` refuses it), its frame (6: the galvo
/// head's at the first pose), its layers and the traces validation checks them by.
fn plan_zone(
    zone_id: usize,
    p: &Planned,
    settings: &PlanSettings,
    lens_model: &LensModel,
    previous: &mut AxisPose,
    estimate: &mut TimeEstimate,
) -> (Zone, Vec<Vec<Trace>>) {
    let (machine, rotary) = (&settings.machine, settings.table());
    let (poses, unreachable) =
        match zone_poses(machine, &rotary, &focus_points(p), &p.axis, previous) {
            Ok(poses) => (poses, None),
            Err(reason) => (
                unlimited_poses(machine, &rotary, &focus_points(p), &p.axis, previous),
                Some(unreachable_reason(p, machine, &reason)),
            ),
        };
    let frame = head_frame_on(&rotary, poses[0].tilt_deg, poses[0].rotary_deg);
    let (layers, zone_traces, zone_s) =
        zone_layers(p, &frame, &poses, settings, lens_model, previous, estimate);
    estimate.per_zone_s.push(zone_s);
    let (max_incidence_rad, max_pairwise_rad) = section_angles(&p.section, &p.axis);
    let zone = Zone {
        id: zone_id,
        origin: [p.section.origin.x, p.section.origin.y, p.section.origin.z],
        frame,
        contours: pieces_contours(&p.section),
        max_incidence_deg: max_incidence_rad.to_degrees(),
        max_pairwise_deg: max_pairwise_rad.to_degrees(),
        layers,
        unreachable,
    };
    (zone, zone_traces)
}

/// The focus points of a planned section's layers (work-piece frame, mm).
fn focus_points(p: &Planned) -> Vec<Point3> {
    p.layers
        .layers
        .iter()
        .map(|(_, h, _)| p.section.origin + p.axis.into_inner() * *h)
        .collect()
}

/// The zone order: nearest neighbour + 2-opt on the machine move time between provisional
/// poses (from home; the nearest outside the limits where none is within them).
fn zone_order(planned: &[Planned], machine: &MachineSettings, rotary: &TableModel) -> Vec<usize> {
    let provisional: Vec<Vec<AxisPose>> = planned
        .iter()
        .map(|p| {
            zone_poses(machine, rotary, &focus_points(p), &p.axis, &AxisPose::HOME).unwrap_or_else(
                |_| unlimited_poses(machine, rotary, &focus_points(p), &p.axis, &AxisPose::HOME),
            )
        })
        .collect();
    crate::order::order(
        planned.len(),
        |j| move_time_s(machine, &AxisPose::HOME, &provisional[j][0]),
        |i, j| {
            let last = provisional[i].last().unwrap_or(&AxisPose::HOME);
            move_time_s(machine, last, &provisional[j][0])
        },
    )
}

/// A zone's layers at their poses: each layer's galvo polylines in the zone `frame` and what
/// validation needs of them; the estimate accumulated layer by layer from the `previous`
/// pose (which it moves on). Returns the layers, their traces and the zone's time (s).
fn zone_layers(
    p: &Planned,
    frame: &trim_cell::job::Frame,
    poses: &[AxisPose],
    settings: &PlanSettings,
    lens_model: &LensModel,
    previous: &mut AxisPose,
    estimate: &mut TimeEstimate,
) -> (Vec<Layer>, Vec<Vec<Trace>>, f64) {
    let machine = &settings.machine;
    let mut zone_s = 0.0;
    let mut layers = Vec::with_capacity(poses.len());
    let mut zone_traces = Vec::with_capacity(poses.len());
    for (index, ((_, h, pieces_in_layer), pose)) in p.layers.layers.iter().zip(poses).enumerate() {
        let focus = p.section.origin + p.axis.into_inner() * *h;
        let (polylines, layer_traces) = layer_polylines(pieces_in_layer, frame, &focus, lens_model);
        let list = ListComposition::of(&polylines);
        let (marking_s, jumping_s) = (
            list.marking_s(&settings.galvo),
            list.jumping_s(&settings.galvo),
        );
        let motion_s = move_time_s(machine, previous, pose);
        estimate.marking_s += marking_s;
        estimate.jumping_s += jumping_s;
        estimate.motion_s += motion_s;
        if motion_s > 0.0 {
            estimate.settle_s += machine.settle_s;
        }
        let overhead_s = settings.timing.extra_s(&list);
        estimate.overhead_s += overhead_s;
        zone_s += marking_s + jumping_s + motion_s + overhead_s;
        *previous = *pose;
        layers.push(Layer {
            index,
            focus_point: [focus.x, focus.y, focus.z],
            pose: pose.to_job_pose(machine.kinematics),
            polylines,
        });
        zone_traces.push(layer_traces);
    }
    (layers, zone_traces, zone_s)
}

/// One layer's pieces as galvo polylines (x, y in `frame` relative to `focus`, mm) with their
/// commands through the lens model, and the trace of each for validation.
fn layer_polylines(
    pieces_in_layer: &[crate::layer::LayerPiece],
    frame: &trim_cell::job::Frame,
    focus: &Point3,
    lens_model: &LensModel,
) -> (Vec<Polyline>, Vec<Trace>) {
    let mut polylines = Vec::with_capacity(pieces_in_layer.len());
    let mut layer_traces = Vec::with_capacity(pieces_in_layer.len());
    for lp in pieces_in_layer {
        let (points, heights): (Vec<[f64; 2]>, Vec<f64>) =
            lp.points.iter().map(|q| project(frame, focus, q)).unzip();
        // What the galvo is sent: the height term and the field correction undone.
        // A point no command reaches keeps its geometric value and fails validation.
        let commands = points
            .iter()
            .zip(&heights)
            .map(|(p, h)| lens_model.command_for(*p, *h).unwrap_or(*p))
            .collect();
        polylines.push(Polyline {
            contour: lp.contour,
            points,
            commands,
            heights_mm: heights.clone(),
            passes: 1,
        });
        layer_traces.push(Trace {
            source: lp.source.clone(),
            features: lp.features.clone(),
            height_mm: heights,
        });
    }
    (polylines, layer_traces)
}

/// The zone table's row of a zone: centre and axis, angles (the largest incidence with the
/// lens ray angle from its points), layers and contours.
fn zone_row(p: &Planned, zone: &Zone, zone_traces: &[Vec<Trace>], lens: &Lens) -> ZoneRow {
    let frame = &zone.frame;
    let with_lens = zone_traces
        .iter()
        .zip(&zone.layers)
        .flat_map(|(lt, layer)| lt.iter().zip(&layer.polylines))
        .flat_map(|(t, pl)| t.features.iter().zip(&pl.points))
        .map(|(f, xy)| {
            angle_rad(
                f,
                &lens.ray(&frame.x_axis(), &frame.y_axis(), &frame.z_axis(), *xy),
            )
        })
        .fold(0.0, f64::max);
    let a = p.axis.into_inner();
    ZoneRow {
        zone: zone.id,
        cluster: p.cluster,
        centre: [
            zone.origin[0],
            zone.origin[1],
            zone.origin[2],
            a.x,
            a.y,
            a.z,
        ],
        max_pairwise_deg: zone.max_pairwise_deg,
        max_incidence_deg: zone.max_incidence_deg,
        max_incidence_with_lens_deg: with_lens.to_degrees(),
        layers: zone.layers.len(),
        contours: zone.contours.clone(),
    }
}

/// A fixed-head machine: one zone with the machine's beam direction as its axis.
fn fixed_direction_zoning(pieces: &[Piece], axis: UnitVector3) -> Zoning {
    let mut g: ZoneGroup = make_group(pieces, (0..pieces.len()).collect(), true);
    g.axis = axis;
    g.max_incidence_rad = pieces
        .iter()
        .flat_map(|p| p.features.iter())
        .map(|f| angle_rad(f, &axis))
        .fold(0.0, f64::max);
    Zoning {
        groups: vec![g],
        k: 1,
        automatic: false,
        greedy_splits: 0,
        merges: 0,
    }
}

fn pieces_contours(section: &Section) -> Vec<ContourId> {
    let mut ids: Vec<ContourId> = section.pieces.iter().map(|p| p.contour).collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// Why a zone has no pose within the limits, for the zone's `unreachable` and the violation.
fn unreachable_reason(p: &Planned, machine: &MachineSettings, reason: &str) -> String {
    format!(
        "no {} pose within the axis limits puts the beam along ({:.4}, {:.4}, {:.4}): {reason}",
        machine.kinematics.name(),
        p.axis.x,
        p.axis.y,
        p.axis.z
    )
}

/// The poses of an unreachable zone's layers, limits ignored: per layer the candidate with the
/// least rotary travel. A direction the kinematics cannot point at all keeps `previous`.
fn unlimited_poses(
    machine: &MachineSettings,
    table: &TableModel,
    focus_points: &[Point3],
    axis: &UnitVector3,
    previous: &AxisPose,
) -> Vec<AxisPose> {
    let mut prev = *previous;
    focus_points
        .iter()
        .map(|f| {
            let pose = inverse_on(machine, table, f, axis, prev.rotary_deg)
                .into_iter()
                .min_by(|a, b| {
                    trim_cell::kinematics::rotary_travel_deg(a, &prev)
                        .total_cmp(&trim_cell::kinematics::rotary_travel_deg(b, &prev))
                })
                .unwrap_or(prev);
            prev = pose;
            pose
        })
        .collect()
}

/// The poses of a zone's layers: one tilt branch for all (so the zone has one frame), the
/// branch within limits for every layer with the least rotary travel from `previous`.
fn zone_poses(
    machine: &MachineSettings,
    table: &TableModel,
    focus_points: &[Point3],
    axis: &UnitVector3,
    previous: &AxisPose,
) -> Result<Vec<AxisPose>, String> {
    let Some(first) = focus_points.first() else {
        return Ok(Vec::new());
    };
    let branches = inverse_on(machine, table, first, axis, previous.rotary_deg);
    if branches.is_empty() {
        return Err("the kinematics cannot point the beam that way".to_owned());
    }
    let mut best: Option<(f64, Vec<AxisPose>)> = None;
    let mut reasons = Vec::new();
    for branch in &branches {
        let mut poses = Vec::with_capacity(focus_points.len());
        let mut prev = *previous;
        let mut failed = None;
        for f in focus_points {
            let cands: Vec<AxisPose> = inverse_on(machine, table, f, axis, prev.rotary_deg)
                .into_iter()
                .filter(|c| (c.tilt_deg - branch.tilt_deg).abs() < 1e-9)
                .collect();
            match choose_pose(machine, &cands, &prev) {
                Ok(pose) => {
                    poses.push(pose);
                    prev = pose;
                }
                Err(why) => {
                    failed = Some(why);
                    break;
                }
            }
        }
        match failed {
            Some(why) => reasons.push(why),
            None => {
                let travel = trim_cell::kinematics::rotary_travel_deg(previous, &poses[0]);
                if best.as_ref().is_none_or(|(t, _)| travel < *t - 1e-12) {
                    best = Some((travel, poses));
                }
            }
        }
    }
    best.map(|b| b.1).ok_or_else(|| reasons.join("; "))
}

/// (largest incidence to the axis, largest pairwise angle between piece features), radians.
fn section_angles(section: &Section, axis: &UnitVector3) -> (f64, f64) {
    let incidence = section
        .pieces
        .iter()
        .flat_map(|p| p.features.iter())
        .map(|f| angle_rad(f, axis))
        .fold(0.0, f64::max);
    let means: Vec<Vector3> = section
        .pieces
        .iter()
        .map(|p| p.feature().into_inner())
        .collect();
    let mut pairwise: f64 = 0.0;
    for (i, a) in means.iter().enumerate() {
        for b in &means[i + 1..] {
            pairwise = pairwise.max(angle_rad(a, b));
        }
    }
    (incidence, pairwise)
}

/// The registered point at `source` (vertex index + fraction) on a contour.
fn point_on_contour(points: &[Point3], source: f64) -> Point3 {
    let last = points.len() - 1;
    let i = (source.floor().max(0.0) as usize).min(last.saturating_sub(1));
    let t = source - i as f64;
    points[i] + (points[(i + 1).min(last)] - points[i]) * t
}

/// Checks the job against the input path and the settings (see the module docs).
fn validate(
    job: &Job,
    traces: &[Vec<Vec<Trace>>],
    path: &Path,
    settings: &PlanSettings,
    lens_model: &LensModel,
) -> ValidationReport {
    let mut checks = Checks {
        settings,
        lens_model,
        lens: lens_of(settings),
        rotary: settings.table(),
        limit_rad: settings.max_incidence_deg.to_radians(),
        half_field: [
            0.5 * settings.galvo.field_mm[0],
            0.5 * settings.galvo.field_mm[1],
        ],
        focus_half_length_mm: job.focus_half_length_mm,
        report: ValidationReport::default(),
        lines: Vec::new(),
        more: 0,
    };
    let mut spans: std::collections::BTreeMap<ContourId, Vec<Span>> = Default::default();
    for (zone, zone_traces) in job.zones.iter().zip(traces) {
        if let Some(why) = &zone.unreachable {
            checks.report.unreachable_zones.push(zone.id);
            checks.violation(format!(
                "zone {} (contours {:?}): unreachable: {why}",
                zone.id, zone.contours
            ));
        }
        for (layer, layer_traces) in zone.layers.iter().zip(zone_traces) {
            let at = format!("zone {} layer {}", zone.id, layer.index);
            checks.pose(zone, layer, &at);
            for (k, (pl, t)) in layer.polylines.iter().zip(layer_traces).enumerate() {
                let Some(contour) = path.get(pl.contour) else {
                    checks.violation(format!("{at}: contour {} is not in the path", pl.contour));
                    continue;
                };
                if pl.points.len() < 2 {
                    checks.violation(format!(
                        "{at} contour {}: polyline has fewer than 2 points",
                        pl.contour
                    ));
                }
                spans.entry(pl.contour).or_default().push(Span {
                    at: At {
                        zone: zone.id,
                        layer: layer.index,
                        polyline: k,
                    },
                    source: t.source.clone(),
                });
                for i in 0..pl.points.len().min(t.height_mm.len()).min(t.features.len()) {
                    checks.point(zone, layer, pl, t, i, contour.points(), &at);
                }
            }
        }
    }
    checks.partition(path, spans);
    checks.finish()
}

/// What validation checks against, and what it found so far.
struct Checks<'a> {
    settings: &'a PlanSettings,
    lens_model: &'a LensModel,
    lens: Lens,
    rotary: TableModel,
    limit_rad: f64,
    half_field: [f64; 2],
    focus_half_length_mm: f64,
    report: ValidationReport,
    lines: Vec<String>,
    more: usize,
}

impl Checks<'_> {
    /// One violation line; past [`MAX_VIOLATION_LINES`], counted only.
    fn violation(&mut self, s: String) {
        if self.lines.len() < MAX_VIOLATION_LINES {
            self.lines.push(s);
        } else {
            self.more += 1;
        }
    }

    /// The layer's pose: every axis given, within the limits (unless the zone is unreachable),
    /// and putting the focus on the focus point along the zone axis.
    fn pose(&mut self, zone: &Zone, layer: &Layer, at: &str) {
        let machine = &self.settings.machine;
        let Some(pose) = AxisPose::from_job_pose(&layer.pose, machine.kinematics) else {
            self.violation(format!("{at}: pose lacks an axis: {:?}", layer.pose));
            return;
        };
        // An unreachable zone's poses are outside the limits by construction.
        if let Some(why) = limit_violation(machine, &pose).filter(|_| zone.unreachable.is_none()) {
            self.violation(format!("{at}: pose outside the axis limits: {why}"));
        }
        let (tip, dir) = forward_on(machine, &self.rotary, &pose);
        let focus = Point3::from(layer.focus_point);
        if (tip - focus).norm() > POSE_TOLERANCE
            || angle_rad(&dir, &zone.frame.z_axis()) > POSE_TOLERANCE
        {
            self.violation(format!(
                "{at}: the pose does not put the focus on the focus point along the zone axis"
            ));
        }
    }

    /// Point `i` of a polyline: within the focus length, the field and the incidence limit; its
    /// command landing on it; its round trip back onto the registered contour.
    #[expect(clippy::too_many_arguments)] // one point in its zone, layer, polyline and contour
    fn point(
        &mut self,
        zone: &Zone,
        layer: &Layer,
        pl: &Polyline,
        t: &Trace,
        i: usize,
        contour: &[Point3],
        at: &str,
    ) {
        let (xy, h, f) = (&pl.points[i], &t.height_mm[i], &t.features[i]);
        let here = || format!("{at} contour {} point {i}", pl.contour);
        let (fx, fy, fz) = (
            zone.frame.x_axis(),
            zone.frame.y_axis(),
            zone.frame.z_axis(),
        );
        let half_field = self.half_field;
        self.report.max_focus_deviation_mm = self.report.max_focus_deviation_mm.max(h.abs());
        if h.abs() > self.focus_half_length_mm + CHECK_SLACK {
            self.violation(format!("{}: {h:.4} mm from the focal plane", here()));
        }
        let field_abs = xy[0].abs().max(xy[1].abs());
        self.report.max_field_abs_mm = self.report.max_field_abs_mm.max(field_abs);
        if xy[0].abs() > half_field[0] + CHECK_SLACK || xy[1].abs() > half_field[1] + CHECK_SLACK {
            self.violation(format!(
                "{}: ({:.3}, {:.3}) mm outside the field",
                here(),
                xy[0],
                xy[1]
            ));
        }
        let incidence = angle_rad(f, &self.lens.ray(&fx, &fy, &fz, *xy));
        self.report.max_incidence_deg = self.report.max_incidence_deg.max(incidence.to_degrees());
        if incidence > self.limit_rad + CHECK_SLACK {
            self.violation(format!(
                "{}: incidence {:.3}° over the limit",
                here(),
                incidence.to_degrees()
            ));
        }
        // The command, sent through the lens model, lands on the point.
        if let Some(c) = pl.commands.get(i) {
            let landed = self.lens_model.land(*c, *h);
            let err = (landed[0] - xy[0]).hypot(landed[1] - xy[1]);
            self.report.max_command_error_mm = self.report.max_command_error_mm.max(err);
            if err > ROUND_TRIP_TOLERANCE_MM {
                self.violation(format!(
                    "{}: the galvo command lands {:.4} mm off the point (outside the field correction?)",
                    here(),
                    err
                ));
            }
            let c_abs = c[0].abs().max(c[1].abs());
            if c[0].abs() > half_field[0] + CHECK_SLACK || c[1].abs() > half_field[1] + CHECK_SLACK
            {
                self.violation(format!(
                    "{}: command ({:.3}, {:.3}) mm outside the field",
                    here(),
                    c[0],
                    c[1]
                ));
            }
            self.report.max_field_abs_mm = self.report.max_field_abs_mm.max(c_abs);
        } else {
            self.violation(format!("{}: no galvo command", here()));
        }
        let registered = point_on_contour(contour, t.source[i]);
        let back = workpiece_from_galvo(zone, layer, *xy) + fz * *h;
        let err = (back - registered).norm();
        self.report.max_round_trip_error_mm = self.report.max_round_trip_error_mm.max(err);
        if err > ROUND_TRIP_TOLERANCE_MM {
            self.violation(format!("{}: round trip off by {err:.6} mm", here()));
        }
    }

    /// Every contour marked once: its polylines partition it along its arc length (no stretch
    /// marked twice, none left out; [`crate::partition`]). A contour a stretch of which would
    /// be marked twice is recorded in `double_marked_contours`.
    fn partition(
        &mut self,
        path: &Path,
        mut spans: std::collections::BTreeMap<ContourId, Vec<Span>>,
    ) {
        for c in path.contours() {
            let found = crate::partition::violations(
                c.id(),
                c.points(),
                &spans.remove(&c.id()).unwrap_or_default(),
            );
            if found.iter().any(|f| f.marked_twice) {
                self.report.double_marked_contours.push(c.id());
            }
            for f in found {
                self.violation(f.line);
            }
        }
    }

    /// The report, with its violation lines (and how many more there were).
    fn finish(mut self) -> ValidationReport {
        if self.more > 0 {
            self.lines
                .push(format!("… and {} more violations", self.more));
        }
        self.report.passed = self.lines.is_empty();
        self.report.violations = self.lines;
        self.report
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan_field::LensSettings;
    use crate::test_shapes::square;
    use crate::zoning::ZoningSettings;
    use trim_synth::testing::synthetic_core_path;

    #[test]
    fn synthetic_core_plans_and_validates() {
        let path = synthetic_core_path(60, 1);
        // The k-means zoning's 3° budget is checked below (the covering has no budget).
        let settings = PlanSettings {
            zoning: ZoningSettings {
                method: ZoningMethod::Kmeans,
                ..ZoningSettings::default()
            },
            ..PlanSettings::default()
        };
        let out = plan_with_report(&path, &settings).unwrap();
        let v = &out.job.validation;
        assert!(v.passed, "{:?}", v.violations);
        assert!(v.max_round_trip_error_mm <= ROUND_TRIP_TOLERANCE_MM);
        assert!(v.max_incidence_deg <= 5.0 + 1e-9);
        assert!(out.automatic_k);
        for row in &out.table {
            assert!(
                row.max_incidence_deg <= 3.0 + 1e-9,
                "zoning keeps the 3° budget: {row:?}"
            );
        }
        // Zone frames are right-handed with Z the zone axis; layers top down.
        for z in &out.job.zones {
            assert!(trim_cell::frame::orthonormality_error(&z.frame) < 1e-12);
            for w in z.layers.windows(2) {
                let d = Point3::from(w[0].focus_point) - Point3::from(w[1].focus_point);
                assert!(
                    (d.dot(&z.frame.z_axis()) - out.job.layer_step_mm).abs() < 1e-9
                        || d.dot(&z.frame.z_axis()) > 0.0
                );
            }
        }
        // The JSON round trip keeps every galvo point to 1e-12 mm (serde_json parses floats
        // to within an ulp or so, not always bit-exactly).
        let back = Job::from_json(&out.job.to_json().unwrap()).unwrap();
        assert_eq!(back.zones.len(), out.job.zones.len());
        let flat = |j: &Job| -> Vec<f64> {
            j.zones
                .iter()
                .flat_map(|z| z.layers.iter())
                .flat_map(|l| l.polylines.iter())
                .flat_map(|p| p.points.iter().flat_map(|xy| [xy[0], xy[1]]))
                .collect()
        };
        let (a, b) = (flat(&out.job), flat(&back));
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    #[test]
    fn telecentric_zoning_uses_the_full_limit_and_is_deterministic() {
        let path = synthetic_core_path(60, 2);
        let settings = PlanSettings {
            field: LensSettings {
                telecentric: true,
                ..LensSettings::default()
            },
            ..PlanSettings::default()
        };
        let a = plan_with_report(&path, &settings).unwrap();
        assert!(a.job.validation.passed, "{:?}", a.job.validation.violations);
        assert!(a.table.iter().all(|r| r.max_incidence_deg <= 5.0 + 1e-9));
        let b = plan_with_report(&path, &settings).unwrap();
        assert_eq!(a.job.to_json().unwrap(), b.job.to_json().unwrap());
    }

    #[test]
    fn unreachable_axis_names_the_zone() {
        // Beam pointing down −Z needs A = ±180°: outside −100..50.
        let c = trim_geom::Contour::new(
            42,
            vec![Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)],
            -Vector3::z(),
        )
        .unwrap();
        let path = Path::new(vec![c]).unwrap();
        let job = plan(&path, &PlanSettings::default()).unwrap();
        assert_eq!(job.zones.len(), 1);
        let why = job.zones[0]
            .unreachable
            .as_deref()
            .expect("marked unreachable");
        assert!(why.contains("axis limits"), "{why}");
        let v = &job.validation;
        assert!(!v.passed);
        assert_eq!(v.unreachable_zones, vec![0]);
        assert!(
            v.violations
                .iter()
                .any(|l| l.contains("zone 0") && l.contains("42") && l.contains("unreachable")),
            "{:?}",
            v.violations
        );
        // The marked zone survives the Job's JSON round trip.
        let back = Job::from_json(&job.to_json().unwrap()).unwrap();
        assert_eq!(back.zones[0].unreachable, job.zones[0].unreachable);
    }

    #[test]
    fn a_cancelled_plan_stops_with_cancelled_and_an_uncancelled_one_plans() {
        use std::sync::Arc;
        use std::sync::atomic::AtomicBool;
        let path = synthetic_core_path(60, 1);
        for method in [ZoningMethod::Cover, ZoningMethod::Kmeans] {
            let settings = PlanSettings {
                zoning: ZoningSettings {
                    method,
                    ..ZoningSettings::default()
                },
                ..PlanSettings::default()
            };
            let cancelled = Arc::new(AtomicBool::new(true));
            let e = trim_geom::cancel::run_cancellable(cancelled, || plan(&path, &settings))
                .expect_err("a cancelled plan");
            assert!(matches!(e, PlanError::Cancelled), "{method:?}: {e}");
            let running = Arc::new(AtomicBool::new(false));
            trim_geom::cancel::run_cancellable(running, || plan(&path, &settings))
                .expect("an uncancelled plan");
        }
    }

    /// Every galvo point of contour `id`, back in the work-piece frame (its height kept).
    fn landed(job: &Job, id: ContourId) -> Vec<Point3> {
        job.layers()
            .flat_map(|(_, zone, layer)| {
                layer
                    .polylines
                    .iter()
                    .filter(move |p| p.contour == id)
                    .flat_map(move |p| {
                        p.points.iter().zip(&p.heights_mm).map(move |(xy, h)| {
                            workpiece_from_galvo(zone, layer, *xy) + zone.frame.z_axis() * *h
                        })
                    })
            })
            .collect()
    }

    #[test]
    fn the_planned_line_stands_half_a_kerf_out_of_the_material_a_hole_inward_an_outline_outward() {
        // A 20 mm square outline (material inside) holding a 4 mm square hole (material
        // outside), on the plane z = 0.
        let path = Path::new(vec![square(1, 20.0, 20, false), square(2, 4.0, 8, false)]).unwrap();
        let settings = PlanSettings::default();
        let d = settings.kerf_offset_mm().unwrap();
        assert!((d - 0.5 * 2.0 * settings.beam.waist_radius_mm()).abs() < 1e-15);
        let out = plan_with_report(&path, &settings).unwrap();
        assert!(
            out.job.validation.passed,
            "{:?}",
            out.job.validation.violations
        );
        let kerf = out.job.kerf.as_ref().expect("kerf record");
        assert_eq!(kerf.compensated, vec![1, 2]);
        assert!(kerf.uncompensated.is_empty());
        // Signed distance out of a square centred at the origin (negative inside).
        let out_of = |q: &Point3, s: f64| {
            let (dx, dy) = (q.x.abs() - s / 2.0, q.y.abs() - s / 2.0);
            if dx > 0.0 || dy > 0.0 {
                dx.max(0.0).hypot(dy.max(0.0))
            } else {
                dx.max(dy)
            }
        };
        let hole = landed(&out.job, 2);
        assert!(!hole.is_empty());
        for q in &hole {
            // Into the hole by the offset (1 µm: the round-trip tolerance), on the face.
            assert!(
                (out_of(q, 4.0) + d).abs() < 1e-3,
                "hole {q}: {}",
                out_of(q, 4.0)
            );
            assert!(q.z.abs() < 1e-9);
        }
        for q in &landed(&out.job, 1) {
            let o = out_of(q, 20.0);
            assert!(o > d - 1e-3 && o < 2.0 * d, "outline {q}: {o}");
        }
        // Off: the line on the edges, no record.
        let mut off = settings.clone();
        off.trim.kerf_compensation = false;
        let on_edge = plan_with_report(&path, &off).unwrap();
        assert!(on_edge.job.kerf.is_none());
        for q in &landed(&on_edge.job, 2) {
            assert!(out_of(q, 4.0).abs() < 1e-3, "{q}");
        }
        // Sides from a fuller path: the hole alone says nothing, the path with its outline
        // does.
        let hole_only = Path::new(vec![square(2, 4.0, 8, false)]).unwrap();
        let alone = plan_with_report(&hole_only, &settings).unwrap();
        let rec = alone.job.kerf.as_ref().unwrap();
        assert!(rec.compensated.is_empty());
        assert_eq!(rec.uncompensated[0].contour, 2);
        let sides = crate::kerf::material_sides(&path);
        let given = plan_with_sides(&hole_only, &settings, Some(&sides)).unwrap();
        assert_eq!(given.job.kerf.as_ref().unwrap().compensated, vec![2]);
        for q in &landed(&given.job, 2) {
            assert!((out_of(q, 4.0) + d).abs() < 1e-3, "{q}");
        }
    }

    /// Validation refuses a Job whose polylines mark a stretch of a contour twice (issue 24
    /// point 12), naming the contour, both zones and both layers: a planted overlap of a
    /// sub-segment at a junction between two zones, and a polyline planted to run back.
    #[test]
    fn a_planted_sub_segment_overlap_between_two_zones_is_refused() {
        let path = synthetic_core_path(8, 1);
        let mut settings = PlanSettings::default();
        settings.trim.kerf_compensation = false;
        let lens_model = settings.lens_model().unwrap().0;
        let (out, planned) = plan_line_traced(&path, &settings).unwrap();
        assert!(
            out.job.validation.passed,
            "{:?}",
            out.job.validation.violations
        );
        assert!(out.job.validation.double_marked_contours.is_empty());
        // A junction between two zones: polyline A's last source is polyline B's first.
        let mut index = Vec::new();
        for (z, zone) in out.job.zones.iter().enumerate() {
            for (l, layer) in zone.layers.iter().enumerate() {
                for (k, pl) in layer.polylines.iter().enumerate() {
                    index.push((z, l, k, pl.contour));
                }
            }
        }
        let trace = |(z, l, k): (usize, usize, usize)| &planned[z][l][k];
        let (a, b) = index
            .iter()
            .flat_map(|a| index.iter().map(move |b| (a, b)))
            .find(|(a, b)| {
                a.0 != b.0
                    && a.3 == b.3
                    && trace((a.0, a.1, a.2)).source.last() == trace((b.0, b.1, b.2)).source.first()
            })
            .map(|(a, b)| ((a.0, a.1, a.2), (b.0, b.1, b.2)))
            .expect("a contour split between two zones");
        let contour = out.job.zones[a.0].layers[a.1].polylines[a.2].contour;
        let (mut job, mut traces) = (out.job.clone(), planned.clone());
        // A runs on over half of B's first segment: its new point is B's, in A's frame.
        let (b0, b1) = (trace(b).source[0], trace(b).source[1]);
        let on = 0.5 * (b0 + b1);
        let p = point_on_contour(path.get(contour).unwrap().points(), on);
        let zone = &mut job.zones[a.0];
        let frame = zone.frame;
        let layer = &mut zone.layers[a.1];
        let (xy, h) = project(&frame, &Point3::from(layer.focus_point), &p);
        let pl = &mut layer.polylines[a.2];
        pl.points.push(xy);
        pl.commands.push(lens_model.command_for(xy, h).unwrap());
        pl.heights_mm.push(h);
        let t = &mut traces[a.0][a.1][a.2];
        t.source.push(on);
        t.features.push(*t.features.last().unwrap());
        t.height_mm.push(h);
        let v = validate(&job, &traces, &path, &settings, &lens_model);
        assert!(!v.passed);
        assert_eq!(v.double_marked_contours, vec![contour]);
        let name = |(z, l, _): (usize, usize, usize)| {
            format!(
                "zone {} layer {}",
                job.zones[z].id, job.zones[z].layers[l].index
            )
        };
        assert!(
            v.violations
                .iter()
                .any(|l| l.contains(&format!("contour {contour}:"))
                    && l.contains("marked twice")
                    && l.contains(&name(a))
                    && l.contains(&name(b))),
            "{:?}",
            v.violations
        );
        // The round trip of the planted point holds: only the partition refuses it.
        assert!(v.max_round_trip_error_mm <= ROUND_TRIP_TOLERANCE_MM);

        // A polyline planted to run back along its contour over its last segment (every point
        // on it): its one-but-last point once more at its end.
        let (mut job, mut traces) = (out.job.clone(), planned.clone());
        let (z, l, k) = index
            .iter()
            .map(|i| (i.0, i.1, i.2))
            .find(|&i| trace(i).source.len() >= 3)
            .expect("a polyline of three points");
        let pl = &mut job.zones[z].layers[l].polylines[k];
        let back = pl.points.len() - 2;
        pl.points.push(pl.points[back]);
        pl.commands.push(pl.commands[back]);
        pl.heights_mm.push(pl.heights_mm[back]);
        let t = &mut traces[z][l][k];
        t.source.push(t.source[back]);
        t.features.push(t.features[back]);
        t.height_mm.push(t.height_mm[back]);
        let v = validate(&job, &traces, &path, &settings, &lens_model);
        assert!(!v.passed);
        assert_eq!(
            v.double_marked_contours,
            vec![job.zones[z].layers[l].polylines[k].contour]
        );
        assert!(
            v.violations
                .iter()
                .any(|line| line.contains("runs back") && line.contains(&name((z, l, k)))),
            "{:?}",
            v.violations
        );
    }

    #[test]
    fn refuses_bad_settings_by_key() {
        let path = synthetic_core_path(4, 1);
        let settings = PlanSettings {
            max_incidence_deg: -1.0,
            ..PlanSettings::default()
        };
        let e = plan(&path, &settings).unwrap_err();
        assert!(e.to_string().contains("max_incidence_deg"), "{e}");
        let settings = PlanSettings {
            zoning: ZoningSettings {
                k: Some(100),
                ..ZoningSettings::default()
            },
            ..PlanSettings::default()
        };
        let e = plan(&path, &settings).unwrap_err();
        assert!(matches!(e, PlanError::TooManyZones { k: 100, .. }), "{e}");
        let mut settings = PlanSettings::default();
        settings.trim.kerf_clearance_um = 150.0;
        let e = plan(&path, &settings).unwrap_err();
        assert!(e.to_string().contains("trim.kerf_clearance_um"), "{e}");
    }

    #[test]
    fn a_galvo_field_far_smaller_than_a_lens_is_refused_by_its_pieces_not_planned_for_minutes() {
        // A 0.01 mm field cut the demo core into 14,976 pieces and planned for over a minute; a
        // 100 mm square is 40 atoms, each halved toward a field no piece fits.
        let path = Path::new(vec![square(1, 100.0, 40, false)]).unwrap();
        let mut settings = PlanSettings::default();
        settings.galvo.field_mm = [0.01, 0.01];
        let e = plan(&path, &settings).unwrap_err();
        assert!(
            matches!(e, PlanError::TooManyFieldPieces { pieces, max: crate::cover::MAX_ATOMS, .. } if pieces > crate::cover::MAX_ATOMS),
            "{e}"
        );
        let text = e.to_string();
        assert!(
            text.starts_with("galvo.field_mm: ")
                && text.contains("the 5000 the pose covering takes"),
            "{text}"
        );
    }
}
