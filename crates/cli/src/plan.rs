//! `trimctl plan`: plan zones, layers, galvo polylines and machine poses from a (registered)
//! path CSV; write the Job JSON (and an SVG), print the zone table (paper Table 1) on stdout.

use std::path::PathBuf;

use anyhow::Context;
use trim_plan::planner::{PlanOutput, PlanSettings, plan_with_report};

use crate::config::JobConfig;

/// Arguments of `trimctl plan`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The path CSV (`contour,x,y,z,u,v,w`, millimetres, work-piece frame).
    #[arg(long)]
    pub path: PathBuf,
    /// A job file (job.toml) with the planning settings (default: built-in defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Where to write the Job JSON.
    #[arg(long)]
    pub out: PathBuf,
    /// Where to write an SVG of the zones and their layers.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let settings = match &args.config {
        Some(path) => JobConfig::load(path)?.plan_settings(),
        None => PlanSettings::default(),
    };
    let path = trim_geom::formats::read_path(&args.path)?;
    let output = plan_with_report(&path, &settings)
        .with_context(|| format!("planning {}", args.path.display()))?;
    let job = &output.job;
    let json = job.to_json()?;
    std::fs::write(&args.out, json + "\n")
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    if let Some(svg) = &args.svg {
        std::fs::write(svg, trim_plan::svg::job_svg(job))
            .with_context(|| format!("cannot write {}", svg.display()))?;
    }
    print!("{}", zone_table(&output));
    let v = &job.validation;
    eprintln!(
        "trimctl plan: {} contours → {} pieces; k-means k = {}{} → {} zones ({} merges, {} greedy splits) → {} sections/zones, {} layers; ΔH = {:.4} mm",
        path.len(),
        output.pieces,
        output.k,
        if output.automatic_k {
            " (automatic)"
        } else {
            ""
        },
        output.clusters,
        output.merges,
        output.greedy_splits,
        job.zones.len(),
        job.zones.iter().map(|z| z.layers.len()).sum::<usize>(),
        job.layer_step_mm,
    );
    eprintln!(
        "trimctl plan: validation {}: focus ≤ {:.4} mm, incidence ≤ {:.3}° (lens included), field ≤ {:.3} mm, round trip ≤ {:.2e} mm; estimate {:.1} s ({:.1} s motion)",
        if v.passed { "passed" } else { "FAILED" },
        v.max_focus_deviation_mm,
        v.max_incidence_deg,
        v.max_field_abs_mm,
        v.max_round_trip_error_mm,
        job.estimate.total_s,
        job.estimate.motion_s,
    );
    for line in &v.violations {
        eprintln!("trimctl plan: violation: {line}");
    }
    if !v.passed {
        anyhow::bail!(
            "the plan does not validate ({} violations); {} was written for inspection",
            v.violations.len(),
            args.out.display()
        );
    }
    Ok(())
}

/// The zone table: the paper's Table 1 columns (zone, centre and axis (x, y, z, u, v, w),
/// largest included angle) plus the largest incidence with and without the lens, the layer
/// count and the contours.
fn zone_table(output: &PlanOutput) -> String {
    use std::fmt::Write as _;
    let mut s = String::from(
        "zone  cluster  centre (x, y, z, u, v, w)                                 included/°  incidence/°  with lens/°  layers  contours\n",
    );
    for r in &output.table {
        let c = r.centre;
        let _ = writeln!(
            s,
            "{:>4}  {:>7}  ({:8.3}, {:8.3}, {:8.3}, {:6.3}, {:6.3}, {:6.3})  {:>10.4}  {:>11.4}  {:>11.4}  {:>6}  {:?}",
            r.zone,
            r.cluster,
            c[0],
            c[1],
            c[2],
            c[3],
            c[4],
            c[5],
            r.max_pairwise_deg,
            r.max_incidence_deg,
            r.max_incidence_with_lens_deg,
            r.layers,
            r.contours
        );
    }
    s
}
