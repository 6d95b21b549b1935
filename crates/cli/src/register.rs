//! `trimctl register`: registers a CAM path onto a scan of the clamped part and writes the
//! registered path and the per-contour quality report.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use trim_geom::formats::{read_path, write_path};
use trim_geom::transform::similarity_from_matrix;
use trim_geom::{Point3, PointCloud, Similarity3, Vector3};
use trim_register::datum::datum_fit;
use trim_register::regional::{RegisterSettings, register};
use trim_register::sampling::View;

use crate::cad::load_cad;
use crate::config::JobConfig;
use crate::summary;

/// Arguments of `trimctl register`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The CAD: an STL or PLY mesh (sampled), or a point cloud with outward normals
    /// (PLY/PCD/XYZ), in the CAD frame, mm.
    #[arg(long)]
    pub cad: PathBuf,
    /// The scan of the clamped part (PLY/PCD/XYZ), scan frame, mm. Normals are not needed.
    /// Several, with --poses, merge into one cloud in the work-piece frame: a second machine
    /// pose shows the walls and end faces the first did not see.
    #[arg(long, required = true)]
    pub scan: Vec<PathBuf>,
    /// The machine pose of each scan: CSV `scan,x,y,z,a,c` (or `b`) as `calibrate cell` reads,
    /// `scan` the scan's file name. Each scan goes into the work-piece frame through the job's
    /// `[calibration]` and `[machine]` at its pose (the nominal cell without --config).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The template path CSV, CAD frame.
    #[arg(long)]
    pub path: PathBuf,
    /// Where to write the registered path CSV (scan frame).
    #[arg(long)]
    pub out: PathBuf,
    /// Where to write the quality report (JSON).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Where to write the registration's picture (SVG): the registered contours over the scan,
    /// coloured by their predicted error bound, the flagged ones red and dashed with their id,
    /// and the part's verdict. Not with --datums (a datum fit has no per-contour bounds).
    #[arg(long, value_name = "FILE", conflicts_with = "datums")]
    pub svg: Option<PathBuf>,
    /// A job.toml whose `[register]` table sets the registration and whose
    /// `[part.scan_from_cad]` is the fixture's nominal pose (unless --initial is given).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The scanner position in the scan frame, mm, as `x,y,z` (overrides the config).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub viewpoint: Option<Vec<f64>>,
    /// The fixture's nominal `scan_from_cad`: a text file of 16 numbers (row-major 4×4, a
    /// rotation, translation in mm). Default: the job's `[part.scan_from_cad]` with --config,
    /// else the identity (the CAM data is in the machine frame).
    #[arg(long)]
    pub initial: Option<PathBuf>,
    /// Datum-compliant positioning (thesis §3.5.2) instead of the regional registration: a text
    /// file of the part's datum points in the CAD frame (`x y z` or `x,y,z` per line, at least 3,
    /// normally 6). The path is moved rigidly by the datum fit; the report gives each datum's
    /// residual.
    #[arg(long, value_name = "FILE")]
    pub datums: Option<PathBuf>,
}

/// The job's `[register]` (defaults without a job file) with `--viewpoint x,y,z` applied,
/// validated.
pub(crate) fn register_settings(
    config: Option<&JobConfig>,
    viewpoint: Option<&[f64]>,
) -> anyhow::Result<RegisterSettings> {
    let mut settings = config.map_or_else(RegisterSettings::default, |c| c.register.clone());
    if let Some(v) = viewpoint {
        anyhow::ensure!(
            v.len() == 3,
            "--viewpoint: expected x,y,z, got {} numbers",
            v.len()
        );
        settings.scanner_viewpoint_mm = Some([v[0], v[1], v[2]]);
    }
    settings
        .validate()
        .map_err(|e| anyhow::anyhow!("register.{e}"))?;
    Ok(settings)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    crate::outputs::check(&[
        ("--out", Some(&args.out)),
        ("--report", args.report.as_deref()),
        ("--svg", args.svg.as_deref()),
    ])?;
    let config = args.config.as_deref().map(JobConfig::load).transpose()?;
    let settings = register_settings(config.as_ref(), args.viewpoint.as_deref())?;
    let initial = match (&args.initial, &config) {
        (Some(p), _) => read_matrix(p).with_context(|| format!("--initial {}", p.display()))?,
        (None, Some(c)) => c.part.scan_from_cad.scan_from_cad("part.scan_from_cad")?,
        (None, None) => Similarity3::identity(),
    };
    // The CAD (parsed and sampled) and the scans (parsed) are read side by side. With a job
    // file, one scan (scanner frame) goes into the work-piece frame through its [calibration]
    // and [part.scan_pose], as `trimctl run` does; several through their --poses.
    let (cad, scan) = std::thread::scope(|s| {
        let scan =
            s.spawn(|| crate::scans::merged(&args.scan, args.poses.as_deref(), config.as_ref()));
        let cad = load_cad(&args.cad, "--cad", settings.cad_sample_points)
            .with_context(|| format!("reading {}", args.cad.display()));
        let scan = scan
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("reading the scans: the reader panicked")));
        (cad, scan)
    });
    let (cad, scan) = (cad?, scan?);
    let path = read_path(&args.path).with_context(|| format!("reading {}", args.path.display()))?;
    let t_read = t0.elapsed().as_secs_f64();
    if let Some(datums_file) = &args.datums {
        return datum_positioning(&args, datums_file, &cad, &scan, &path, &initial, &settings);
    }
    let registration = register(&cad, &scan, &path, &initial, &settings)?;
    write_path(&args.out, &registration.path)
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(report) = &args.report {
        trim_geom::fs::write_atomic(report, serde_json::to_string_pretty(&registration.report)?)
            .with_context(|| format!("writing {}", report.display()))?;
    }
    if let Some(svg) = &args.svg {
        write_svg(svg, &registration, &scan, settings.quality.tolerance_um)?;
    }
    eprintln!("stage timings:");
    eprintln!("  {:<28} {:>8.3} s", "read inputs", t_read);
    for (name, s) in &registration.report.timings_s {
        eprintln!("  {name:<28} {s:>8.3} s");
    }
    print!("{}", summary::registration(&registration.report));
    if let Some(reason) = &registration.report.global.refused {
        anyhow::bail!(
            "the part is refused: {reason} (the registered path and the report were written)"
        );
    }
    Ok(())
}

