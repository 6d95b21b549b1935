//! `trimctl hatch --scan SCAN --boundary B.csv --pitch MM [--angle DEG] [--method geodesic|slab]
//! --out tracks.csv [--svg tracks.svg]`: equal-spacing hatch tracks on a scanned surface
//! (`trim_plan::hatch`).
//!
//! `B.csv` is a path CSV holding one closed contour on the surface: a polygon, whose last row
//! may repeat the first or not (the closing edge is implied; `hatch::close_boundary`).
//! `tracks.csv` is a path CSV: `contour` = track id in execution order (serpentine; the outline,
//! if any, last), `x y z` in the scan's frame (mm), `u v w` the unit surface normal.
//! Stdout: the number of tracks, the neighbour spacing across the surface (mean, CV, min, max),
//! coverage (scan points inside the boundary within pitch/2 × 1.05 of a track), the boundary
//! error and the planning time. Bad input exits 1 with a message naming the file.

use std::path::{Path as FsPath, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use trim_geom::formats::{read_path, read_points, write_path};
use trim_plan::hatch::{
    Hatch, HatchMethod, HatchReport, HatchSettings, HatchStage, TrackKind, hatch,
    hatch_with_progress, measure,
};

/// Arguments of `trimctl hatch`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The surface scan: .ply, .pcd or .xyz (normals optional; estimated from the surface fit).
    #[arg(long)]
    pub scan: PathBuf,
    /// Path CSV with one closed contour lying on the surface: the region to hatch.
    #[arg(long)]
    pub boundary: PathBuf,
    /// Track pitch (neighbour spacing across the surface), mm.
    #[arg(long)]
    pub pitch: f64,
    /// Hatch direction, degrees from scan X projected onto the patch's best-fit plane.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub angle: f64,
    /// Planning method: geodesic (default) or slab (the cladding paper's method).
    #[arg(long, default_value = "geodesic")]
    pub method: HatchMethod,
    /// Point step along tracks (the pulse pitch), mm; default: the track pitch.
    #[arg(long, conflicts_with = "chord_tolerance")]
    pub step: Option<f64>,
    /// Place points by this chord tolerance instead of a step (vector marking), mm.
    #[arg(long)]
    pub chord_tolerance: Option<f64>,
    /// Leave out the outline track along the boundary.
    #[arg(long)]
    pub no_outline: bool,
    /// Output path CSV of the tracks.
    #[arg(long)]
    pub out: PathBuf,
    /// Optional SVG: the tracks over the surface, coloured by local spacing error.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

/// A spinner with the current stage on a terminal; nothing otherwise.
fn spinner() -> Option<ProgressBar> {
    std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let s = ProgressBar::new_spinner();
        s.set_style(
            ProgressStyle::with_template("{spinner} hatch: {msg} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        s.enable_steady_tick(std::time::Duration::from_millis(100));
        s
    })
}

/// Reads the boundary: exactly one contour, closed.
fn read_boundary(file: &FsPath) -> anyhow::Result<Vec<trim_geom::Point3>> {
    let path = read_path(file)?;
    if path.len() != 1 {
        bail!(
            "{}: a boundary file holds exactly one closed contour, found {} contours",
            file.display(),
            path.len()
        );
    }
    let contour = &path.contours()[0];
    let points = contour.points().to_vec();
    trim_plan::hatch::check_boundary(&points)
        .with_context(|| format!("{}: contour {}", file.display(), contour.id()))?;
    Ok(points)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let cloud = read_points(&args.scan)?;
    let boundary = read_boundary(&args.boundary)?;
    let settings = HatchSettings {
        pitch_mm: args.pitch,
        angle_deg: args.angle,
        method: args.method,
        step_mm: args.step,
        chord_tolerance_mm: args.chord_tolerance,
        outline: !args.no_outline,
        ..HatchSettings::default()
    };
    let bar = spinner();
    let start = Instant::now();
    let planned = hatch_with_progress(&cloud, &boundary, &settings, &mut |stage| {
        let msg = match stage {
            HatchStage::Fit => "fitting the surface",
            HatchStage::Tracks => "planning tracks",
            HatchStage::Sample => "placing points",
        };
        match &bar {
            Some(b) => b.set_message(msg),
            None => tracing::debug!("hatch: {msg}"),
        }
    });
    let elapsed = start.elapsed();
    let planned = planned.with_context(|| {
        format!(
            "hatching {} inside {}",
            args.scan.display(),
            args.boundary.display()
        )
    })?;
    if let Some(b) = &bar {
        b.set_message("measuring");
    }
    let report = measure(&planned);
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    write_path(&args.out, &planned.to_path()?)?;
    if let Some(svg) = &args.svg {
        trim_geom::fs::write_atomic(svg, render_svg(&planned, &report))
            .with_context(|| format!("{}: cannot write", svg.display()))?;
    }
    let s = report.spacing;
    println!(
        "tracks: {} ({} hatch{}), {} points",
        report.tracks,
        report.hatch_tracks,
        if report.tracks > report.hatch_tracks {
            " + outline"
        } else {
            ""
        },
        report.points
    );
    println!(
        "spacing: mean {:.4} mm (pitch {} mm, {:+.2} %), CV {:.2} %, min {:.4} mm, max {:.4} mm \
         ({} measured)",
        s.mean_mm,
        args.pitch,
        if args.pitch > 0.0 {
            100.0 * (s.mean_mm / args.pitch - 1.0)
        } else {
            0.0
        },
        100.0 * s.cv,
        s.min_mm,
        s.max_mm,
        s.count
    );
    println!(
        "coverage: {:.2} % of scan points inside the boundary within pitch/2 x 1.05 \
         (hatch only {:.2} %), largest gap {:.4} mm",
        100.0 * report.coverage,
        100.0 * report.coverage_hatch_only,
        report.max_gap_mm
    );
    println!(
        "boundary: largest excursion {:.4} mm",
        report.boundary_error_mm
    );
    println!(
        "time: {:.3} s ({} method)",
        elapsed.as_secs_f64(),
        planned.method
    );
    Ok(())
}

/// The SVG: scan points inside the boundary (grey), the boundary, and every track segment
/// coloured by its local spacing error (blue −5 % … green 0 … red +5 %; grey unmeasured), in
/// the patch's plane coordinates.
fn render_svg(h: &Hatch, report: &HatchReport) -> String {
    use std::fmt::Write as _;
    const SIZE_PX: f64 = 800.0;
    const MARGIN_PX: f64 = 20.0;
    const MAX_DOTS: usize = 20_000;
    const MIN_WIDTH_PX: f64 = 560.0;
    const CAPTION_PX: f64 = 40.0;
    let frame = h.frame();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for v in &h.boundary_plane {
        lo = [lo[0].min(v[0]), lo[1].min(v[1])];
        hi = [hi[0].max(v[0]), hi[1].max(v[1])];
    }
    // The longer side spans the picture; the other keeps the region's aspect ratio.
    let scale = (SIZE_PX - 2.0 * MARGIN_PX) / (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-9);
    let width_px = 2.0 * MARGIN_PX + (hi[0] - lo[0]) * scale;
    let plot_px = 2.0 * MARGIN_PX + (hi[1] - lo[1]) * scale;
    let px = |st: [f64; 2]| {
        (
            MARGIN_PX + (st[0] - lo[0]) * scale,
            plot_px - MARGIN_PX - (st[1] - lo[1]) * scale,
        )
    };
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0}" height="{h_px:.0}" viewBox="0 0 {w:.0} {h_px:.0}">"#,
        w = width_px.max(MIN_WIDTH_PX),
        h_px = plot_px + CAPTION_PX
    );
    let _ = writeln!(out, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let inside = h.surface.inside_points();
    let every = inside.len().div_ceil(MAX_DOTS).max(1);
    let _ = write!(out, r##"<g fill="#ccc">"##);
    for p in inside.iter().step_by(every) {
        let (x, y) = px(frame.to_plane(p));
        let _ = write!(out, r#"<circle cx="{x:.1}" cy="{y:.1}" r="0.6"/>"#);
    }
    let _ = writeln!(out, "</g>");
    let ring: Vec<String> = h
        .boundary_plane
        .iter()
        .map(|v| {
            let (x, y) = px(*v);
            format!("{x:.2},{y:.2}")
        })
        .collect();
    let _ = writeln!(
        out,
        r#"<polygon points="{}" fill="none" stroke="black" stroke-width="1"/>"#,
        ring.join(" ")
    );
    for (t, local) in h.tracks.iter().zip(&report.local_spacing_mm) {
        let outline = matches!(t.kind, TrackKind::Outline);
        for (i, w) in t.points.windows(2).enumerate() {
            let colour = if outline {
                "#555".to_string()
            } else {
                match local[i].or(local[i + 1]) {
                    Some(s) => error_colour(s / h.pitch_mm - 1.0),
                    None => "#999".to_string(),
                }
            };
            let (a, b) = (px(frame.to_plane(&w[0])), px(frame.to_plane(&w[1])));
            let _ = writeln!(
                out,
                r#"<line x1="{:.2}" y1="{:.2}" x2="{:.2}" y2="{:.2}" stroke="{colour}" stroke-width="0.8"/>"#,
                a.0, a.1, b.0, b.1
            );
        }
    }
    let s = report.spacing;
    let _ = writeln!(
        out,
        r#"<text x="{MARGIN_PX}" y="{:.0}" font-family="sans-serif" font-size="12">{} tracks, {} method, pitch {} mm: spacing mean {:.4} mm, CV {:.2} %, coverage {:.2} %<tspan x="{MARGIN_PX}" dy="15">local spacing error: blue −5 % … green 0 … red +5 %; outline grey</tspan></text>"#,
        plot_px + 12.0,
        report.tracks,
        h.method,
        h.pitch_mm,
        s.mean_mm,
        100.0 * s.cv,
        100.0 * report.coverage
    );
    out.push_str("</svg>\n");
    out
}

/// Blue (−5 %) → green (0) → red (+5 %), as an HSL hue.
fn error_colour(relative: f64) -> String {
    let t = (relative / 0.05).clamp(-1.0, 1.0);
    let hue = 120.0 - 120.0 * t; // +5 % → 0 (red), −5 % → 240 (blue)
    format!("hsl({hue:.0},80%,40%)")
}

pub use trim_plan::hatch::track_ids::{TRACKS_PER_REGION, track_id};

/// Refuses a path whose contour ids would collide with hatch tracks (negative ids).
pub fn check_path_ids(path: &trim_geom::Path, what: &FsPath) -> anyhow::Result<()> {
    if let Some(c) = path.contours().iter().find(|c| c.id() < 0) {
        bail!(
            "{}: contour {} has a negative id; hatch tracks take the negative ids, so give the path's contours ids ≥ 0",
            what.display(),
            c.id()
        );
    }
    Ok(())
}

/// Renumbers tracks (path CSV from `trimctl hatch`, or a fresh hatch) as region `region`'s.
pub fn as_region_tracks(
    tracks: &trim_geom::Path,
    region: usize,
) -> anyhow::Result<Vec<trim_geom::Contour>> {
    if tracks.len() as i64 >= TRACKS_PER_REGION {
        bail!(
            "{} tracks in one region: at most {}",
            tracks.len(),
            TRACKS_PER_REGION - 1
        );
    }
    tracks
        .contours()
        .iter()
        .enumerate()
        .map(|(t, c)| {
            trim_geom::Contour::with_features(
                track_id(region, t),
                c.points().to_vec(),
                c.features().to_vec(),
            )
            .map_err(anyhow::Error::from)
        })
        .collect()
}

/// One hatched region of a job.
pub struct RegionHatch {
    /// The region's tracks, ids from [`track_id`], work-piece frame.
    pub tracks: Vec<trim_geom::Contour>,
    /// One line for the operator: tracks, spacing, coverage, boundary, time.
    pub summary: String,
}

/// Hatches `[[hatch]]` regions on the registered scan: each boundary (CAD frame) is carried
/// onto the scan by `to_scan` (registration), hatched there, and written to
/// `out_dir/hatch_{r}.csv` and `.svg`.
pub fn hatch_regions(
    regions: &[crate::config::HatchRegion],
    scan: &trim_geom::PointCloud,
    to_scan: &dyn Fn(&trim_geom::Point3) -> trim_geom::Point3,
    out_dir: &FsPath,
) -> anyhow::Result<Vec<RegionHatch>> {
    let mut out = Vec::with_capacity(regions.len());
    for (r, region) in regions.iter().enumerate() {
        let file = &region.boundary;
        let boundary: Vec<trim_geom::Point3> = read_boundary(file)
            .with_context(|| format!("hatch[{r}]"))?
            .iter()
            .map(to_scan)
            .collect();
        let start = Instant::now();
        let planned = hatch(scan, &boundary, &region.settings).with_context(|| {
            format!(
                "hatch[{r}]: hatching inside {} on the registered scan",
                file.display()
            )
        })?;
        let elapsed = start.elapsed().as_secs_f64();
        let report = measure(&planned);
        let tracks = planned.to_path()?;
        let csv = out_dir.join(format!("hatch_{r}.csv"));
        write_path(&csv, &tracks)?;
        let svg = out_dir.join(format!("hatch_{r}.svg"));
        trim_geom::fs::write_atomic(&svg, render_svg(&planned, &report))
            .with_context(|| format!("{}: cannot write", svg.display()))?;
        let s = report.spacing;
        let summary = format!(
            "hatch[{r}] {}: {} tracks ({} method, pitch {} mm), spacing mean {:.4} mm CV {:.2} %, coverage {:.2} %, boundary ≤ {:.4} mm, {:.2} s → {}",
            file.display(),
            report.tracks,
            planned.method,
            planned.pitch_mm,
            s.mean_mm,
            100.0 * s.cv,
            100.0 * report.coverage,
            report.boundary_error_mm,
            elapsed,
            svg.display()
        );
        out.push(RegionHatch {
            tracks: as_region_tracks(&tracks, r)?,
            summary,
        });
    }
    Ok(out)
}
