//! The digital twin: a *true* cell that differs from the nominal one (job.toml `[sim.truth]`;
//! DESIGN.md "Frames and the calibration chain").
//!
//! The planner works from `[calibration]` (nominal where it is silent); the simulators carry the
//! truth: the rotary axes' real lines, the scanner's real pose on the head, the galvo head's real
//! field (offset, rotation, distortion) and the lens's real pivot height L. The galvo simulator
//! hands every marked vector to [`Twin::on_mark`], which asks the CNC simulator where the
//! machine is, builds the real beam of that command, carries it into the work-piece frame
//! through the *true* table, meets the true part there and measures the distance from the
//! landed spot to the true trimming line: the **spot error**.
//!
//! Truth model of the head: a command c (mm, head frame) lands on the focal plane at
//! `J + D(c)` (J the linear joints, the tool point), `D` = [`LensDistortion::land`]; the beam
//! comes from a pivot at height L above `J + D(0)`, so at height h (toward the lens) it is at
//! `D(0) + (L − h)/L·(D(c) − D(0))`. A telecentric lens sends every beam along +Z.

use crate::ablation::LandedCut;
use std::sync::{Arc, Mutex};
use trim_geom::crop::point_segment_distance;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use trim_cell::cell_model::{ScanPose, ScannerPose, TableModel};
use trim_cell::kinematics::{AxisPose, KinematicsKind, MachineSettings, joints_of};
use trim_cell::lens::LensDistortion;
use trim_cell::truth::TruthSettings;
use trim_geom::kdtree::KdTree;
use trim_geom::{Path, Point3, UnitVector3, Vector3};
use trim_plan::planner::PlanSettings;

/// Neighbouring path vertices searched for the nearest segment of the trimming line.
const NEAREST_VERTICES: usize = 8;

/// The true cell, resolved against the plan settings the controller is configured with.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueCell {
    /// The controller's configuration: its (nominal) kinematics turn commanded poses into
    /// joint positions.
    pub machine: MachineSettings,
    /// The true rotary axis lines.
    pub table: TableModel,
    /// The scanner's true pose on the head.
    pub scanner: ScannerPose,
    /// The galvo head's true field.
    pub head: LensDistortion,
    /// A telecentric lens (beams along +Z).
    pub telecentric: bool,
    /// The true pivot height L (mm).
    pub pivot_to_focal_plane_mm: f64,
    /// Galvo bits per millimetre (as the controller is set up).
    pub bits_per_mm: f64,
}

impl TrueCell {
    /// The true cell of `truth` on the machine and galvo of `plan`.
    #[must_use]
    pub fn new(truth: &TruthSettings, plan: &PlanSettings) -> TrueCell {
        let cal = &truth.calibration;
        TrueCell {
            machine: plan.machine,
            table: cal.table(&plan.machine),
            scanner: cal.scanner(),
            head: truth.head,
            telecentric: plan.field.telecentric,
            pivot_to_focal_plane_mm: cal
                .lens
                .pivot_to_focal_plane_mm
                .unwrap_or(plan.beam.focal_length_mm),
            bits_per_mm: plan.galvo.bits_per_mm,
        }
    }

    /// The joints (mm) and rotary axes (degrees) the controller drives for the CNC position
    /// `[X, Y, Z, A, B, C]`; `tcp`: the position is LinuxCNC world coordinates (M428).
    #[must_use]
    pub fn joints(&self, position: [f64; 6], tcp: bool) -> (Vector3, f64, f64) {
        let tilt = match self.machine.kinematics {
            KinematicsKind::XyzbcTrt => position[4],
            _ => position[3],
        };
        let pose = AxisPose {
            linear_mm: [position[0], position[1], position[2]],
            tilt_deg: tilt,
            rotary_deg: position[5],
        };
        let mut m = self.machine;
        m.pose_mode = if tcp {
            trim_cell::PoseMode::Tcp
        } else {
            trim_cell::PoseMode::Joints
        };
        (joints_of(&m, &pose), tilt, position[5])
    }

