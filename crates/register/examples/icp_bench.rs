//! Times trimctl's point-to-plane ICP on two point clouds, for the peer comparison
//! (`benches/peers/run`). Prints one JSON object on stdout.
//!
//! `icp_bench SOURCE.ply TARGET.ply --max-dist D --iterations N --repeat R
//!  [--translation-eps E] [--rotation-eps-rad A] [--init 16 numbers, row-major]`
//!
//! The target must carry normals. Each timed run builds the target's kd-tree and runs ICP, as a
//! peer's one-call registration does. Threads: `RAYON_NUM_THREADS`.

use std::time::Instant;

use trim_geom::formats::read_points;
use trim_geom::transform::similarity_from_matrix;
use trim_register::icp::{IcpMethod, IcpSettings, IcpTarget, icp};

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err(
            "usage: icp_bench SOURCE TARGET [--max-dist D] [--iterations N] [--repeat R]".into(),
        );
    }
    let source = read_points(std::path::Path::new(&args[1]))?;
    let target = read_points(std::path::Path::new(&args[2]))?;
    let max_dist: f64 = arg(&args, "--max-dist", 1.0);
    let iterations: usize = arg(&args, "--iterations", 30);
    let repeat: usize = arg(&args, "--repeat", 10);
    let init = match args.iter().position(|a| a == "--init") {
        Some(i) => {
            let v: Vec<f64> = args[i + 1..i + 17]
                .iter()
                .map(|s| s.parse())
                .collect::<Result<_, _>>()?;
            similarity_from_matrix(&nalgebra::Matrix4::from_row_slice(&v))?
        }
        None => trim_geom::Similarity3::identity(),
    };
    let settings = IcpSettings {
        method: IcpMethod::PointToPlane,
        max_correspondence_distance_mm: max_dist,
        max_iterations: iterations,
        translation_epsilon_mm: arg(&args, "--translation-eps", 1e-3),
        rotation_epsilon_rad: arg(&args, "--rotation-eps-rad", 0.1f64.to_radians()),
        ..IcpSettings::default()
    };
    let mut times = Vec::with_capacity(repeat);
    let mut last = None;
    for _ in 0..repeat {
        let t0 = Instant::now();
        let prepared = IcpTarget::new(target.clone())?;
        let r = icp(&source, &prepared, &init, &settings)?;
        times.push(t0.elapsed().as_secs_f64());
        last = Some(r);
    }
    let r = last.ok_or("--repeat must be at least 1")?;
    let m = r.target_from_source.to_homogeneous();
    let rows: Vec<String> = (0..4)
        .map(|i| {
            format!(
                "[{}]",
                (0..4)
                    .map(|j| format!("{:.12e}", m[(i, j)]))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })
        .collect();
    let mut sorted = times.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "{{\"median_s\": {:.6e}, \"times_s\": [{}], \"iterations\": {}, \"fitness\": {:.6}, \"rmse\": {:.6e}, \"source_points\": {}, \"target_points\": {}, \"threads\": {}, \"target_from_source\": [{}]}}",
        sorted[sorted.len() / 2],
        times
            .iter()
            .map(|t| format!("{t:.6e}"))
            .collect::<Vec<_>>()
            .join(", "),
        r.iterations,
        r.fitness,
        r.rmse_mm,
        source.len(),
        target.len(),
        rayon::current_num_threads(),
        rows.join(", ")
    );
    Ok(())
}
