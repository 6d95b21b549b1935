//! `trimctl register`: registers a CAM path onto a scan of the clamped part and writes the
//! registered path and the per-contour quality report.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use trim_geom::formats::{Geometry, read_geometry, read_path, read_points, write_path};
use trim_geom::normals::{Orientation, estimate_normals};
use trim_geom::transform::similarity_from_matrix;
use trim_geom::{PointCloud, Similarity3, Vector3};
use trim_register::regional::{RegisterSettings, register};

use crate::config::JobConfig;
use crate::summary;

/// Neighbours for estimating the normals of a CAD point cloud given without them.
const CAD_NORMAL_NEIGHBOURS: usize = 12;

/// Arguments of `trimctl register`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The CAD: an STL or PLY mesh (sampled), or a point cloud (PLY/PCD/XYZ; normals estimated
    /// if absent), in the CAD frame, mm.
    #[arg(long)]
    pub cad: PathBuf,
    /// The scan of the clamped part (PLY/PCD/XYZ), scan frame, mm. Normals are not needed.
    #[arg(long)]
    pub scan: PathBuf,
    /// The template path CSV, CAD frame.
    #[arg(long)]
    pub path: PathBuf,
    /// Where to write the registered path CSV (scan frame).
    #[arg(long)]
    pub out: PathBuf,
    /// Where to write the quality report (JSON).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// A job.toml whose `[register]` table sets the registration.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The scanner position in the scan frame, mm, as `x,y,z` (overrides the config).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub viewpoint: Option<Vec<f64>>,
    /// The fixture's nominal `scan_from_cad`: a text file of 16 numbers (row-major 4×4).
    /// Default: the identity (the CAM data is in the machine frame).
    #[arg(long)]
    pub initial: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let mut settings = match &args.config {
        Some(p) => JobConfig::load(p)?.register,
        None => RegisterSettings::default(),
    };
    if let Some(v) = &args.viewpoint {
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
    let initial = match &args.initial {
        Some(p) => read_matrix(p)?,
        None => Similarity3::identity(),
    };
    let cad = match read_geometry(&args.cad)
        .with_context(|| format!("reading {}", args.cad.display()))?
    {
        Geometry::Mesh(mesh) => mesh.sample_area_weighted(settings.cad_sample_points, 1),
        Geometry::Points(cloud) if cloud.has_normals() => cloud,
        Geometry::Points(cloud) => {
            // Orientation from the cloud's centroid outward: right for closed, convex-ish parts;
            // point-to-plane residuals do not depend on the sign, visibility culling does.
            let centre = cloud.bounds().map(|b| b.center()).unwrap_or_default();
            let normals = estimate_normals(
                cloud.points(),
                CAD_NORMAL_NEIGHBOURS,
                Orientation::AlongReference(Vector3::z()),
            )?;
            let oriented = cloud
                .points()
                .iter()
                .zip(normals)
                .map(|(p, n)| if n.dot(&(p - centre)) < 0.0 { -n } else { n })
                .collect();
            PointCloud::with_normals(cloud.points().to_vec(), oriented)?
        }
        Geometry::Path(_) => anyhow::bail!("{}: is a path, not a CAD model", args.cad.display()),
    };
    let scan =
        read_points(&args.scan).with_context(|| format!("reading {}", args.scan.display()))?;
    let path = read_path(&args.path).with_context(|| format!("reading {}", args.path.display()))?;
    let t_read = t0.elapsed().as_secs_f64();
    let registration = register(&cad, &scan, &path, &initial, &settings)?;
    write_path(&args.out, &registration.path)
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(report) = &args.report {
        std::fs::write(report, serde_json::to_string_pretty(&registration.report)?)
            .with_context(|| format!("writing {}", report.display()))?;
    }
    eprintln!("stage timings:");
    eprintln!("  {:<28} {:>8.3} s", "read inputs", t_read);
    for (name, s) in &registration.report.timings_s {
        eprintln!("  {name:<28} {s:>8.3} s");
    }
    print!("{}", summary::registration(&registration.report));
    Ok(())
}

fn read_matrix(path: &std::path::Path) -> anyhow::Result<Similarity3> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let values: Vec<f64> = text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>()
                .with_context(|| format!("{}: `{s}` is not a number", path.display()))
        })
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(
        values.len() == 16,
        "{}: expected 16 numbers (a 4×4 matrix), got {}",
        path.display(),
        values.len()
    );
    Ok(similarity_from_matrix(&nalgebra::Matrix4::from_row_slice(
        &values,
    ))?)
}
