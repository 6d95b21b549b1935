//! `trimctl plan`: plan zones, layers, galvo polylines and machine poses from a (registered)
//! path CSV; write the Job JSON (and an SVG), print the zone table (paper Table 1) on stdout.

use std::path::PathBuf;

use anyhow::Context;
use trim_plan::planner::plan_with_report;

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
    /// Hatch tracks to plan beside the contours: a tracks CSV from `trimctl hatch`, in the
    /// path's frame (repeatable). The tracks take negative contour ids: −(1 + 100000·r + t) for
    /// track t of the r-th file.
    #[arg(long, value_name = "TRACKS.csv")]
    pub hatch: Vec<PathBuf>,
    /// A timing file from `trimctl calibrate timing`: its [machine] move keys and [timing]
    /// replace the job file's for the time estimate.
    #[arg(long, value_name = "timing.toml")]
    pub timing: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    crate::outputs::check(&[("--out", Some(&args.out)), ("--svg", args.svg.as_deref())])?;
    // A job file is checked whole on load, its [beam] against cell.laser_profile's limits
    // included; the defaults are checked the same way.
    let mut settings = match &args.config {
        Some(path) => JobConfig::load(path)?.plan.clone(),
        None => {
            let config = JobConfig::default();
            config.validate().context("the default job")?;
            config.plan.clone()
        }
    };
    if let Some(file) = &args.timing {
        crate::calibrate_timing::TimingFile::load(file)?
            .apply(&mut settings.machine, &mut settings.timing);
    }
    let mut path = trim_geom::formats::read_path(&args.path)?;
    if !args.hatch.is_empty() {
        crate::hatch::check_path_ids(&path, &args.path)?;
        let mut contours = path.contours().to_vec();
        for (r, file) in args.hatch.iter().enumerate() {
            let tracks = trim_geom::formats::read_path(file)?;
            contours.extend(
                crate::hatch::as_region_tracks(&tracks, r)
                    .with_context(|| format!("--hatch {}", file.display()))?,
            );
        }
        path = trim_geom::Path::new(contours)?;
    }
    let output = plan_with_report(&path, &settings)
        .with_context(|| format!("planning {}", args.path.display()))?;
    let job = &output.job;
    let json = job.to_json()?;
    trim_geom::fs::write_atomic(&args.out, json + "\n")
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    if let Some(svg) = &args.svg {
        trim_geom::fs::write_atomic(svg, trim_plan::svg::job_svg(job))
            .with_context(|| format!("cannot write {}", svg.display()))?;
    }
    print!("{}", crate::summary::zone_table(&output));
    let v = &job.validation;
    eprintln!(
        "trimctl plan: {} contours → {} pieces; {} → {} zones, {} layers; ΔH = {:.4} mm",
        path.len(),
        output.pieces,
        crate::summary::zoning(&output),
        job.zones.len(),
        job.zones.iter().map(|z| z.layers.len()).sum::<usize>(),
        job.layer_step_mm,
    );
    eprintln!(
        "trimctl plan: validation {}: focus ≤ {:.4} mm, incidence ≤ {:.3}° (lens included), field ≤ {:.3} mm, round trip ≤ {:.2e} mm, commands land ≤ {:.2e} mm; estimate {:.1} s ({:.1} s motion of which {:.1} s settle; laser on {:.1} %)",
        if v.passed { "passed" } else { "FAILED" },
        v.max_focus_deviation_mm,
        v.max_incidence_deg,
        v.max_field_abs_mm,
        v.max_round_trip_error_mm,
        v.max_command_error_mm,
        job.estimate.total_s,
        job.estimate.motion_s,
        job.estimate.settle_s,
        job.estimate.laser_on_fraction * 1e2,
    );
    for line in crate::summary::kerf(job).lines() {
        eprintln!("trimctl plan: {line}");
    }
    for line in &v.violations {
        eprintln!("trimctl plan: violation: {line}");
    }
    if !v.unreachable_zones.is_empty() {
        eprintln!(
            "trimctl plan: unreachable zones (outside the axis limits; `run` refuses this plan): {:?}",
            v.unreachable_zones
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use trim_cell::job::Job;

    fn write_core(dir: &std::path::Path) -> PathBuf {
        let csv = dir.join("core.csv");
        let path = trim_synth::testing::synthetic_core_path(60, 11);
        trim_geom::formats::write_path(&csv, &path).expect("writes the CSV");
        csv
    }

    #[test]
    fn plans_a_csv_into_job_json_and_svg() {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("plan.json");
        let svg = dir.path().join("plan.svg");
        run(Args {
            path: write_core(dir.path()),
            config: None,
            out: out.clone(),
            svg: Some(svg.clone()),
            hatch: Vec::new(),
            timing: None,
        })
        .expect("plans");
        let job =
            Job::from_json(&std::fs::read_to_string(&out).expect("json written")).expect("a job");
        assert!(job.validation.passed);
        assert!(job.validation.max_round_trip_error_mm <= 1e-3);
        let svg = std::fs::read_to_string(&svg).expect("svg written");
        assert!(svg.starts_with("<svg"));
    }

    #[test]
    fn config_sets_the_settings_and_bad_input_names_file_and_line() {
        let dir = tempfile::tempdir().expect("temp dir");
        let config = dir.path().join("job.toml");
        trim_geom::fs::write_atomic(
            &config,
            "[field]\ntelecentric = true\n[layers]\nstep_mm = 0.3\n",
        )
        .expect("writes");
        let out = dir.path().join("plan.json");
        run(Args {
            path: write_core(dir.path()),
            config: Some(config),
            out: out.clone(),
            svg: None,
            hatch: Vec::new(),
            timing: None,
        })
        .expect("plans");
        let job = Job::from_json(&std::fs::read_to_string(&out).expect("json")).expect("job");
        assert!((job.layer_step_mm - 0.3).abs() < 1e-15);

        let bad = dir.path().join("bad.csv");
        trim_geom::fs::write_atomic(
            &bad,
            "contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,1,0,nan?,0,0,1\n",
        )
        .expect("writes");
        let e = run(Args {
            path: bad.clone(),
            config: None,
            out: out.clone(),
            svg: None,
            hatch: Vec::new(),
            timing: None,
        })
        .expect_err("refused");
        let text = format!("{e:#}");
        assert!(
            text.contains("bad.csv") && text.contains("line 3"),
            "{text}"
        );
        assert!(!text.contains('\n'), "one line: {text}");
    }
}
