//! `trimctl calibrate field --marks marks.csv --out field.json`: the galvo field correction
//! (`trim_calib::field`).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use trim_calib::field::{FieldFitSettings, Mark, fit_field, read_marks};
use trim_plan::lens::FieldCorrection;

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
    /// The lens's focal length (mm): the nominal L and the centre of L's search.
    #[arg(long, default_value_t = trim_plan::Beam::default().focal_length_mm)]
    pub focal_length_mm: f64,
    /// An SVG of the residual vectors before and after, magnified.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let marks = read_marks(&args.marks)?;
    let settings = FieldFitSettings {
        focal_length_mm: args.focal_length_mm,
        ..FieldFitSettings::default()
    };
    let (field, r) = fit_field(&marks, &settings)
        .with_context(|| format!("fitting the field to {}", args.marks.display()))?;
    field
        .write(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(svg) = &args.svg {
        std::fs::write(svg, residual_svg(&marks, &field, args.focal_length_mm))
            .with_context(|| format!("writing {}", svg.display()))?;
    }
    println!(
        "{}: {} marks ({} off the focal plane) over ±{:.1} mm",
        args.marks.display(),
        r.marks,
        r.marks_off_plane,
        r.half_field_mm
    );
    println!(
        "residual before (nominal lens, no correction): RMS {:.1} µm, max {:.1} µm",
        r.rms_before_um, r.max_before_um
    );
    println!(
        "residual after:                                RMS {:.2} µm, max {:.2} µm",
        r.rms_after_um, r.max_after_um
    );
    println!(
        "leave-one-out (each mark unseen by its fit):   RMS {:.2} µm, max {:.2} µm",
        r.loo_rms_um, r.loo_max_um
    );
    println!(
        "offset ({:.4}, {:.4}) mm, rotation {:.4}°, {}",
        r.offset_mm[0],
        r.offset_mm[1],
        r.rotation_deg,
        match r.pivot_to_focal_plane_mm {
            Some(l) => format!(
                "pivot height L = {l:.2} mm (fitted from the off-plane rows; nominal {:.2} mm)",
                args.focal_length_mm
            ),
            None => "no off-plane rows: L is left to the job".to_owned(),
        }
    );
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The marks' residual vectors before (grey: nominal lens) and after (red: the fit), drawn
/// ×200 at each commanded position.
fn residual_svg(marks: &[Mark], field: &FieldCorrection, focal_length_mm: f64) -> String {
    const SIZE: f64 = 800.0;
    const MAGNIFY: f64 = 200.0;
    let half = field.half_field_mm * 1.1;
    let px = |x: f64| (x + half) / (2.0 * half) * SIZE;
    let py = |y: f64| (half - y) / (2.0 * half) * SIZE;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{SIZE}" height="{}" viewBox="0 0 {SIZE} {}">"#,
        SIZE + 40.0,
        SIZE + 40.0
    );
    let _ = writeln!(
        s,
        r#"<text x="10" y="{}" font-family="sans-serif" font-size="14">marks: residual ×{MAGNIFY} — grey: nominal lens (L = {focal_length_mm} mm, no correction), red: after the fit</text>"#,
        SIZE + 25.0
    );
    let l = field.pivot_to_focal_plane_mm.unwrap_or(focal_length_mm);
    for m in marks {
        let (x, y) = (m.x_cmd, m.y_cmd);
        let sn = trim_plan::lens::height_scale(focal_length_mm, m.h_mm);
        let before = [m.x_meas - x * sn, m.y_meas - y * sn];
        let d = field.land([x, y]);
        let sa = trim_plan::lens::height_scale(l, m.h_mm);
        let after = [m.x_meas - d[0] * sa, m.y_meas - d[1] * sa];
        for (v, colour) in [(before, "#999"), (after, "#d22")] {
            let _ = writeln!(
                s,
                r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}" stroke-width="1.2"/>"#,
                px(x),
                py(y),
                px(x + v[0] * MAGNIFY),
                py(y + v[1] * MAGNIFY)
            );
        }
        let _ = writeln!(
            s,
            r#"<circle cx="{:.1}" cy="{:.1}" r="1.5" fill="black"/>"#,
            px(x),
            py(y)
        );
    }
    s.push_str("</svg>\n");
    s
}
