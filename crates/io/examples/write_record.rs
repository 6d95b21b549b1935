//! Writes a run record (MCAP) of a small hand-made job executed on the in-process simulators,
//! with scan and CAD clouds and template and registered paths, and prints the message count per
//! topic as JSON on stdout (read by tests/python/test_mcap_record.py).
//!
//! `cargo run -q -p trim-io --example write_record -- OUT.mcap`

use std::collections::BTreeMap;

use tokio_util::sync::CancellationToken;
use trim_cell::job::{
    Frame, Job, JobSettings, Layer, Polyline, Pose, TimeEstimate, ValidationReport, Zone,
};
use trim_io::cell_devices::{Cell, Timeouts};
use trim_io::executor::Executor;
use trim_io::laser::Profile;
use trim_io::record::{Recorder, device_tap};
use trim_io::tap::now_ns;
use trim_sim::{SimCell, SimOptions};

/// Points in each synthetic cloud.
const CLOUD_POINTS: usize = 500;

fn job() -> Job {
    let zones = (0..2_usize)
        .map(|z| Zone {
            id: z,
            origin: [10.0 * z as f64, 0.0, 0.0],
            frame: Frame {
                x: [1.0, 0.0, 0.0],
                y: [0.0, 1.0, 0.0],
                z: [0.0, 0.0, 1.0],
            },
            contours: vec![z as i64],
            max_incidence_deg: 1.0,
            max_pairwise_deg: 1.0,
            layers: (0..2_usize)
                .map(|m| {
                    let mut pose = BTreeMap::new();
                    for (k, v) in [
                        ("x", 10.0 * z as f64),
                        ("y", 0.0),
                        ("z", -0.1 * m as f64),
                        ("a", 5.0 * z as f64),
                        ("c", 0.0),
                    ] {
                        pose.insert(k.to_owned(), v);
                    }
                    Layer {
                        index: m,
                        focus_point: [10.0 * z as f64, 0.0, -0.1 * m as f64],
                        pose: Pose(pose),
                        polylines: vec![Polyline::from_points(
                            z as i64,
                            vec![[-3.0, -1.0], [0.0, 2.0], [3.0, -1.0]],
                        )],
                    }
                })
                .collect(),
            unreachable: None,
        })
        .collect();
    Job {
        version: 1,
        layer_step_mm: 0.1,
        focus_half_length_mm: 0.4,
        zones,
        settings: JobSettings {
            lens: Default::default(),
            plan: trim_cell::plan_settings::PlanSettings::default(),
        },
        validation: ValidationReport::default(),
        estimate: TimeEstimate::default(),
        kerf: None,
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .ok_or("usage: write_record OUT.mcap")?;
    let job = job();
    let recorder = Recorder::create(std::path::Path::new(&out))?.shared();
    {
        let mut r = recorder.lock().map_err(|_| "poisoned")?;
        let t = now_ns();
        let cloud = |s: f64| -> Vec<[f64; 3]> {
            (0..CLOUD_POINTS)
                .map(|i| {
                    let a = i as f64 * 0.1;
                    [s * a.cos(), s * a.sin(), 0.01 * i as f64]
                })
                .collect()
        };
        r.point_cloud("/scan", t, &cloud(10.0))?;
        r.point_cloud("/cad", t, &cloud(10.2))?;
        let path = |dz: f64| -> Vec<(i64, Vec<[f64; 3]>)> {
            vec![
                (0, vec![[0.0, 0.0, dz], [5.0, 0.0, dz], [5.0, 5.0, dz]]),
                (1, vec![[10.0, 0.0, dz], [12.0, 3.0, dz]]),
            ]
        };
        r.paths("/template", t, &path(0.0), [0.2, 0.6, 1.0, 1.0])?;
        r.paths("/registered", t, &path(0.05), [1.0, 0.4, 0.1, 1.0])?;
    }
    let sim = SimCell::start(SimOptions {
        cnc_time_scale: 0.05,
        ..SimOptions::new(Profile::builtin("monaco")?)
    })
    .await?;
    let cell = Cell::connect(
        &sim.addresses(),
        &Timeouts::default(),
        device_tap(&recorder),
    )
    .await?;
    let journal = format!("{out}.journal");
    let _ = std::fs::remove_file(&journal);
    let summary = Executor::new(job, cell, &journal, Some(recorder.clone()))
        .run(CancellationToken::new(), None)
        .await?;
    drop(sim);
    // A heartbeat task of the dropped galvo client may still hold a tap for a moment: once the
    // file is finished, late messages are refused, so the counts below are final.
    let per_topic = {
        let mut rec = recorder.lock().map_err(|_| "poisoned")?;
        rec.finish()?;
        rec.messages_per_topic()
    };
    let report = serde_json::json!({
        "messages_per_topic": per_topic,
        "layers_marked": summary.layers_marked,
        "cloud_points": CLOUD_POINTS,
    });
    println!("{report}");
    Ok(())
}
