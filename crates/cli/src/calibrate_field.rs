//! `trimctl calibrate field --marks marks.csv --out field.json`: the galvo field correction
//! (`trim_calib::field_correction`), optionally as the controller's 65 × 65 table
//! (`trim_cell::lens::CorrectionTable`, docs/protocols/correction-table.md) and as an SVG of the
//! residual vectors.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use trim_calib::field_correction::{FieldFitReport, FieldFitSettings, Mark, fit_field, read_marks};
use trim_cell::lens::{CorrectionTable, FieldCorrection, height_scale};

/// Arguments of `trimctl calibrate field`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// CSV with the header `x_cmd,y_cmd,h_mm,x_meas,y_meas` (mm, head frame; rows at h ≠ 0 from
    /// raised or lowered coupons). Measure relative to the field-centre mark.
    #[arg(long)]
    pub marks: PathBuf,
    /// Where to write the field correction (field.json); name it as
    /// `calibration.field_correction` in job.toml.
    #[arg(long)]
    pub out: PathBuf,
    /// The lens's focal length (mm): the nominal L (the "before" model, L when no row is off
    /// the focal plane) and the centre of L's search.
    #[arg(long, default_value_t = trim_cell::Beam::default().focal_length_mm)]
    pub focal_length_mm: f64,
    /// Also write the controller's 65 × 65 correction table: the BJJCZ/EzCad `.cor` integer
    /// layout when the name ends in `.cor`, a plain text table otherwise.
    #[arg(long)]
    pub table_out: Option<PathBuf>,
    /// The side of the field the table spans (mm); default: the marked range.
    #[arg(long, requires = "table_out")]
    pub table_field_mm: Option<f64>,
    /// An SVG of the residual vectors at each mark, before (nominal lens) and after the fit,
    /// each magnified to be seen.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// The penalty weight of the smooth part; default: chosen by leave-one-out.
    #[arg(long)]
    pub smoothing: Option<f64>,
}

/// The widest `--table-field-mm` (mm): no galvo field is a metre across.
const MAX_TABLE_FIELD_MM: f64 = 1000.0;

