//! The registration's picture (`registration.svg`, `trimctl register --svg`): the registered
//! contours over the scan, each coloured by its predicted error bound against the tolerance,
//! the flagged ones drawn red and dashed with their id, and the part's verdict above. It is
//! what an operator looks at when `trimctl run` refuses to start: where on the part the
//! untrustworthy contours are, and why. Pure string output: no I/O here.

use std::fmt::Write as _;

use trim_geom::{Path, Point3, Vector3};
use trim_plan::svg::{path_data, xml_escape};
use trim_register::regional::{QualityReport, moments, principal_axes};

/// The picture's width (px).
const WIDTH_PX: f64 = 1000.0;
/// The plot's height limits (px): the part keeps its aspect ratio within them.
const PLOT_MIN_PX: f64 = 260.0;
const PLOT_MAX_PX: f64 = 640.0;
/// Margin around the plot (px).
const MARGIN_PX: f64 = 24.0;
/// Height of the header (title and verdict lines) above the plot (px).
const HEADER_PX: f64 = 58.0;
/// At most this many scan points are drawn (every k-th): enough to show where the scanner saw
/// the part, small enough for a browser.
pub const MAX_SCAN_DOTS: usize = 12_000;
/// At most this many flagged contours are listed under the plot (all are drawn).
pub const MAX_LISTED: usize = 24;
/// Longest verdict line (characters); the whole reason is in the line's tooltip.
const MAX_LINE_CHARS: usize = 125;
/// The colour of a flagged contour.
const FLAGGED_COLOUR: &str = "#c00000";

/// One contour as the picture draws it.
#[derive(Debug, Clone)]
pub struct ContourView<'a> {
    /// The contour id.
    pub id: i64,
    /// Its registered points (scan frame, mm).
    pub points: &'a [Point3],
    /// Its predicted bound on the largest cross-edge error (µm).
    pub bound_um: f64,
    /// Whether the registration trusts it.
    pub trusted: bool,
    /// Its flags, as the report names them (`predicted_error`, …).
    pub flags: Vec<String>,
}

/// The part's verdict as the picture states it.
#[derive(Debug, Clone, Default)]
pub struct PartView {
    /// The tolerance the bounds are judged against (µm).
    pub tolerance_um: f64,
    /// Why the part is refused, if it is.
    pub refused: Option<String>,
    /// Why the part is in doubt, if it is.
    pub in_doubt: Option<String>,
    /// Which edges are in doubt, if any.
    pub edges_in_doubt: Option<String>,
    /// Which stretch of the part's long axis is in doubt, if any.
    pub region_in_doubt: Option<String>,
}

/// The views of a registered `path` and its quality `report` (contours matched by id).
#[must_use]
pub fn views<'a>(path: &'a Path, report: &QualityReport) -> Vec<ContourView<'a>> {
    path.contours()
        .iter()
        .map(|c| {
            let q = report.contours.iter().find(|q| q.id == c.id());
            ContourView {
                id: c.id(),
                points: c.points(),
                bound_um: q.map_or(f64::NAN, |q| q.predicted_max_error_um),
                trusted: q.is_some_and(|q| q.trustworthy),
                flags: q.map_or_else(
                    || vec!["not in the report".to_string()],
                    |q| {
                        q.flags
                            .iter()
                            .map(|f| {
                                serde_json::to_value(f)
                                    .ok()
                                    .and_then(|v| v.as_str().map(str::to_string))
                                    .unwrap_or_else(|| format!("{f:?}"))
                            })
                            .collect()
                    },
                ),
            }
        })
        .collect()
}

/// The part's verdict from `report`, judged at `tolerance_um`.
#[must_use]
pub fn part_view(report: &QualityReport, tolerance_um: f64) -> PartView {
    PartView {
        tolerance_um,
        refused: report.global.refused.clone(),
        in_doubt: report.global.in_doubt.clone(),
        edges_in_doubt: report.global.edges_in_doubt.clone(),
        region_in_doubt: report.global.region_in_doubt.clone(),
    }
}

