//! `trimctl inspect --cad CAD --path PATH.csv --scan SCAN [--scan SCAN ...] [--poses poses.csv]
//! [--config job.toml] [--tolerance-um T] --out DIR`: the part scanned after trimming, fitted to
//! its CAD, every contour measured and judged (`trim_inspect`; DESIGN.md "Inspection").
//!
//! Writes `DIR/inspection.json`, `DIR/inspection.csv`, `DIR/deviation.png` and
//! `DIR/report.html`. Exit 1 when a contour fails (or on bad input), else 0; undecided contours
//! are listed but do not fail the command.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use trim_geom::formats::{Geometry, read_geometry, read_path};
use trim_geom::mesh::Mesh;
use trim_geom::{Path as TrimPath, Point3, PointCloud, Similarity3, Vector3};
use trim_inspect::inputs::{CadExtent, check_path_on_cad, check_scan_for_fit};
use trim_inspect::{InspectSettings, Inspection, Placement, Verdict, inspect, signed_distances};
use trim_register::datum::datum_fit;
use trim_register::regional::register;
use trim_register::sampling::View;

use crate::cad::CAD_SAMPLE_SEED;
use crate::config::JobConfig;
use crate::deviation_map::{DrawnContour, encode_map, verdict_colour};
use crate::exit::{Exit, Failure};
use crate::progress::stage;

/// The deviation map shows at most this many scan points (every k-th beyond).
const MAP_POINTS: usize = 300_000;

/// The map's colour scale spans ± this many tolerances.
const MAP_SCALE_TOLERANCES: f64 = 3.0;

