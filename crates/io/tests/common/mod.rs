//! Shared helpers of the trim-io integration tests (and of trim-sim's twin test, which includes
//! this file by path): a hand-made job and the simulated cell.

use std::collections::BTreeMap;
use std::time::Duration;

use trim_cell::job::{
    Frame, GalvoSettings, Job, JobSettings, Layer, Polyline, Pose, TimeEstimate, ValidationReport,
    Zone,
};
use trim_io::cell_devices::{Cell, Timeouts};
use trim_io::galvo::list::vectors_bits;
use trim_io::laser::Profile;
use trim_io::tap::Tap;
use trim_sim::galvo::{Lit, MarkRecord};
use trim_sim::{SimCell, SimOptions};

/// Timeouts for tests: short device timeouts so faults resolve fast, still far above the
/// in-process simulators' reply times (under 10 ms even on a loaded machine), and a heartbeat
/// the client beats every 100 ms.
pub fn test_timeouts() -> Timeouts {
    Timeouts {
        galvo_reply: Duration::from_millis(500),
        galvo_resends: 1,
        galvo_heartbeat_ms: 400,
        laser_reply: Duration::from_millis(500),
        cnc_reply: Duration::from_millis(1000),
        cnc_motion: Duration::from_secs(3),
        list_time_factor: 3.0,
        list_time_margin: Duration::from_millis(1500),
        shutdown_step: Duration::from_millis(400),
        laser_off_budget: Duration::from_millis(1200),
        journal_write: Duration::from_millis(1000),
    }
}

fn pose(x: f64, y: f64, z: f64, a: f64, c: f64) -> Pose {
    let mut m = BTreeMap::new();
    for (k, v) in [("x", x), ("y", y), ("z", z), ("a", a), ("c", c)] {
        m.insert(k.to_owned(), v);
    }
    Pose(m)
}

/// A small job: 2 zones × `layers` layers × 2 polylines (a 3-segment zig-zag and a 2-segment
/// corner), so 5 vectors per layer; zone 1 tilted (A 10°, C 30°).
pub fn demo_job(layers: usize) -> Job {
    let mut zones = Vec::new();
    for zid in 0..2_usize {
        let (a, c) = if zid == 0 { (0.0, 0.0) } else { (10.0, 30.0) };
        let zl = (0..layers)
            .map(|m| {
                let dz = -0.1 * m as f64;
                let s = 1.0 + 0.25 * m as f64 + zid as f64;
                Layer {
                    index: m,
                    focus_point: [5.0 * zid as f64, 0.0, dz],
                    pose: pose(5.0 * zid as f64, 0.0, dz, a, c),
                    polylines: vec![
                        Polyline::from_points(
                            1 + zid as i64,
                            vec![
                                [-4.0 * s, -2.0],
                                [-2.0 * s, 2.0],
                                [0.0, -2.0],
                                [2.0 * s, 2.0],
                            ],
                        ),
                        Polyline::from_points(
                            10 + zid as i64,
                            vec![[5.0, 5.0 + s], [8.0, 5.0 + s], [8.0, 9.0]],
                        ),
                    ],
                }
            })
            .collect();
        zones.push(Zone {
            id: zid,
            origin: [5.0 * zid as f64, 0.0, 0.0],
            frame: Frame {
                x: [1.0, 0.0, 0.0],
                y: [0.0, 1.0, 0.0],
                z: [0.0, 0.0, 1.0],
            },
            contours: vec![1 + zid as i64, 10 + zid as i64],
            max_incidence_deg: 2.0,
            max_pairwise_deg: 3.0,
            layers: zl,
            unreachable: None,
        });
    }
    Job {
        version: 1,
        layer_step_mm: 0.1,
        focus_half_length_mm: 0.4,
        zones,
        settings: JobSettings {
            lens: Default::default(),
            plan: trim_cell::plan_settings::PlanSettings {
                galvo: GalvoSettings {
                    mark_speed_mm_per_s: 400.0,
                    jump_speed_mm_per_s: 2000.0,
                    ..GalvoSettings::default()
                },
                ..Default::default()
            },
        },
        validation: ValidationReport::default(),
        estimate: TimeEstimate::default(),
        kerf: None,
    }
}

/// Every planned vector of the job, in bits.
pub fn planned_vectors(job: &Job) -> Vec<([i32; 2], [i32; 2])> {
    job.layers()
        .flat_map(|(_, _, l)| vectors_bits(l, &job.settings.plan.galvo).expect("in field"))
        .collect()
}

/// Checks every planned vector was marked with light exactly once and nothing else was;
/// returns the number of partly marked vectors (light cut mid-vector).
pub fn assert_marked_exactly_once(job: &Job, marks: &[MarkRecord]) -> usize {
    let mut want: BTreeMap<([i32; 2], [i32; 2]), i32> = BTreeMap::new();
    for v in planned_vectors(job) {
        *want.entry(v).or_default() += 1;
    }
    let mut got: BTreeMap<([i32; 2], [i32; 2]), i32> = BTreeMap::new();
    for m in marks.iter().filter(|m| m.lit == Lit::Full) {
        *got.entry((m.from_bits, m.to_bits)).or_default() += 1;
    }
    assert_eq!(got, want, "fully marked vectors differ from the plan");
    marks.iter().filter(|m| m.lit == Lit::Partial).count()
}

/// Starts the simulated cell (galvo in real time, CNC 10× faster).
pub async fn sim_cell(profile: &str) -> SimCell {
    sim_cell_scaled(profile, 1.0).await
}

/// Starts the simulated cell with the galvo's clock slowed `galvo_time_scale` times.
pub async fn sim_cell_scaled(profile: &str, galvo_time_scale: f64) -> SimCell {
    let mut o = SimOptions::new(Profile::builtin(profile).expect("profile"));
    o.galvo_time_scale = galvo_time_scale;
    o.cnc_time_scale = 0.1;
    SimCell::start(o).await.expect("simulators")
}

/// Connects a cell to the simulators.
pub async fn connect(sim: &SimCell, tap: Tap) -> Cell {
    Cell::connect(&sim.addresses(), &test_timeouts(), tap)
        .await
        .expect("connect")
}