/// The two axes the picture shows: the path's two principal directions (largest spread
/// right, the next up; `trim_register::regional::principal_axes`), each signed so that its
/// largest component is positive; the view looks along the path's thinnest direction.
fn view_axes(points: &[Point3]) -> (Vector3, Vector3, Point3) {
    let (centre, cov) = moments(points);
    let (axes, _) = principal_axes(&cov);
    let signed = |v: Vector3| {
        let k = v.iamax();
        if v[k] < 0.0 { -v } else { v }
    };
    let (e1, e2) = (
        signed(axes.column(0).into_owned()),
        signed(axes.column(1).into_owned()),
    );
    if e1.iter().chain(e2.iter()).all(|v| v.is_finite()) {
        (e1, e2, centre)
    } else {
        (Vector3::x(), Vector3::y(), centre)
    }
}

/// Green (bound 0) through amber to red (bound at or over the tolerance), as an HSL colour.
fn bound_colour(bound_um: f64, tolerance_um: f64) -> String {
    let t = if bound_um.is_finite() && tolerance_um > 0.0 {
        (bound_um / tolerance_um).clamp(0.0, 1.0)
    } else {
        1.0
    };
    format!("hsl({:.0},80%,38%)", 120.0 * (1.0 - t))
}

/// `text` cut to [`MAX_LINE_CHARS`] with an ellipsis.
fn shortened(text: &str) -> String {
    if text.chars().count() <= MAX_LINE_CHARS {
        text.to_string()
    } else {
        let cut: String = text.chars().take(MAX_LINE_CHARS - 1).collect();
        format!("{cut}…")
    }
}

/// A contour's tooltip: its id, bound and flags.
fn tooltip(c: &ContourView<'_>) -> String {
    let bound = if c.bound_um.is_finite() {
        format!("{:.1} µm", c.bound_um)
    } else {
        "none".to_string()
    };
    if c.flags.is_empty() {
        format!("contour {}: bound {bound}, trusted", c.id)
    } else {
        format!(
            "contour {}: bound {bound}, flags: {}",
            c.id,
            c.flags.join(", ")
        )
    }
}