/// Arguments of `trimctl inspect`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The CAD mesh (STL or PLY mesh), CAD frame, mm: distances are measured to its surface.
    #[arg(long)]
    pub cad: PathBuf,
    /// The template path CSV, CAD frame: the contours to judge.
    #[arg(long)]
    pub path: PathBuf,
    /// A scan of the trimmed part (PLY/PCD/XYZ). Several, with --poses, merge into one cloud.
    #[arg(long, required = true)]
    pub scan: Vec<PathBuf>,
    /// The machine pose of each scan: CSV `scan,x,y,z,a,c` (or `b`) as `calibrate cell` reads,
    /// `scan` the scan's file name. Each scan goes into the work-piece frame through the job's
    /// `[calibration]` at its pose.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// A job.toml: its `[register]` fits the scan, `[part.scan_from_cad]` is the fixture's
    /// nominal pose, `[calibration]` and `[machine]` carry the scans into the work-piece frame
    /// (one scan without --poses: at `[part.scan_pose]`, as `trimctl register` does).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The tolerance on excess and gouge, µm (default 30).
    #[arg(long)]
    pub tolerance_um: Option<f64>,
    /// Scan points within this distance of a contour are measured for it, mm (default 0.5).
    #[arg(long)]
    pub band_mm: Option<f64>,
    /// The scan noise (standard deviation), µm; default: estimated from the scan.
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// The scanner position in the work-piece frame, mm, `x,y,z` (overrides the config).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub viewpoint: Option<Vec<f64>>,
    /// Fit by the six-point datum fit (thesis §3.5.2) instead of the registration: a text file
    /// of datum points, CAD frame (`x y z` per line). The fit is rigid; each contour's bound is
    /// twice the worst datum residual.
    #[arg(long, value_name = "FILE")]
    pub datums: Option<PathBuf>,
    /// The output folder (created).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let config = args.config.as_deref().map(JobConfig::load).transpose()?;
    let reg_settings =
        crate::register::register_settings(config.as_ref(), args.viewpoint.as_deref())?;
    let mut settings = InspectSettings::default();
    if let Some(t) = args.tolerance_um {
        settings.tolerance_um = t;
    }
    if let Some(b) = args.band_mm {
        settings.band_mm = b;
    }
    settings.noise_um = args.noise_um;
    settings.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
    let initial = match &config {
        Some(c) => c.part.scan_from_cad.scan_from_cad("part.scan_from_cad")?,
        None => Similarity3::identity(),
    };

    let spinner = stage("reading the CAD, the path and the scans");
    let mesh = match read_geometry(&args.cad)
        .with_context(|| format!("reading {}", args.cad.display()))?
    {
        Geometry::Mesh(m) => m,
        _ => bail!(
            "{}: --cad must be a mesh (STL or PLY faces): inspection measures distances to the CAD's surface",
            args.cad.display()
        ),
    };
    let cad_points = mesh.sample_area_weighted(reg_settings.cad_sample_points, CAD_SAMPLE_SEED);
    let path = read_path(&args.path).with_context(|| format!("reading {}", args.path.display()))?;
    let scan = crate::scans::merged(&args.scan, args.poses.as_deref(), config.as_ref())?;
    drop(spinner);
    // Before the fit, which sizes its own structures by the path and reports a sparse scan in
    // its own terms.
    check_path_on_cad(mesh.vertices(), &path)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.path.display()))?;
    let scans = args
        .scan
        .iter()
        .map(|f| f.display().to_string())
        .collect::<Vec<_>>()
        .join(" + ");
    if args.datums.is_none() {
        check_scan_for_fit(&scans, scan.len(), reg_settings.coarse.min_voxel_points)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }

    let spinner = stage("fitting the scan to the CAD");
    let placement = match &args.datums {
        Some(file) => {
            let datums = crate::register::read_points_text(file)?;
            let view = match reg_settings.scanner_viewpoint_mm {
                Some(v) => View::From(Point3::from(v)),
                None => View::Along(Vector3::from(reg_settings.view_direction)),
            };
            let fit = datum_fit(
                &cad_points,
                &scan,
                &datums,
                &initial,
                view,
                &reg_settings.coarse,
            )?;
            let worst_um = fit.residuals_mm.iter().copied().fold(0.0, f64::max) * 1e3;
            Placement::rigid(fit.scan_from_cad, 2.0 * worst_um)
        }
        None => Placement::from_registration(
            &register(&cad_points, &scan, &path, &initial, &reg_settings).with_context(|| {
                format!(
                    "fitting {scans} ({} points) to {}",
                    scan.len(),
                    args.cad.display()
                )
            })?,
        ),
    };
    drop(spinner);

    let spinner = stage("measuring the contours");
    let result = inspect(&mesh, &path, scan.points(), &placement, &settings)?;
    drop(spinner);

    write_inspection(
        &args.out, &mesh, &path, &scan, &placement, &settings, &result,
    )?;

    let count = |v: Verdict| result.contours.iter().filter(|c| c.verdict == v).count();
    let (pass, fail, undecided) = (
        count(Verdict::Pass),
        count(Verdict::Fail),
        count(Verdict::Undecided),
    );
    for c in result
        .contours
        .iter()
        .filter(|c| c.verdict != Verdict::Pass)
    {
        println!(
            "contour {:>5}  {:<9}  {}",
            c.id,
            c.verdict.as_str(),
            c.reason
        );
    }
    println!(
        "{} contours: {pass} pass, {fail} fail, {undecided} undecided (tolerance {} µm, noise {:.1} µm, {} points measured, {:.2} s); wrote {}",
        result.contours.len(),
        result.tolerance_um,
        result.noise_um,
        result.points_measured,
        t0.elapsed().as_secs_f64(),
        args.out.display()
    );
    if fail > 0 {
        return Err(Failure::with_exit(
            Exit::Refused,
            anyhow::anyhow!(
                "{fail} contour(s) fail inspection (see {})",
                args.out.join("report.html").display()
            ),
        ));
    }
    Ok(())
}

