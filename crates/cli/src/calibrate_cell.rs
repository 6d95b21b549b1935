//! `trimctl calibrate cell --scans DIR --poses poses.csv --sphere-diameter-mm D --tool-mark X,Y,Z --out cal.toml`:
//! the rotary axis lines and the scanner's pose on the head (`trim_calib::cell_calibration`).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, bail};
use trim_calib::artefact::{CalPose, fit_observations};
use trim_calib::cell_calibration::calibrate_cell;
use trim_cell::cell_model::{Calibration, TableModel};
use trim_cell::kinematics::MachineSettings;
use trim_cell::scans_at_poses::read_poses;
use trim_geom::Point3;

use crate::config::JobConfig;
use crate::progress::stage;

/// Arguments of `trimctl calibrate cell`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The folder holding the sphere scans (PLY, PCD or XYZ, scanner frame) named in poses.csv.
    #[arg(long)]
    pub scans: PathBuf,
    /// CSV with the header `scan,x,y,z,a,c` (file name in --scans; X, Y, Z joint positions in
    /// mm; degrees). A B/C cell writes `b` for `a`.
    #[arg(long)]
    pub poses: PathBuf,
    /// The precision sphere's diameter (mm).
    #[arg(long)]
    pub sphere_diameter_mm: f64,
    /// The centre of a laser mark made at the field centre at the first pose, as the scanner
    /// saw it there (scanner frame, mm): X,Y,Z.
    #[arg(
        long,
        required = true,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true
    )]
    pub tool_mark: Vec<f64>,
    /// Where to write the `[calibration]` table (TOML; paste it into job.toml).
    #[arg(long)]
    pub out: PathBuf,
    /// The job file whose `[machine]` gives the nominal cell (default: the defaults).
    #[arg(long, value_name = "JOB.toml")]
    pub job: Option<PathBuf>,
}

/// A pose residual RMS over this (µm) is warned of, on stderr and in the table's header.
const WARN_RMS_UM: f64 = 10.0;

/// The largest `--sphere-diameter-mm`: a calibration sphere on a machine table.
const MAX_SPHERE_DIAMETER_MM: f64 = 500.0;

