//! SVG plots of a job: the zones coloured over the part (top view X–Y and side view Y–Z of the
//! work-piece frame), and one small panel per zone with its layers in galvo millimetres
//! (darker = higher layer). Pure string output: no I/O here.

use std::fmt::Write as _;

use trim_geom::Point3;

use trim_cell::job::{Job, workpiece_from_galvo};

/// The size of each part view (px).
pub const VIEW_PX: f64 = 420.0;
/// The size of each zone panel (px).
pub const PANEL_PX: f64 = 170.0;
/// Zone panels per row.
pub const PANELS_PER_ROW: usize = 6;
/// Margin inside views and panels (px).
const MARGIN_PX: f64 = 14.0;
/// The golden angle (degrees): consecutive zones get well separated hues.
const HUE_STEP_DEG: f64 = 137.508;

/// The font size of a panel's contour line (px) and the width of a character at it, about.
const LEGEND_FONT_PX: f64 = 8.0;
const LEGEND_CHAR_PX: f64 = 4.4;

/// A zone panel's bottom line: its contours as an operator reads them (CAM ids, then hatch
/// tracks as `hatch[0] tracks 1–70`), squeezed to the panel's width when longer.
fn contour_legend(out: &mut String, x0: f64, y0: f64, contours: &[trim_geom::ContourId]) {
    let text = crate::hatch::track_ids::describe_contours(contours);
    let width = PANEL_PX - 8.0;
    let squeeze = if text.chars().count() as f64 * LEGEND_CHAR_PX > width {
        format!(r#" textLength="{width}" lengthAdjust="spacingAndGlyphs""#)
    } else {
        String::new()
    };
    let _ = writeln!(
        out,
        r#"<text x="{}" y="{}" font-size="{LEGEND_FONT_PX}"{squeeze}>{}</text>"#,
        x0 + 4.0,
        y0 + PANEL_PX - 4.0,
        xml_escape(&text)
    );
}

/// The colour of a zone (HSL, hue by golden angle).
#[must_use]
pub fn zone_colour(zone: usize) -> String {
    format!("hsl({:.1},70%,45%)", (zone as f64 * HUE_STEP_DEG) % 360.0)
}

struct Bounds {
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Bounds {
    fn around(points: impl Iterator<Item = [f64; 2]>) -> Bounds {
        let mut b = Bounds {
            lo: [f64::INFINITY; 2],
            hi: [f64::NEG_INFINITY; 2],
        };
        for p in points {
            b.lo = [b.lo[0].min(p[0]), b.lo[1].min(p[1])];
            b.hi = [b.hi[0].max(p[0]), b.hi[1].max(p[1])];
        }
        if !b.lo[0].is_finite() {
            b = Bounds {
                lo: [-1.0; 2],
                hi: [1.0; 2],
            };
        }
        b
    }

    /// Maps a point into a square of `size` px at (`x0`, `y0`), y up, aspect kept.
    fn mapper(&self, x0: f64, y0: f64, size: f64) -> impl Fn([f64; 2]) -> (f64, f64) + use<> {
        let span = (self.hi[0] - self.lo[0])
            .max(self.hi[1] - self.lo[1])
            .max(1e-9);
        let scale = (size - 2.0 * MARGIN_PX) / span;
        let (lo, hi) = (self.lo, self.hi);
        let cx = 0.5 * (lo[0] + hi[0]);
        let cy = 0.5 * (lo[1] + hi[1]);
        move |p: [f64; 2]| {
            (
                x0 + size / 2.0 + (p[0] - cx) * scale,
                y0 + size / 2.0 - (p[1] - cy) * scale,
            )
        }
    }
}

/// The `d` attribute of an SVG path through `points` (px), `M x,y L x,y …`.
#[must_use]
pub fn path_data(points: &[(f64, f64)]) -> String {
    let mut d = String::new();
    for (i, (x, y)) in points.iter().enumerate() {
        let _ = write!(d, "{}{x:.2},{y:.2}", if i == 0 { "M" } else { " L" });
    }
    d
}

fn polyline(out: &mut String, points: &[(f64, f64)], colour: &str, width: f64) {
    let d = path_data(points);
    let _ = writeln!(
        out,
        r#"<path d="{d}" fill="none" stroke="{colour}" stroke-width="{width}"/>"#
    );
}

/// The colour of zones no pose within the axis limits reaches.
const UNREACHABLE_COLOUR: &str = "#d00000";

/// `text` with the characters XML gives a meaning (`& < > "`) escaped, for SVG text and
/// attributes.
#[must_use]
pub fn xml_escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The job's SVG: its polylines in top and side views, then a panel per zone with its layers
/// shaded top (dark) to bottom (light). Unreachable zones are drawn red and their panels say so.
#[must_use]
pub fn job_svg(job: &Job) -> String {
    // Every galvo point back on its focal plane, in the work-piece frame.
    // (zone id, unreachable, points)
    let mut lines: Vec<(usize, bool, Vec<Point3>)> = Vec::new();
    for z in &job.zones {
        for l in &z.layers {
            for p in &l.polylines {
                lines.push((
                    z.id,
                    z.unreachable.is_some(),
                    p.points
                        .iter()
                        .map(|xy| workpiece_from_galvo(z, l, *xy))
                        .collect(),
                ));
            }
        }
    }
    let rows = job.zones.len().div_ceil(PANELS_PER_ROW);
    let width = (2.0 * VIEW_PX).max(PANELS_PER_ROW as f64 * PANEL_PX);
    let height = VIEW_PX + 30.0 + rows as f64 * PANEL_PX;
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(
        out,
        r#"<rect width="{width}" height="{height}" fill="white"/>"#
    );
    let views: [(&str, usize, usize); 2] = [
        ("top view (X right, Y up)", 0, 1),
        ("side view (Y right, Z up)", 1, 2),
    ];
    for (v, (title, a, b)) in views.iter().enumerate() {
        let x0 = v as f64 * VIEW_PX;
        let bounds = Bounds::around(
            lines
                .iter()
                .flat_map(|(_, _, pts)| pts.iter().map(|p| [p[*a], p[*b]])),
        );
        let map = bounds.mapper(x0, 0.0, VIEW_PX);
        let _ = writeln!(
            out,
            r##"<rect x="{x0}" y="0" width="{VIEW_PX}" height="{VIEW_PX}" fill="none" stroke="#ccc"/><text x="{}" y="12">{title}</text>"##,
            x0 + 4.0
        );
        for (zone, unreachable, pts) in &lines {
            let px: Vec<(f64, f64)> = pts.iter().map(|p| map([p[*a], p[*b]])).collect();
            if *unreachable {
                polyline(&mut out, &px, UNREACHABLE_COLOUR, 2.4);
            } else {
                polyline(&mut out, &px, &zone_colour(*zone), 1.2);
            }
        }
    }
    for (i, z) in job.zones.iter().enumerate() {
        let (x0, y0) = (
            (i % PANELS_PER_ROW) as f64 * PANEL_PX,
            VIEW_PX + 30.0 + (i / PANELS_PER_ROW) as f64 * PANEL_PX,
        );
        let bounds = Bounds::around(
            z.layers
                .iter()
                .flat_map(|l| l.polylines.iter())
                .flat_map(|p| p.points.iter().copied()),
        );
        let map = bounds.mapper(x0, y0, PANEL_PX);
        let _ = writeln!(
            out,
            r##"<rect x="{x0}" y="{y0}" width="{PANEL_PX}" height="{PANEL_PX}" fill="none" stroke="{}"/><text x="{}" y="{}">zone {} · {} layers · {:.1}°</text>"##,
            zone_colour(z.id),
            x0 + 4.0,
            y0 + 12.0,
            z.id,
            z.layers.len(),
            z.max_incidence_deg
        );
        contour_legend(&mut out, x0, y0, &z.contours);
        if let Some(why) = &z.unreachable {
            let _ = writeln!(
                out,
                r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{UNREACHABLE_COLOUR}" fill-opacity="0.12" stroke="{UNREACHABLE_COLOUR}" stroke-width="3"><title>{}</title></rect><text x="{}" y="{}" fill="{UNREACHABLE_COLOUR}" font-weight="bold">UNREACHABLE</text>"#,
                x0 + 1.5,
                y0 + 1.5,
                PANEL_PX - 3.0,
                PANEL_PX - 3.0,
                xml_escape(why),
                x0 + 4.0,
                y0 + 26.0,
            );
        }
        let n = z.layers.len().max(1) as f64;
        for l in &z.layers {
            let lightness = 25.0 + 50.0 * l.index as f64 / n;
            let colour = format!(
                "hsl({:.1},70%,{lightness:.0}%)",
                (z.id as f64 * HUE_STEP_DEG) % 360.0
            );
            for p in &l.polylines {
                let px: Vec<(f64, f64)> = p.points.iter().map(|xy| map(*xy)).collect();
                polyline(&mut out, &px, &colour, 1.0);
            }
        }
    }
    out.push_str("</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::{PlanSettings, plan};
    use trim_synth::testing::synthetic_core_path;

    #[test]
    fn draws_every_polyline_twice_and_a_panel_per_zone() {
        let job = plan(&synthetic_core_path(10, 3), &PlanSettings::default()).unwrap();
        let svg = job_svg(&job);
        let polylines: usize = job
            .zones
            .iter()
            .flat_map(|z| z.layers.iter())
            .map(|l| l.polylines.len())
            .sum();
        // Two part views plus one panel: three paths per polyline.
        assert_eq!(svg.matches("<path ").count(), 3 * polylines);
        assert_eq!(svg.matches(" layers · ").count(), job.zones.len());
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>\n"));
        assert!(!svg.contains("NaN"));
        assert!(!svg.contains("UNREACHABLE"));
        assert!(!svg.contains("hatch["));
    }

    #[test]
    fn the_legend_names_hatch_tracks_not_their_ids() {
        use crate::hatch::track_ids::track_id;
        let mut job = plan(&synthetic_core_path(10, 3), &PlanSettings::default()).unwrap();
        job.zones[0].contours = (0..70).map(|t| track_id(0, t)).chain([2, 41]).collect();
        let svg = job_svg(&job);
        assert!(
            svg.contains(">[2, 41] hatch[0] tracks 1–70</text>"),
            "{svg}"
        );
        assert!(!svg.contains("[-"));
    }

    #[test]
    fn marks_unreachable_zones_red_with_their_reason() {
        let mut job = plan(&synthetic_core_path(10, 3), &PlanSettings::default()).unwrap();
        job.zones[0].unreachable = Some("A = 120° outside [-100, 50] <&>".to_owned());
        let svg = job_svg(&job);
        assert_eq!(svg.matches(">UNREACHABLE<").count(), 1);
        assert!(svg.contains("<title>A = 120° outside [-100, 50] &lt;&amp;&gt;</title>"));
        let polylines: usize = job.zones[0].layers.iter().map(|l| l.polylines.len()).sum();
        // Its polylines in both part views are drawn in the warning colour.
        assert_eq!(
            svg.matches(&format!(
                "stroke=\"{UNREACHABLE_COLOUR}\" stroke-width=\"2.4\""
            ))
            .count(),
            2 * polylines
        );
    }
}