/// Writes an inspection's outputs into `dir`: deviation.png (the scan's signed distance to
/// the CAD, the contours by verdict), inspection.json, inspection.csv and report.html, whole or
/// not at all ([`write_all_or_none`]). The map shows the scan points near the part (within
/// [`CadExtent::near`] of the CAD's box once fitted): a far outlier has no distance worth
/// drawing and would shrink the part to a dot.
pub(crate) fn write_inspection(
    dir: &Path,
    mesh: &Mesh,
    path: &TrimPath,
    scan: &PointCloud,
    placement: &Placement,
    settings: &InspectSettings,
    result: &Inspection,
) -> anyhow::Result<()> {
    let spinner = stage("drawing the deviation map");
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let stride = scan.len().div_ceil(MAP_POINTS).max(1);
    let cad_from_scan = placement.scan_from_cad.inverse();
    let extent = CadExtent::new(mesh.vertices());
    let shown: Vec<Point3> = scan
        .points()
        .iter()
        .step_by(stride)
        .map(|q| placement.cad_from_scan_point(&cad_from_scan, q, settings.inverse_iterations))
        .filter(|p| extent.is_some_and(|e| e.near(p)))
        .collect();
    let distances = signed_distances(mesh, &shown)?;
    let drawn: Vec<DrawnContour<'_>> = path
        .contours()
        .iter()
        .zip(&result.contours)
        .map(|(c, r)| DrawnContour {
            points: c.points(),
            verdict: r.verdict,
        })
        .collect();
    let png = encode_map(
        &shown,
        &distances,
        &drawn,
        MAP_SCALE_TOLERANCES * settings.tolerance_um,
    )?;
    drop(spinner);
    write_outputs(dir, result, Some(png))
}

/// The contour fields of inspection.json and inspection.csv, in order. The film's two come
/// last: a film over an opening seen from both sides (`ContourInspection::film`), null (an
/// empty CSV cell) where none is measured.
const FIELDS: [&str; 11] = [
    "id",
    "verdict",
    "excess_height_um",
    "excess_length_mm",
    "gouge_depth_um",
    "blocked_fraction",
    "uncertainty_um",
    "coverage",
    "reason",
    "film_thickness_um",
    "film_uncertainty_um",
];

/// Writes inspection.json, inspection.csv, report.html and (when given) deviation.png's
/// `png` into `dir` as one set, whole or not at all ([`write_all_or_none`]).
fn write_outputs(dir: &Path, result: &Inspection, png: Option<Vec<u8>>) -> anyhow::Result<()> {
    let round = |v: f64, digits: i32| {
        let f = 10f64.powi(digits);
        (v * f).round() / f
    };
    let contours: Vec<serde_json::Value> = result
        .contours
        .iter()
        .map(|c| {
            serde_json::json!({
                "id": c.id,
                "verdict": c.verdict.as_str(),
                "excess_height_um": round(c.excess_height_um, 2),
                "excess_length_mm": round(c.excess_length_mm, 3),
                "gouge_depth_um": round(c.gouge_depth_um, 2),
                "blocked_fraction": c.blocked_fraction.map(|b| round(b, 4)),
                "uncertainty_um": round(c.uncertainty_um, 2),
                "coverage": round(c.coverage, 4),
                "reason": c.reason,
                "film_thickness_um": c.film.map(|f| round(f.thickness_um, 2)),
                "film_uncertainty_um": c.film.map(|f| round(f.uncertainty_um, 2)),
            })
        })
        .collect();
    let json = serde_json::json!({
        "tolerance_um": result.tolerance_um,
        "noise_um": round(result.noise_um, 2),
        "contours": contours,
    });
    let mut files: Vec<(&str, Vec<u8>)> = Vec::new();
    if let Some(png) = png {
        files.push(("deviation.png", png));
    }
    files.push(("inspection.json", serde_json::to_vec_pretty(&json)?));

    let mut csv = FIELDS.join(",");
    csv.push('\n');
    for c in &contours {
        let row: Vec<String> = FIELDS
            .iter()
            .map(|k| match &c[k] {
                serde_json::Value::Null => String::new(),
                serde_json::Value::String(s) => format!("\"{}\"", s.replace('"', "\"\"")),
                v => v.to_string(),
            })
            .collect();
        csv.push_str(&row.join(","));
        csv.push('\n');
    }
    files.push(("inspection.csv", csv.into_bytes()));
    files.push(("report.html", report_html(result, &contours).into_bytes()));
    write_all_or_none(dir, &files)
}