/// Writes the registration's picture (`crate::registration_svg`) to `file`.
pub(crate) fn write_svg(
    file: &std::path::Path,
    registration: &trim_register::regional::Registration,
    scan: &PointCloud,
    tolerance_um: f64,
) -> anyhow::Result<()> {
    use crate::registration_svg::{part_view, render, views};
    let report = &registration.report;
    let svg = render(
        &views(&registration.path, report),
        &part_view(report, tolerance_um),
        scan.points(),
    );
    trim_geom::fs::write_atomic(file, svg).with_context(|| format!("writing {}", file.display()))
}

/// The six-point datum fit as the positioning mode: a rigid pose from the datums, applied to the
/// whole path.
fn datum_positioning(
    args: &Args,
    datums_file: &std::path::Path,
    cad: &PointCloud,
    scan: &PointCloud,
    path: &trim_geom::Path,
    initial: &Similarity3,
    settings: &RegisterSettings,
) -> anyhow::Result<()> {
    let datums = read_points_text(datums_file)?;
    let view = match settings.scanner_viewpoint_mm {
        Some(v) => View::From(Point3::from(v)),
        None => View::Along(Vector3::from(settings.view_direction)),
    };
    let t = Instant::now();
    let fit = datum_fit(cad, scan, &datums, initial, view, &settings.coarse)?;
    let fit_s = t.elapsed().as_secs_f64();
    let registered = path.transformed(&fit.scan_from_cad)?;
    write_path(&args.out, &registered)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let report = serde_json::json!({
        "mode": "datum",
        "scan_from_cad": fit.scan_from_cad.to_homogeneous().transpose().as_slice().chunks(4)
            .map(<[f64]>::to_vec).collect::<Vec<_>>(),
        "datums_in_scan": fit.datums_in_scan.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>(),
        "residuals_mm": fit.residuals_mm,
        "timings_s": [["datum fit", fit_s]],
    });
    if let Some(file) = &args.report {
        trim_geom::fs::write_atomic(file, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", file.display()))?;
    }
    eprintln!("stage timings:\n  {:<28} {fit_s:>8.3} s", "datum fit");
    let worst = fit.residuals_mm.iter().copied().fold(0.0, f64::max);
    println!(
        "datum fit: {} datums, residuals {} µm (worst {:.1} µm)",
        datums.len(),
        fit.residuals_mm
            .iter()
            .map(|r| format!("{:.1}", r * 1e3))
            .collect::<Vec<_>>()
            .join(", "),
        worst * 1e3
    );
    Ok(())
}

/// Points from a text file: `x y z` or `x,y,z` per line; `#` starts a comment.
pub(crate) fn read_points_text(path: &std::path::Path) -> anyhow::Result<Vec<Point3>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut points = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let values: Vec<f64> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .with_context(|| {
                        format!("{}:{}: `{s}` is not a finite number", path.display(), i + 1)
                    })
            })
            .collect::<anyhow::Result<_>>()?;
        anyhow::ensure!(
            values.len() == 3,
            "{}:{}: expected x y z, got {} numbers",
            path.display(),
            i + 1,
            values.len()
        );
        points.push(Point3::new(values[0], values[1], values[2]));
    }
    anyhow::ensure!(
        points.len() >= 3,
        "{}: a datum fit needs at least 3 datum points, got {}",
        path.display(),
        points.len()
    );
    Ok(points)
}

fn read_matrix(path: &std::path::Path) -> anyhow::Result<Similarity3> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let values: Vec<f64> = text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .with_context(|| format!("{}: `{s}` is not a finite number", path.display()))
        })
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(
        values.len() == 16,
        "{}: expected 16 numbers (a 4×4 matrix), got {}",
        path.display(),
        values.len()
    );
    similarity_from_matrix(&nalgebra::Matrix4::from_row_slice(&values)).with_context(|| {
        format!(
            "{}: not a pose matrix (rotation, uniform scale, translation)",
            path.display()
        )
    })
}