/// Refuses a numeric flag out of range before anything is read, naming the flag:
/// `--focal-length-mm` within the lens's physical range (`trim_cell::beam::FOCAL_LENGTH_RANGE_MM`;
/// 1e9 mm fitted and wrote `± inf`), `--smoothing` within (0, `MAX_SMOOTHING`], `--table-field-mm` a
/// finite number within (0, [`MAX_TABLE_FIELD_MM`]].
fn check_flags(args: &Args) -> anyhow::Result<()> {
    let (lo, hi) = trim_cell::beam::FOCAL_LENGTH_RANGE_MM;
    if !(args.focal_length_mm.is_finite() && (lo..=hi).contains(&args.focal_length_mm)) {
        anyhow::bail!(
            "--focal-length-mm: must be within [{lo}, {hi}] mm, got {}",
            trim_geom::Num(args.focal_length_mm)
        );
    }
    if let Some(w) = args.smoothing {
        trim_calib::field_correction::check_smoothing(w)
            .map_err(|m| anyhow::anyhow!("--smoothing: {m}"))?;
    }
    if let Some(f) = args.table_field_mm
        && !(f.is_finite() && f > 0.0 && f <= MAX_TABLE_FIELD_MM)
    {
        anyhow::bail!(
            "--table-field-mm: must be within (0, {MAX_TABLE_FIELD_MM}] mm, got {}",
            trim_geom::Num(f)
        );
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_flags(&args)?;
    let marks = read_marks(&args.marks)?;
    let settings = FieldFitSettings {
        focal_length_mm: args.focal_length_mm,
        smoothing: args.smoothing,
        ..FieldFitSettings::default()
    };
    let (field, r) = fit_field(&marks, &settings)
        .with_context(|| format!("fitting the field to {}", args.marks.display()))?;
    field.write(&args.out)?;
    println!(
        "{}: {} marks at {} commands ({} off the focal plane) over ±{:.1} mm",
        args.marks.display(),
        r.marks,
        r.commands,
        r.marks_off_plane,
        r.half_field_mm
    );
    println!(
        "residual before (nominal lens, no correction): RMS {:8.2} µm, max {:8.2} µm",
        r.rms_before_um, r.max_before_um
    );
    println!(
        "residual after:                                RMS {:8.2} µm, max {:8.2} µm",
        r.rms_after_um, r.max_after_um
    );
    println!(
        "leave-one-out (each command held out):         RMS {:8.2} µm, max {:8.2} µm",
        r.loo_rms_um, r.loo_max_um
    );
    println!(
        "offset ({:.4}, {:.4}) mm, rotation {:.4}°, scale {:.6}",
        r.offset_mm[0], r.offset_mm[1], r.rotation_deg, r.scale
    );
    match (r.pivot_to_focal_plane_mm, r.pivot_std_mm) {
        (Some(l), std) => println!(
            "pivot height L = {l:.2} ± {:.2} mm (fitted from the off-plane rows; nominal {:.2} mm)",
            std.unwrap_or(f64::NAN),
            args.focal_length_mm
        ),
        (None, _) => println!(
            "no off-plane rows: L is left to the job (calibration.lens.pivot_to_focal_plane_mm, \
             else the focal length {:.2} mm)",
            args.focal_length_mm
        ),
    }
    println!(
        "smooth part: penalty {:.1e} (order {}), {} × {} cells, {:.1} effective parameters per \
         axis",
        r.smoothing, r.penalty_order, r.cells, r.cells, r.effective_parameters
    );
    println!("wrote {}", args.out.display());
    if let Some(table_out) = &args.table_out {
        let side = args.table_field_mm.unwrap_or(2.0 * r.half_field_mm);
        let table = CorrectionTable::from_field(&field, side)
            .with_context(|| format!("building the table for {}", table_out.display()))?;
        table.write(table_out)?;
        println!(
            "wrote {} (65 × 65 nodes over {side:.2} mm, {:.3} bits/mm)",
            table_out.display(),
            table.bits_per_mm
        );
    }
    if let Some(svg) = &args.svg {
        trim_geom::fs::write_atomic(svg, residual_svg(&marks, &field, &r, args.focal_length_mm))
            .with_context(|| format!("cannot write {}", svg.display()))?;
        println!("wrote {}", svg.display());
    }
    Ok(())
}

/// One residual vector (mm) at a commanded position (mm).
struct Arrow {
    at: [f64; 2],
    v: [f64; 2],
}

/// Two panels of the marks' residual vectors (head frame, +y up): before (measured minus the
/// nominal lens: identity field, L the focal length) and after (measured minus the fit), each
/// magnified so its longest arrow spans 0.8 of the mark spacing, with a scale bar.
fn residual_svg(
    marks: &[Mark],
    field: &FieldCorrection,
    r: &FieldFitReport,
    focal_length_mm: f64,
) -> String {
    const PANEL: f64 = 520.0;
    const MARGIN: f64 = 30.0;
    let l = field.pivot_to_focal_plane_mm.unwrap_or(focal_length_mm);
    let mut before = Vec::with_capacity(marks.len());
    let mut after = Vec::with_capacity(marks.len());
    for m in marks {
        let c = [m.x_cmd, m.y_cmd];
        let sn = height_scale(focal_length_mm, m.h_mm);
        before.push(Arrow {
            at: c,
            v: [m.x_meas - c[0] * sn, m.y_meas - c[1] * sn],
        });
        let d = field.land(c);
        let sa = height_scale(l, m.h_mm);
        after.push(Arrow {
            at: c,
            v: [m.x_meas - d[0] * sa, m.y_meas - d[1] * sa],
        });
    }
    // The mark spacing: the smallest non-zero distance between distinct commanded x values.
    let mut xs: Vec<f64> = marks.iter().map(|m| m.x_cmd).collect();
    xs.sort_by(f64::total_cmp);
    let spacing = xs
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 1e-6)
        .fold(f64::INFINITY, f64::min);
    let spacing = if spacing.is_finite() {
        spacing
    } else {
        r.half_field_mm
    };
    let half = r.half_field_mm + spacing;
    let mut s = String::new();
    let width = 2.0 * PANEL + 3.0 * MARGIN;
    let height = PANEL + 4.0 * MARGIN;
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="13">"#
    );
    let _ = writeln!(
        s,
        r##"<defs><marker id="head" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="5" markerHeight="5" orient="auto"><path d="M0,0 L10,5 L0,10 z" fill="context-stroke"/></marker></defs>"##
    );
    let panels = [
        (
            &before,
            "#777",
            format!(
                "before (nominal lens): RMS {:.1} µm, max {:.1} µm",
                r.rms_before_um, r.max_before_um
            ),
        ),
        (
            &after,
            "#c22",
            format!(
                "after: RMS {:.2} µm, max {:.2} µm; LOO RMS {:.2} µm",
                r.rms_after_um, r.max_after_um, r.loo_rms_um
            ),
        ),
    ];
    for (k, (arrows, colour, title)) in panels.into_iter().enumerate() {
        let x0 = MARGIN + k as f64 * (PANEL + MARGIN);
        let y0 = 2.0 * MARGIN;
        let px = |x: f64| x0 + (x + half) / (2.0 * half) * PANEL;
        let py = |y: f64| y0 + (half - y) / (2.0 * half) * PANEL;
        let longest = arrows
            .iter()
            .map(|a| a.v[0].hypot(a.v[1]))
            .fold(0.0, f64::max)
            .max(1e-6);
        let magnify = nice_magnification(0.8 * spacing / longest);
        let _ = writeln!(s, r#"<text x="{x0}" y="{:.1}">{title}</text>"#, MARGIN);
        let _ = writeln!(
            s,
            r##"<rect x="{x0}" y="{y0}" width="{PANEL}" height="{PANEL}" fill="none" stroke="#ccc"/>"##
        );
        for a in arrows.iter() {
            let (x, y) = (a.at[0], a.at[1]);
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="1.6" fill="black"/><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}" stroke-width="1.3" marker-end="url(#head)"/>"#,
                px(x),
                py(y),
                px(x),
                py(y),
                px(x + a.v[0] * magnify),
                py(y + a.v[1] * magnify)
            );
        }
        // Scale bar: a round length near the mark spacing once magnified.
        let bar_um = nice_length_um(spacing / magnify * 1e3);
        let bar_px = bar_um * 1e-3 * magnify / (2.0 * half) * PANEL;
        let yb = y0 + PANEL + MARGIN;
        let _ = writeln!(
            s,
            r#"<line x1="{x0}" y1="{yb:.1}" x2="{:.1}" y2="{yb:.1}" stroke="{colour}" stroke-width="3"/><text x="{:.1}" y="{:.1}">{bar_um} µm (arrows ×{magnify})</text>"#,
            x0 + bar_px,
            x0 + bar_px + 8.0,
            yb + 4.0
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The largest 1-2-5 multiple of a power of ten not above `x` (at least 1).
fn nice_magnification(x: f64) -> f64 {
    if !(x.is_finite() && x > 1.0) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|v| *v <= x)
        .unwrap_or(p)
}

/// A round length (1-2-5 × 10ⁿ µm) not above `x_um`.
fn nice_length_um(x_um: f64) -> f64 {
    if !(x_um.is_finite() && x_um > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(x_um.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|v| *v <= x_um)
        .unwrap_or(p)
}