/// Writes `files` (name, contents) into `dir` as one set, whole or not at all: each goes first
/// to a staging name beside its place (`trim_geom::fs::write_atomic`: flushed to the disk), and
/// only when every one is written are they renamed into place (renames in one folder need no
/// space). A failed write (a full disk) removes the staged files and leaves the old outputs as
/// they were: before, a cut deviation.png stood beside a report of the new inspection, or new
/// JSON beside an old report.
fn write_all_or_none(dir: &Path, files: &[(&str, Vec<u8>)]) -> anyhow::Result<()> {
    let staged: Vec<PathBuf> = files
        .iter()
        .map(|(name, _)| dir.join(format!(".{name}.{}.staged", std::process::id())))
        .collect();
    let remove_staged = || {
        for s in &staged {
            let _ = std::fs::remove_file(s);
        }
    };
    for ((name, contents), s) in files.iter().zip(&staged) {
        if let Err(e) = trim_geom::fs::write_atomic(s, contents) {
            remove_staged();
            return Err(e).with_context(|| format!("cannot write {}", dir.join(name).display()));
        }
    }
    for ((name, _), s) in files.iter().zip(&staged) {
        let file = dir.join(name);
        if let Err(e) = std::fs::rename(s, &file) {
            remove_staged();
            return Err(e).with_context(|| format!("cannot write {}", file.display()));
        }
    }
    Ok(())
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A self-contained page: the map (deviation.png beside it) and the table.
fn report_html(result: &Inspection, contours: &[serde_json::Value]) -> String {
    let count = |v: Verdict| result.contours.iter().filter(|c| c.verdict == v).count();
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>trimctl inspection</title>\n\
         <style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #bbb;padding:2px 8px;text-align:right}}td.reason{{text-align:left}}\
         img{{max-width:100%;border:1px solid #888}}</style></head><body>\n\
         <h1>Inspection</h1>\n<p>Tolerance {} µm, scan noise {:.1} µm: {} pass, {} fail, {} undecided \
         (ISO 14253-1: pass when deviation + U ≤ tolerance, fail when deviation − U &gt; tolerance). \
         A film over an opening seen from both sides shows its thickness ± its standard \
         uncertainty u (k = 1).</p>\n\
         <figure><img id=\"deviation\" src=\"deviation.png\" alt=\"scan-to-CAD deviation map\">\
         <figcaption>Scan-to-CAD signed distance, top view (red outside the material, blue inside, \
         ±{:.0} µm); contours green pass, red fail, orange undecided.</figcaption></figure>\n\
         <table id=\"contours\"><thead><tr>",
        result.tolerance_um,
        result.noise_um,
        count(Verdict::Pass),
        count(Verdict::Fail),
        count(Verdict::Undecided),
        MAP_SCALE_TOLERANCES * result.tolerance_um
    );
    // The film's thickness and its uncertainty share one column, "thickness ± u".
    let columns = FIELDS.iter().filter(|f| **f != "film_uncertainty_um");
    for f in columns.clone() {
        let header = match *f {
            "film_thickness_um" => "film_thickness_um ± u",
            f => f,
        };
        let _ = write!(html, "<th>{header}</th>");
    }
    html.push_str("</tr></thead><tbody>\n");
    for (c, r) in contours.iter().zip(&result.contours) {
        let [red, green, blue] = verdict_colour(r.verdict);
        html.push_str("<tr>");
        for &f in columns.clone() {
            let text = match (f, &c[f]) {
                (_, serde_json::Value::Null) => "—".to_string(),
                (_, serde_json::Value::String(s)) => s.clone(),
                ("film_thickness_um", v) => format!("{v} ± {}", c["film_uncertainty_um"]),
                (_, v) => v.to_string(),
            };
            let style = match f {
                "verdict" => format!(" style=\"color:rgb({red},{green},{blue});font-weight:bold\""),
                "reason" => " class=\"reason\"".to_string(),
                _ => String::new(),
            };
            let _ = write!(html, "<td{style}>{}</td>", escape(&text));
        }
        html.push_str("</tr>\n");
    }
    html.push_str("</tbody></table>\n</body></html>\n");
    html
}

#[cfg(test)]
mod tests {
    use trim_inspect::ContourInspection;
    use trim_inspect::opening::FilmThickness;

    use super::*;

    fn contour(id: i64, film: Option<FilmThickness>) -> ContourInspection {
        ContourInspection {
            id,
            verdict: Verdict::Fail,
            excess_height_um: 0.0,
            excess_length_mm: 0.0,
            gouge_depth_um: 0.0,
            blocked_fraction: Some(0.8),
            film,
            uncertainty_um: 24.0,
            coverage: 1.0,
            reason: "blocked".to_string(),
            bound_um: 12.0,
            length_mm: 8.0,
            points: 500,
            excess_bins: Vec::new(),
            gouge_bins: Vec::new(),
        }
    }

    /// A film measured from both sides is written as its thickness and standard uncertainty
    /// (JSON numbers, the CSV's last two columns, one "t ± u" cell in the report); a contour
    /// without one as null, empty cells and a dash.
    #[test]
    fn the_film_is_written_where_it_is_measured_and_null_elsewhere() {
        let film = FilmThickness {
            thickness_um: 123.456,
            uncertainty_um: 3.217,
            upper_readings: 400,
            underside_readings: 300,
        };
        let result = Inspection {
            tolerance_um: 30.0,
            noise_um: 10.0,
            contours: vec![contour(4, Some(film)), contour(9, None)],
            points_measured: 1000,
            timings_s: Vec::new(),
        };
        let dir = tempfile::tempdir().unwrap();
        write_outputs(dir.path(), &result, None).unwrap();

        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("inspection.json")).unwrap(),
        )
        .unwrap();
        let contours = json["contours"].as_array().unwrap();
        assert_eq!(contours[0]["film_thickness_um"].as_f64(), Some(123.46));
        assert_eq!(contours[0]["film_uncertainty_um"].as_f64(), Some(3.22));
        assert!(contours[1]["film_thickness_um"].is_null());
        assert!(contours[1]["film_uncertainty_um"].is_null());
        for c in contours {
            let mut keys: Vec<&str> = c.as_object().unwrap().keys().map(String::as_str).collect();
            keys.sort_unstable();
            let mut want = FIELDS.to_vec();
            want.sort_unstable();
            assert_eq!(keys, want);
        }

        let csv = std::fs::read_to_string(dir.path().join("inspection.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert!(
            lines[0].ends_with(",reason,film_thickness_um,film_uncertainty_um"),
            "{}",
            lines[0]
        );
        assert!(
            lines[1].ends_with(",\"blocked\",123.46,3.22"),
            "{}",
            lines[1]
        );
        assert!(lines[2].ends_with(",\"blocked\",,"), "{}", lines[2]);

        let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
        assert!(html.contains("<th>film_thickness_um ± u</th>"), "{html}");
        assert!(!html.contains("<th>film_uncertainty_um</th>"), "{html}");
        assert!(html.contains("<td>123.46 ± 3.22</td>"), "{html}");
        // Both rows have as many cells as the header has columns.
        let headers = html.matches("<th>").count();
        for row in html.split("<tr>").skip(2) {
            assert_eq!(row.matches("<td").count(), headers, "{row}");
        }
    }
}