/// The farthest a `--tool-mark` coordinate may be from the scanner (mm): it is in its view.
const MAX_TOOL_MARK_MM: f64 = 5_000.0;

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.tool_mark.len() != 3 {
        bail!(
            "--tool-mark: expected X,Y,Z (three numbers), got {}",
            args.tool_mark.len()
        );
    }
    // A NaN or infinite mark was written into the calibration as `scanner_translation_mm =
    // [nan, …]` with exit 0.
    for (axis, v) in ["X", "Y", "Z"].into_iter().zip(&args.tool_mark) {
        if !v.is_finite() {
            bail!("--tool-mark: {axis} = {v}: every coordinate must be a finite number (mm)");
        }
        if v.abs() > MAX_TOOL_MARK_MM {
            bail!(
                "--tool-mark: {axis} = {} mm: the mark is seen by the scanner, so within ±{MAX_TOOL_MARK_MM} mm of it",
                trim_geom::Num(*v)
            );
        }
    }
    if !(args.sphere_diameter_mm.is_finite()
        && args.sphere_diameter_mm > 0.0
        && args.sphere_diameter_mm <= MAX_SPHERE_DIAMETER_MM)
    {
        bail!(
            "--sphere-diameter-mm: must be within (0, {MAX_SPHERE_DIAMETER_MM}] mm, got {}",
            trim_geom::Num(args.sphere_diameter_mm)
        );
    }
    let tool_mark = Point3::new(args.tool_mark[0], args.tool_mark[1], args.tool_mark[2]);
    let pose_rows = read_poses(&args.poses)?;
    let machine = match &args.job {
        Some(j) => JobConfig::load(j)?.plan.machine,
        None => MachineSettings::default(),
    };
    pose_rows.require_kinematics(machine.kinematics)?;
    if args.job.is_some() {
        // The job names the machine, so its limits hold; the nominal cell's need not.
        pose_rows.require_within(&machine)?;
    }
    let kind = pose_rows.kinematics;
    let (names, poses): (Vec<String>, Vec<CalPose>) =
        pose_rows.rows.into_iter().map(|r| (r.scan, r.pose)).unzip();
    let spinner = stage("reading the sphere scans");
    let scans = names
        .iter()
        .map(|n| {
            trim_geom::formats::read_points(&args.scans.join(n))
                .with_context(|| format!("{} (named in {})", n, args.poses.display()))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    drop(spinner);
    let spinner = stage("fitting the spheres");
    let observations = fit_observations(&poses, &scans, args.sphere_diameter_mm)
        .map_err(|(i, e)| anyhow::anyhow!("{}: {e}", args.scans.join(&names[i]).display()))?;
    drop(spinner);
    let nominal = TableModel::nominal(&machine);
    let cal = calibrate_cell(&nominal, &observations, &tool_mark).context("solving the cell")?;
    let r = &cal.report;
    let tilt = kind.tilt_axis().unwrap_or("a").to_uppercase();
    // A residual this large misplaces spots by as much: a third of the 30 µm trimming
    // tolerance. A 25.5 mm diameter given for the twin's 25.4 mm sphere gives 12 µm (σ̂/σ 14).
    let warning = (r.rms_um > WARN_RMS_UM).then(|| {
        format!(
            "the poses disagree with the cell model by an RMS of {:.1} µm (σ̂/σ {:.1}; over \
             {WARN_RMS_UM} µm): spots will be misplaced by about as much; check the sphere's \
             diameter, the poses file and that the sphere did not move",
            r.rms_um, r.sigma_ratio
        )
    });
    if let Some(w) = &warning {
        tracing::warn!("{w}");
    }

    let mut calibration = Calibration::default();
    calibration.set_cell(&cal.table, &cal.scanner);
    #[derive(serde::Serialize)]
    struct Out<'a> {
        calibration: &'a Calibration,
    }
    let mut text = String::new();
    let _ = writeln!(
        text,
        "# trimctl calibrate cell: {} poses from {}, sphere Ø {} mm.",
        poses.len(),
        args.poses.display(),
        args.sphere_diameter_mm
    );
    let _ = writeln!(
        text,
        "# Pose residuals (µm): RMS {:.2}, max {:.2}; tool mark {:.2}. Standard deviations: {tilt} direction {:.5}°, {tilt} point {:.2} µm, C direction {:.5}°, C point {:.2} µm, scanner rotation {:.5}°, scanner translation {:.2} µm.",
        r.rms_um,
        r.pose_residual_um.iter().copied().fold(0.0, f64::max),
        r.tool_mark_residual_um,
        r.tilt_direction_sd_deg,
        r.tilt_point_sd_um,
        r.c_direction_sd_deg,
        r.c_point_sd_um,
        r.scanner_rotation_sd_deg,
        r.scanner_translation_sd_um
    );
    if let Some(w) = &warning {
        let _ = writeln!(text, "# WARNING: {w}.");
    }
    let _ = writeln!(
        text,
        "# Paste the table below into job.toml; add `field_correction = \"field.json\"` from `trimctl calibrate field`.\n"
    );
    text.push_str(
        &toml::to_string(&Out {
            calibration: &calibration,
        })
        .context("serialising the calibration")?,
    );
    trim_geom::fs::write_atomic(&args.out, text)
        .with_context(|| format!("cannot write {}", args.out.display()))?;

    println!("pose  scan                  {tilt:>8}°  C°        residual µm");
    for (i, ((n, p), res)) in names
        .iter()
        .zip(&poses)
        .zip(&r.pose_residual_um)
        .enumerate()
    {
        println!(
            "{i:>4}  {n:<20}  {:>8.2}  {:>8.2}  {res:>8.2}",
            p.tilt_deg, p.c_deg
        );
    }
    let line = |name: &str, l: &trim_cell::cell_model::AxisLine| {
        println!(
            "{name} line: point ({:.4}, {:.4}, {:.4}) mm, direction ({:.7}, {:.7}, {:.7})",
            l.point_mm.x, l.point_mm.y, l.point_mm.z, l.direction.x, l.direction.y, l.direction.z
        );
    };
    line(&tilt, &cal.table.tilt);
    line("C", &cal.table.rotary);
    let t = cal.scanner.translation_mm;
    println!(
        "scanner: rotation {:.5}° from the identity, translation ({:.4}, {:.4}, {:.4}) mm",
        trim_calib::cell_calibration::rotation_error_deg(
            &cal.scanner.rotation,
            &nalgebra::Matrix3::identity()
        ),
        t.x,
        t.y,
        t.z
    );
    println!(
        "residual RMS {:.2} µm over {} poses (σ̂/σ {:.2}); σ: {tilt} {:.5}° / {:.2} µm, C {:.5}° / {:.2} µm, scanner {:.5}° / {:.2} µm",
        r.rms_um,
        poses.len(),
        r.sigma_ratio,
        r.tilt_direction_sd_deg,
        r.tilt_point_sd_um,
        r.c_direction_sd_deg,
        r.c_point_sd_um,
        r.scanner_rotation_sd_deg,
        r.scanner_translation_sd_um
    );
    println!("wrote {}", args.out.display());
    Ok(())
}