    /// The real beam of a galvo command at a CNC position: where it crosses the focal plane
    /// and its direction toward the lens, both in the work-piece frame.
    #[must_use]
    pub fn beam(
        &self,
        position: [f64; 6],
        tcp: bool,
        command_mm: [f64; 2],
    ) -> (Point3, UnitVector3) {
        let (j, tilt, c) = self.joints(position, tcp);
        let d0 = self.head.land([0.0, 0.0]);
        let dc = self.head.land(command_mm);
        let on_plane = Point3::new(j.x + dc[0], j.y + dc[1], j.z);
        let toward_lens = if self.telecentric {
            Vector3::z()
        } else {
            let pivot = Point3::new(j.x + d0[0], j.y + d0[1], j.z + self.pivot_to_focal_plane_mm);
            (pivot - on_plane).normalize()
        };
        let table_from_machine = self.table.machine_from_table(tilt, c).inverse();
        let origin = Vector3::from(self.machine.workpiece_origin_mm);
        (
            table_from_machine * on_plane - origin,
            UnitVector3::new_normalize(table_from_machine * toward_lens),
        )
    }

    /// `scanner_from_workpiece` at a scan pose: how the true scanner sees work-piece points.
    #[must_use]
    pub fn scanner_from_workpiece(&self, pose: &ScanPose) -> Isometry3<f64> {
        trim_cell::cell_model::ScanChain {
            table: self.table,
            scanner: self.scanner,
            pose: *pose,
            workpiece_origin_mm: Vector3::from(self.machine.workpiece_origin_mm),
        }
        .workpiece_from_scanner()
        .inverse()
    }
}

/// The true part: its trimming line with the surface normal at every vertex.
#[derive(Debug)]
pub struct TruePart {
    vertices: Vec<Point3>,
    normals: Vec<Vector3>,
    /// For each vertex: (first vertex of its contour, one past its last).
    spans: Vec<(usize, usize)>,
    tree: KdTree,
}

impl TruePart {
    /// The part whose true trimming line is `path` (work-piece frame; feature vectors are the
    /// surface normals).
    #[must_use]
    pub fn new(path: &Path) -> TruePart {
        let (mut vertices, mut normals, mut spans) = (Vec::new(), Vec::new(), Vec::new());
        for c in path.contours() {
            let start = vertices.len();
            let end = start + c.points().len();
            vertices.extend_from_slice(c.points());
            normals.extend(c.features().iter().map(|f| f.normalize()));
            spans.extend(std::iter::repeat_n((start, end), c.points().len()));
        }
        let tree = KdTree::build(&vertices);
        TruePart {
            vertices,
            normals,
            spans,
            tree,
        }
    }

    /// Where a beam (a point on it and its direction) meets the part's surface at the trimming
    /// line (the tangent plane of the nearest vertex), and the distance (mm) from there to the
    /// trimming line.
    #[must_use]
    pub fn land(&self, on_beam: &Point3, direction: &UnitVector3) -> Option<(Point3, f64)> {
        let near = self.tree.nearest(on_beam)?;
        let (q, n) = (self.vertices[near.index], self.normals[near.index]);
        let along = direction.dot(&n);
        let spot = if along.abs() > 1e-6 {
            on_beam + direction.into_inner() * ((q - on_beam).dot(&n) / along)
        } else {
            *on_beam
        };
        Some((spot, self.distance_to_line(&spot)))
    }

    /// The distance (mm) from a point to the nearest segment of the trimming line.
    #[must_use]
    pub fn distance_to_line(&self, p: &Point3) -> f64 {
        let mut best = f64::INFINITY;
        for n in self.tree.knn(p, NEAREST_VERTICES) {
            let i = n.index;
            let (start, end) = self.spans[i];
            for (a, b) in [
                (i.saturating_sub(1).max(start), i),
                (i, (i + 1).min(end - 1)),
            ] {
                best = best.min(point_segment_distance(
                    p,
                    &self.vertices[a],
                    &self.vertices[b],
                ));
            }
        }
        best
    }
}

/// One landed spot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spot {
    /// The galvo list tag of the vector.
    pub tag: u32,
    /// The vector's index among the list's mark vectors (0-based; add the layer's
    /// `first_vector` for its index in the layer).
    pub vector: u32,
    /// Where it landed on the true part (work-piece frame, mm).
    pub landed_mm: [f64; 3],
    /// Its distance to the true trimming line (mm).
    pub error_mm: f64,
}