/// The picture: `contours` over the `scan` (scan frame, thinned to [`MAX_SCAN_DOTS`]), seen
/// along the path's thinnest direction, with the part's verdict `part` above and the flagged
/// contours listed below.
#[must_use]
pub fn render(contours: &[ContourView<'_>], part: &PartView, scan: &[Point3]) -> String {
    let all: Vec<Point3> = contours
        .iter()
        .flat_map(|c| c.points.iter().copied())
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect();
    let (e1, e2, centre) = view_axes(&all);
    let project = |p: &Point3| {
        let d = p - centre;
        [d.dot(&e1), d.dot(&e2)]
    };
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &all {
        let q = project(p);
        lo = [lo[0].min(q[0]), lo[1].min(q[1])];
        hi = [hi[0].max(q[0]), hi[1].max(q[1])];
    }
    if !(lo[0].is_finite() && hi[0] > lo[0]) {
        lo = [-1.0, -1.0];
        hi = [1.0, 1.0];
    }
    let span = [(hi[0] - lo[0]).max(1e-6), (hi[1] - lo[1]).max(1e-6)];
    let plot_w = WIDTH_PX - 2.0 * MARGIN_PX;
    let scale = (plot_w / span[0]).min((PLOT_MAX_PX - 2.0 * MARGIN_PX) / span[1]);
    let plot_h = (span[1] * scale + 2.0 * MARGIN_PX).max(PLOT_MIN_PX);
    let x0 = MARGIN_PX + 0.5 * (plot_w - span[0] * scale);
    let y_mid = HEADER_PX + 0.5 * plot_h;
    let px = |q: [f64; 2]| {
        (
            x0 + (q[0] - lo[0]) * scale,
            y_mid - (q[1] - 0.5 * (lo[1] + hi[1])) * scale,
        )
    };
    let flagged: Vec<&ContourView<'_>> = contours.iter().filter(|c| !c.trusted).collect();
    let listed = flagged.len().min(MAX_LISTED);
    let list_px = if flagged.is_empty() {
        0.0
    } else {
        18.0 + 14.0 * listed as f64 + if flagged.len() > listed { 14.0 } else { 0.0 }
    };
    let legend_y = HEADER_PX + plot_h + 10.0;
    let height = legend_y + 40.0 + list_px;

    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH_PX}" height="{height:.0}" viewBox="0 0 {WIDTH_PX} {height:.0}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(out, r#"<rect width="100%" height="100%" fill="white"/>"#);

    // The header: what is trusted, then the part's verdict.
    let trusted = contours.len() - flagged.len();
    let _ = writeln!(
        out,
        r#"<text x="{MARGIN_PX}" y="18" font-size="14" font-weight="bold">registration: {trusted} of {} contours trusted (tolerance {:.0} µm)</text>"#,
        contours.len(),
        part.tolerance_um
    );
    let local;
    let verdict = match (&part.refused, &part.in_doubt) {
        (Some(r), _) => Some(("PART REFUSED", r)),
        (None, Some(r)) => Some(("part in doubt", r)),
        (None, None) => match (&part.edges_in_doubt, &part.region_in_doubt) {
            (Some(r), None) => Some(("edges in doubt", r)),
            (None, Some(r)) => Some(("a stretch of the part in doubt", r)),
            (Some(e), Some(r)) => {
                local = format!("{e}; {r}");
                Some(("edges and a stretch of the part in doubt", &local))
            }
            (None, None) => None,
        },
    };
    match verdict {
        Some((what, why)) => {
            let _ = writeln!(
                out,
                r#"<text class="verdict" x="{MARGIN_PX}" y="38" fill="{FLAGGED_COLOUR}" font-weight="bold"><title>{}</title>{what}: {}</text>"#,
                xml_escape(why),
                xml_escape(&shortened(why))
            );
        }
        None => {
            let _ = writeln!(
                out,
                r#"<text class="verdict" x="{MARGIN_PX}" y="38">the part as a whole: accepted</text>"#
            );
        }
    }
    let _ = writeln!(
        out,
        r##"<text x="{MARGIN_PX}" y="52" fill="#666" font-size="10">view along the path's thinnest direction; grey: scan points (every {}th of {}); hover a contour for its bound and flags</text>"##,
        scan.len().div_ceil(MAX_SCAN_DOTS).max(1),
        scan.len()
    );

    // The scan, thinned, where the path is (outliers far off the part are not drawn).
    let every = scan.len().div_ceil(MAX_SCAN_DOTS).max(1);
    let pad = 0.05 * span[0].max(span[1]);
    let _ = write!(out, r##"<g class="scan" fill="#c8c8c8">"##);
    for p in scan.iter().step_by(every) {
        let q = project(p);
        if !(q[0] >= lo[0] - pad
            && q[0] <= hi[0] + pad
            && q[1] >= lo[1] - pad
            && q[1] <= hi[1] + pad)
        {
            continue;
        }
        let (x, y) = px(q);
        let _ = write!(out, r#"<circle cx="{x:.1}" cy="{y:.1}" r="0.7"/>"#);
    }
    let _ = writeln!(out, "</g>");

    // Trusted contours first, the flagged ones over them.
    for c in contours
        .iter()
        .filter(|c| c.trusted)
        .chain(flagged.iter().copied())
    {
        let pts: Vec<(f64, f64)> = c
            .points
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .map(|p| px(project(p)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let d = path_data(&pts);
        let title = xml_escape(&tooltip(c));
        if c.trusted {
            let _ = writeln!(
                out,
                r#"<path class="contour trusted" data-id="{}" d="{d}" fill="none" stroke="{}" stroke-width="1.6"><title>{title}</title></path>"#,
                c.id,
                bound_colour(c.bound_um, part.tolerance_um)
            );
        } else {
            let _ = writeln!(
                out,
                r#"<path class="contour flagged" data-id="{}" d="{d}" fill="none" stroke="{FLAGGED_COLOUR}" stroke-width="2.8" stroke-dasharray="6 3"><title>{title}</title></path>"#,
                c.id
            );
            let (x, y) = pts[pts.len() / 2];
            let _ = writeln!(
                out,
                r#"<text class="label" x="{:.1}" y="{:.1}" fill="{FLAGGED_COLOUR}" font-weight="bold" font-size="11">{}</text>"#,
                x + 4.0,
                y - 4.0,
                c.id
            );
        }
    }

    // The colour scale.
    let bar_w = 240.0;
    let _ = writeln!(
        out,
        r#"<defs><linearGradient id="bound-scale"><stop offset="0" stop-color="{}"/><stop offset="0.5" stop-color="{}"/><stop offset="1" stop-color="{}"/></linearGradient></defs>"#,
        bound_colour(0.0, 1.0),
        bound_colour(0.5, 1.0),
        bound_colour(1.0, 1.0)
    );
    let _ = writeln!(
        out,
        r#"<rect class="legend" x="{MARGIN_PX}" y="{legend_y:.0}" width="{bar_w}" height="10" fill="url(#bound-scale)"/>"#
    );
    for (t, label) in [
        (0.0, "0".to_string()),
        (0.5, format!("{:.0}", 0.5 * part.tolerance_um)),
        (1.0, format!("{:.0} µm", part.tolerance_um)),
    ] {
        let _ = writeln!(
            out,
            r#"<text x="{:.0}" y="{:.0}" font-size="10" text-anchor="middle">{label}</text>"#,
            MARGIN_PX + t * bar_w,
            legend_y + 24.0
        );
    }
    let _ = writeln!(
        out,
        r#"<text x="{:.0}" y="{:.0}" font-size="11">trusted: colour = predicted error bound; <tspan fill="{FLAGGED_COLOUR}" font-weight="bold">red dashed = flagged (not trimmed)</tspan></text>"#,
        MARGIN_PX + bar_w + 20.0,
        legend_y + 9.0
    );

    // The flagged contours, listed.
    if !flagged.is_empty() {
        let y = legend_y + 52.0;
        let _ = writeln!(
            out,
            r#"<text x="{MARGIN_PX}" y="{y:.0}" font-weight="bold">flagged contours ({}):</text>"#,
            flagged.len()
        );
        for (k, c) in flagged.iter().take(listed).enumerate() {
            let _ = writeln!(
                out,
                r#"<text class="flagged-row" x="{MARGIN_PX}" y="{:.0}">{}</text>"#,
                y + 14.0 * (k + 1) as f64,
                xml_escape(&tooltip(c))
            );
        }
        if flagged.len() > listed {
            let _ = writeln!(
                out,
                r#"<text x="{MARGIN_PX}" y="{:.0}">… and {} more (registration.json has every one)</text>"#,
                y + 14.0 * (listed + 1) as f64,
                flagged.len() - listed
            );
        }
    }
    out.push_str("</svg>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strip(y: f64, n: usize) -> Vec<Point3> {
        (0..n)
            .map(|i| Point3::new(i as f64, y, 0.01 * i as f64))
            .collect()
    }

    fn view<'a>(id: i64, points: &'a [Point3], bound_um: f64, flags: &[&str]) -> ContourView<'a> {
        ContourView {
            id,
            points,
            bound_um,
            trusted: flags.is_empty(),
            flags: flags.iter().map(|f| f.to_string()).collect(),
        }
    }

    #[test]
    fn every_contour_is_drawn_once_and_the_flagged_ones_are_named_and_listed() {
        let (a, b, c) = (strip(0.0, 50), strip(5.0, 50), strip(10.0, 2));
        let contours = [
            view(3, &a, 12.0, &[]),
            view(7, &b, 41.5, &["predicted_error"]),
            view(9, &c, 8.0, &[]),
        ];
        let part = PartView {
            tolerance_um: 30.0,
            ..PartView::default()
        };
        // 1000 scan points over the part and 10 outliers far off it.
        let mut scan: Vec<Point3> = (0..1000)
            .map(|i| Point3::new(0.049 * i as f64, 2.0, 0.0))
            .collect();
        scan.extend((0..10).map(|i| Point3::new(500.0 + i as f64, 200.0, 0.0)));
        let svg = render(&contours, &part, &scan);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches(r#"class="contour trusted""#).count(), 2);
        assert_eq!(svg.matches(r#"class="contour flagged""#).count(), 1);
        assert!(svg.contains(r#"data-id="7""#));
        assert!(svg.contains("contour 7: bound 41.5 µm, flags: predicted_error"));
        assert!(svg.contains("2 of 3 contours trusted"));
        assert!(svg.contains("accepted"));
        // The flagged contour is drawn after (over) the trusted ones.
        let flagged_at = svg.find(r#"class="contour flagged""#).unwrap();
        assert!(svg.rfind(r#"class="contour trusted""#).unwrap() < flagged_at);
        // Every scan point on the part is drawn (1000 ≤ the cap), the outliers are not.
        assert_eq!(svg.matches("<circle").count(), 1000);
    }

    #[test]
    fn a_refused_part_says_so_with_the_whole_reason_in_its_tooltip() {
        let a = strip(0.0, 10);
        let reason = format!("contour 4's opening lies 0.8 mm off {}", "x".repeat(300));
        let part = PartView {
            tolerance_um: 30.0,
            refused: Some(reason.clone()),
            in_doubt: Some("ignored when refused".into()),
            edges_in_doubt: None,
            region_in_doubt: None,
        };
        let svg = render(&[view(4, &a, 90.0, &["opening_misplaced"])], &part, &[]);
        assert!(svg.contains("PART REFUSED: contour 4's opening"));
        assert!(svg.contains(&format!("<title>{}</title>", xml_escape(&reason))));
        assert!(svg.contains('…'), "the verdict line is shortened");
        assert!(!svg.contains("ignored when refused"));
    }

    /// A stretch in doubt, alone or with an edge in doubt, is the verdict, with both reasons.
    #[test]
    fn a_stretch_in_doubt_is_the_verdict_with_an_edge_in_doubt_beside_it() {
        let a = strip(0.0, 10);
        let mut part = PartView {
            tolerance_um: 30.0,
            refused: None,
            in_doubt: None,
            edges_in_doubt: None,
            region_in_doubt: Some("5 contours off between 10 and 40 mm".into()),
        };
        let contours = [view(4, &a, 20.0, &["region_in_doubt"])];
        let svg = render(&contours, &part, &[]);
        assert!(svg.contains("a stretch of the part in doubt: 5 contours off"));
        part.edges_in_doubt = Some("the edge of strips 1–3".into());
        let svg = render(&contours, &part, &[]);
        assert!(svg.contains(
            "edges and a stretch of the part in doubt: the edge of strips 1–3; 5 contours off"
        ));
    }

    #[test]
    fn bounds_run_green_to_red_and_odd_input_draws_without_panicking() {
        assert_eq!(bound_colour(0.0, 30.0), "hsl(120,80%,38%)");
        assert_eq!(bound_colour(15.0, 30.0), "hsl(60,80%,38%)");
        assert_eq!(bound_colour(45.0, 30.0), "hsl(0,80%,38%)");
        assert_eq!(bound_colour(f64::NAN, 30.0), "hsl(0,80%,38%)");
        let odd = [Point3::new(f64::NAN, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0)];
        let single = [Point3::new(2.0, 2.0, 2.0)];
        let svg = render(
            &[
                view(1, &odd, f64::NAN, &["no_scan_points"]),
                view(2, &single, 5.0, &[]),
            ],
            &PartView::default(),
            &[Point3::new(f64::INFINITY, 0.0, 0.0)],
        );
        assert_eq!(svg.matches("class=\"contour").count(), 2);
        assert!(!svg.contains("NaN") && !svg.contains("inf"));
        assert!(svg.contains("bound none"));
    }

    #[test]
    fn many_flagged_contours_are_all_drawn_and_the_list_stops_at_its_cap() {
        let pts: Vec<Vec<Point3>> = (0..40).map(|k| strip(k as f64, 5)).collect();
        let contours: Vec<ContourView<'_>> = pts
            .iter()
            .enumerate()
            .map(|(k, p)| view(k as i64, p, 50.0, &["part_in_doubt"]))
            .collect();
        let svg = render(
            &contours,
            &PartView {
                tolerance_um: 30.0,
                ..PartView::default()
            },
            &[],
        );
        assert_eq!(svg.matches(r#"class="contour flagged""#).count(), 40);
        assert_eq!(svg.matches(r#"class="flagged-row""#).count(), MAX_LISTED);
        assert!(svg.contains(&format!("… and {} more", 40 - MAX_LISTED)));
    }
}