/// Where the machine is: the CNC position `[X, Y, Z, A, B, C]` and whether it is in TCP mode.
pub type PoseSource = Box<dyn Fn() -> ([f64; 6], bool) + Send + Sync>;

/// Where each landed cut goes as it lands, besides the twin's own list ([`Twin::on_cut`]).
pub type CutSink = Box<dyn FnMut(&LandedCut) + Send>;

/// The twin: the true cell, the true part and the spots landed so far.
pub struct Twin {
    cell: TrueCell,
    part: TruePart,
    pose: Mutex<Option<PoseSource>>,
    spots: Mutex<Vec<Spot>>,
    cuts: Mutex<Vec<LandedCut>>,
    cut_sink: Mutex<Option<CutSink>>,
    blocked: Mutex<BeamBlock>,
}

/// An injected fault of the twin's beam ([`Twin::block_beam`]): the lists seen so far, in the
/// order their first mark arrived, and which one lands nothing.
#[derive(Debug, Default)]
struct BeamBlock {
    /// The list (1 = the first to mark) whose beam is blocked.
    nth_list: Option<u32>,
    /// The tags of the lists that marked, in order (kept only while a block is set).
    tags: Vec<u32>,
    /// Mark vectors that landed nothing because of the block.
    marks_blocked: u64,
}

impl std::fmt::Debug for Twin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Twin")
            .field("cell", &self.cell)
            .finish_non_exhaustive()
    }
}

impl Twin {
    /// A twin of `cell` carrying `part`. Attach the CNC with [`Twin::attach_cnc`].
    #[must_use]
    pub fn new(cell: TrueCell, part: TruePart) -> Arc<Twin> {
        Arc::new(Twin {
            cell,
            part,
            pose: Mutex::new(None),
            spots: Mutex::new(Vec::new()),
            cuts: Mutex::new(Vec::new()),
            cut_sink: Mutex::new(None),
            blocked: Mutex::new(BeamBlock::default()),
        })
    }

    /// Fault injection: the beam is blocked while the `nth_list`-th galvo list marks (1 = the
    /// first list whose marks reach the twin; in a fresh run the layers mark in the job's
    /// order, so that is the job's n-th layer). The galvo, the laser and the executor see a
    /// normal layer (marked, journaled as done); nothing reaches the part: no spot, no cut. It
    /// stands for a beam that did not arrive (a shutter, a soiled window, a power drop) and
    /// exists to show that inspection catches an under-trimmed part. A simulator-only fault:
    /// a real cell has no twin. Set it before the run: lists are counted from then on.
    pub fn block_beam(&self, nth_list: u32) {
        self.blocked
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .nth_list = Some(nth_list);
    }

    /// Mark vectors that landed nothing because of [`Twin::block_beam`].
    #[must_use]
    pub fn marks_blocked(&self) -> u64 {
        self.blocked
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .marks_blocked
    }

    /// Whether list `tag`'s beam is blocked (and counts the vector if so).
    fn beam_blocked(&self, tag: u32) -> bool {
        let mut b = self
            .blocked
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let Some(nth) = b.nth_list else {
            return false;
        };
        // The lists mark one after the other: the last tag seen is almost always this one.
        let ordinal = match b.tags.iter().rposition(|t| *t == tag) {
            Some(i) => i + 1,
            None => {
                b.tags.push(tag);
                b.tags.len()
            }
        };
        let blocked = usize::try_from(nth).is_ok_and(|n| n == ordinal);
        if blocked {
            b.marks_blocked += 1;
        }
        blocked
    }

    /// The true cell.
    #[must_use]
    pub fn cell(&self) -> &TrueCell {
        &self.cell
    }

    /// Where the machine's position comes from (the CNC simulator).
    pub fn attach_cnc(&self, source: PoseSource) {
        *self
            .pose
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(source);
    }

    /// Mark vector `vector` (0-based in the list; galvo bits, from → to) of list `tag`: lands
    /// both ends on the true part.
    pub fn on_mark(&self, tag: u32, vector: u32, from_bits: [i32; 2], to_bits: [i32; 2]) {
        if self.beam_blocked(tag) {
            return;
        }
        let Some((position, tcp)) = self
            .pose
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_ref()
            .map(|f| f())
        else {
            return;
        };
        let mut out = Vec::with_capacity(2);
        for bits in [from_bits, to_bits] {
            let mm = [
                f64::from(bits[0]) / self.cell.bits_per_mm,
                f64::from(bits[1]) / self.cell.bits_per_mm,
            ];
            let (p, d) = self.cell.beam(position, tcp, mm);
            if let Some((spot, error_mm)) = self.part.land(&p, &d) {
                out.push(Spot {
                    tag,
                    vector,
                    landed_mm: [spot.x, spot.y, spot.z],
                    error_mm,
                });
            }
        }
        if let [from, to] = out.as_slice() {
            let cut = LandedCut {
                from: Point3::from(from.landed_mm),
                to: Point3::from(to.landed_mm),
            };
            self.cuts
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .push(cut);
            if let Some(sink) = self
                .cut_sink
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .as_mut()
            {
                sink(&cut);
            }
        }
        self.spots
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .extend(out);
    }

    /// Hands every cut landed from now on to `sink` as it lands (replacing an earlier sink),
    /// before the galvo's list goes on: the sink has seen a layer's cuts before the galvo
    /// reports the layer done. `trimctl run --verify` keeps them in the run folder this way,
    /// so a run killed midway loses none of what landed.
    pub fn on_cut(&self, sink: CutSink) {
        *self
            .cut_sink
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(sink);
    }

    /// Every mark vector landed so far, as the segment it drew on the true part (a vector
    /// marked again is there again), for [`crate::ablation::ablate`].
    #[must_use]
    pub fn cuts(&self) -> Vec<LandedCut> {
        self.cuts
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Every spot landed so far.
    #[must_use]
    pub fn spots(&self) -> Vec<Spot> {
        self.spots
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }
}

/// Spot error statistics (µm).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SpotStats {
    /// Spots counted.
    pub spots: usize,
    /// Mean (µm).
    pub mean_um: f64,
    /// 95th percentile (µm).
    pub p95_um: f64,
    /// Largest (µm).
    pub max_um: f64,
}

impl SpotStats {
    /// The statistics of spot errors given in millimetres.
    #[must_use]
    pub fn of_mm(errors_mm: &[f64]) -> SpotStats {
        if errors_mm.is_empty() {
            return SpotStats::default();
        }
        let mut um: Vec<f64> = errors_mm.iter().map(|e| e * 1e3).collect();
        um.sort_by(f64::total_cmp);
        let rank = ((0.95 * um.len() as f64).ceil() as usize).clamp(1, um.len()) - 1;
        SpotStats {
            spots: um.len(),
            mean_um: um.iter().sum::<f64>() / um.len() as f64,
            p95_um: um[rank],
            max_um: um[um.len() - 1],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::Contour;

    fn line_part() -> Path {
        let pts: Vec<Point3> = (0..=100)
            .map(|i| Point3::new(-5.0 + 0.1 * f64::from(i), 2.0, 1.0))
            .collect();
        Path::new(vec![Contour::new(7, pts, Vector3::z()).expect("contour")]).expect("path")
    }

    #[test]
    fn a_perfect_cell_lands_on_the_commanded_point() {
        let plan = PlanSettings::default();
        let cell = TrueCell::new(&TruthSettings::default(), &plan);
        // TCP pose putting the focus at (0, 2, 1) with the beam along +Z: world = point.
        let pos = [0.0, 2.0, 1.0, 0.0, 0.0, 0.0];
        let part = TruePart::new(&line_part());
        for cmd in [[0.0, 0.0], [3.0, 0.0], [-4.5, 0.0]] {
            let (p, d) = cell.beam(pos, true, cmd);
            let (spot, err) = part.land(&p, &d).expect("lands");
            // The beam leans outward by atan(x/L); the part is on the focal plane: no error.
            assert!(err < 1e-9, "{cmd:?}: {err}");
            assert!((spot - Point3::new(cmd[0], 2.0, 1.0)).norm() < 1e-9);
        }
        // 0.01 mm off the line in y: 10 µm error.
        let (p, d) = cell.beam(pos, true, [1.0, 0.01]);
        let (_, err) = part.land(&p, &d).expect("lands");
        assert!((err - 0.01).abs() < 1e-9, "{err}");
    }

    #[test]
    fn the_head_height_term_follows_the_pivot() {
        // Focal plane 0.2 mm above the part: the beam meets the part 0.2 mm further along its
        // slant, (L + 0.2)/L of the command.
        let plan = PlanSettings::default();
        let cell = TrueCell::new(&TruthSettings::default(), &plan);
        let l = cell.pivot_to_focal_plane_mm;
        let pos = [0.0, 2.0, 1.2, 0.0, 0.0, 0.0];
        let part = TruePart::new(&line_part());
        let (p, d) = cell.beam(pos, true, [4.0, 0.0]);
        let (spot, _) = part.land(&p, &d).expect("lands");
        assert!((spot.x - 4.0 * (l + 0.2) / l).abs() < 1e-9, "{spot}");
    }

    #[test]
    fn a_blocked_beam_lands_nothing_of_its_list_and_everything_of_the_others() {
        let plan = PlanSettings::default();
        let twin = Twin::new(
            TrueCell::new(&TruthSettings::default(), &plan),
            TruePart::new(&line_part()),
        );
        twin.attach_cnc(Box::new(|| ([0.0, 2.0, 1.0, 0.0, 0.0, 0.0], true)));
        twin.block_beam(2);
        let bits = |x_mm: f64| [(x_mm * twin.cell().bits_per_mm).round() as i32, 0];
        // Three lists in the order they mark; the second is blocked.
        for (tag, vectors) in [(0x5A00_0001, 2), (0x5A00_0002, 3), (0x5A00_0003, 2)] {
            for v in 0..vectors {
                twin.on_mark(tag, v, bits(f64::from(v)), bits(f64::from(v) + 0.5));
            }
        }
        assert_eq!(twin.marks_blocked(), 3);
        assert_eq!(twin.cuts().len(), 4);
        let tags: Vec<u32> = twin.spots().iter().map(|s| s.tag).collect();
        assert_eq!(tags.len(), 8);
        assert!(!tags.contains(&0x5A00_0002), "{tags:x?}");
        // Without a block every vector lands.
        let clear = Twin::new(
            TrueCell::new(&TruthSettings::default(), &plan),
            TruePart::new(&line_part()),
        );
        clear.attach_cnc(Box::new(|| ([0.0, 2.0, 1.0, 0.0, 0.0, 0.0], true)));
        clear.on_mark(1, 0, bits(0.0), bits(0.5));
        assert_eq!((clear.cuts().len(), clear.marks_blocked()), (1, 0));
    }

    /// The sink sees every landed cut, in order, as the twin's own list has it (a blocked
    /// beam's vectors neither), and its serde form reads back the same cut.
    #[test]
    fn the_cut_sink_sees_every_landed_cut_as_it_lands() {
        let plan = PlanSettings::default();
        let twin = Twin::new(
            TrueCell::new(&TruthSettings::default(), &plan),
            TruePart::new(&line_part()),
        );
        twin.attach_cnc(Box::new(|| ([0.0, 2.0, 1.0, 0.0, 0.0, 0.0], true)));
        let seen = Arc::new(Mutex::new(Vec::new()));
        let into = Arc::clone(&seen);
        twin.on_cut(Box::new(move |c| {
            into.lock().expect("the test's lock").push(*c);
        }));
        twin.block_beam(2);
        let bits = |x_mm: f64| [(x_mm * twin.cell().bits_per_mm).round() as i32, 0];
        for (tag, vectors) in [(1, 2), (2, 3), (3, 1)] {
            for v in 0..vectors {
                twin.on_mark(tag, v, bits(f64::from(v)), bits(f64::from(v) + 0.5));
            }
        }
        let seen = seen.lock().expect("the test's lock").clone();
        assert_eq!(seen, twin.cuts());
        assert_eq!(seen.len(), 3);
        let text = serde_json::to_string(&seen[1]).expect("a cut serialises");
        let back: LandedCut = serde_json::from_str(&text).expect("and reads back");
        assert_eq!(back, seen[1]);
    }

    #[test]
    fn spot_stats_rank_the_95th_percentile() {
        let errs: Vec<f64> = (1..=100).map(|i| f64::from(i) * 1e-3).collect();
        let s = SpotStats::of_mm(&errs);
        assert_eq!(s.spots, 100);
        assert!((s.p95_um - 95.0).abs() < 1e-9 && (s.max_um - 100.0).abs() < 1e-9);
        assert_eq!(SpotStats::of_mm(&[]).spots, 0);
    }
}
