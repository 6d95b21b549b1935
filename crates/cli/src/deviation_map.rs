//! `trimctl inspect`'s deviation map: the scan's signed distance to the CAD seen from above
//! (the CAD frame's +Z), a diverging colour scale with its labels, and the contours drawn in
//! their verdict's colour. Encoded as an 8-bit RGB PNG.

use anyhow::Context;
use trim_geom::Point3;
use trim_inspect::Verdict;

/// Image size, pixels.
const WIDTH: usize = 1200;
const HEIGHT: usize = 800;
/// The colour bar's place: left edge, top, width, height (pixels).
const BAR: [usize; 4] = [1100, 80, 30, 640];
/// The plot area's margin, pixels.
const MARGIN: usize = 40;

/// A contour to draw: its points (CAD frame) and verdict.
pub struct DrawnContour<'a> {
    /// Points, CAD frame, mm.
    pub points: &'a [Point3],
    /// Its verdict.
    pub verdict: Verdict,
}

/// The map of `points` (CAD frame) with `distances_mm`, encoded as a PNG in memory (the caller
/// writes it whole or not at all); the scale spans ±`scale_um`.
pub fn encode_map(
    points: &[Point3],
    distances_mm: &[f64],
    contours: &[DrawnContour<'_>],
    scale_um: f64,
) -> anyhow::Result<Vec<u8>> {
    let mut img = vec![255u8; WIDTH * HEIGHT * 3];
    // The view: x across, y up, fitted into the plot area with equal scales.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points
        .iter()
        .chain(contours.iter().flat_map(|c| c.points.iter()))
    {
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    anyhow::ensure!(lo[0].is_finite(), "nothing to draw in the deviation map");
    let plot_w = (BAR[0] - 2 * MARGIN) as f64;
    let plot_h = (HEIGHT - 2 * MARGIN) as f64;
    // The part is long along y: turn it so its long side runs across the picture.
    let turn = hi[1] - lo[1] > hi[0] - lo[0];
    let (span_a, span_b) = if turn {
        (hi[1] - lo[1], hi[0] - lo[0])
    } else {
        (hi[0] - lo[0], hi[1] - lo[1])
    };
    let px_per_mm = (plot_w / span_a.max(1e-9)).min(plot_h / span_b.max(1e-9));
    let to_px = |p: &Point3| -> (f64, f64) {
        let (a, b) = if turn {
            (p.y - lo[1], hi[0] - p.x)
        } else {
            (p.x - lo[0], p.y - lo[1])
        };
        (
            MARGIN as f64 + a * px_per_mm,
            (HEIGHT - MARGIN) as f64 - b * px_per_mm,
        )
    };
    // Points, smallest |distance| first so the deviations stay on top.
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&i, &j| distances_mm[i].abs().total_cmp(&distances_mm[j].abs()));
    for i in order {
        let (x, y) = to_px(&points[i]);
        let colour = diverging(distances_mm[i] * 1e3 / scale_um);
        dot(&mut img, x, y, 1, colour);
    }
    for c in contours {
        let colour = verdict_colour(c.verdict);
        for w in c.points.windows(2) {
            line(&mut img, to_px(&w[0]), to_px(&w[1]), colour);
        }
    }
    // The colour bar, +scale at the top, and its labels.
    let [bx, by, bw, bh] = BAR;
    for row in 0..bh {
        let v = 1.0 - 2.0 * row as f64 / (bh - 1) as f64;
        for col in 0..bw {
            put(&mut img, bx + col, by + row, diverging(v));
        }
    }
    for k in 0..=4 {
        let v = 1.0 - 0.5 * f64::from(k);
        let row = by + ((bh - 1) as f64 * f64::from(k) / 4.0) as usize;
        for col in 0..6 {
            put(&mut img, bx - 6 + col, row, [0, 0, 0]);
        }
        text(
            &mut img,
            bx - 70,
            row.saturating_sub(5),
            &format!("{:+.0}", v * scale_um),
        );
    }
    text(&mut img, bx - 10, by - 30, "UM");
    text(
        &mut img,
        MARGIN,
        12,
        "SCAN TO CAD SIGNED DISTANCE, TOP VIEW",
    );
    let mut png_bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut png_bytes, WIDTH as u32, HEIGHT as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder
        .write_header()
        .context("encoding the deviation map")?;
    writer
        .write_image_data(&img)
        .context("encoding the deviation map")?;
    writer.finish().context("encoding the deviation map")?;
    Ok(png_bytes)
}

/// Blue (−1) – white (0) – red (+1), clamped.
fn diverging(v: f64) -> [u8; 3] {
    let v = v.clamp(-1.0, 1.0);
    let fade = |t: f64| (255.0 * (1.0 - t)).round() as u8;
    if v >= 0.0 {
        [255, fade(v), fade(v)]
    } else {
        [fade(-v), fade(-v), 255]
    }
}

/// Green pass, red fail, orange undecided.
pub fn verdict_colour(v: Verdict) -> [u8; 3] {
    match v {
        Verdict::Pass => [0, 150, 0],
        Verdict::Fail => [200, 0, 0],
        Verdict::Undecided => [230, 140, 0],
    }
}

fn put(img: &mut [u8], x: usize, y: usize, c: [u8; 3]) {
    if x < WIDTH && y < HEIGHT {
        let i = 3 * (y * WIDTH + x);
        img[i..i + 3].copy_from_slice(&c);
    }
}

fn dot(img: &mut [u8], x: f64, y: f64, r: i64, c: [u8; 3]) {
    let (cx, cy) = (x.round() as i64, y.round() as i64);
    for dy in -r..=r {
        for dx in -r..=r {
            if let (Ok(px), Ok(py)) = (usize::try_from(cx + dx), usize::try_from(cy + dy)) {
                put(img, px, py, c);
            }
        }
    }
}

fn line(img: &mut [u8], a: (f64, f64), b: (f64, f64), c: [u8; 3]) {
    let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        dot(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), 1, c);
    }
}

/// A 3 × 5 pixel font, drawn at twice its size: digits, signs, and the capitals the labels use.
fn glyph(ch: char) -> [u8; 5] {
    match ch {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '+' => [0b000, 0b010, 0b111, 0b010, 0b000],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        ',' => [0b000, 0b000, 0b000, 0b010, 0b100],
        'A' => [0b010, 0b101, 0b111, 0b101, 0b101],
        'C' => [0b111, 0b100, 0b100, 0b100, 0b111],
        'D' => [0b110, 0b101, 0b101, 0b101, 0b110],
        'E' => [0b111, 0b100, 0b111, 0b100, 0b111],
        'G' => [0b111, 0b100, 0b101, 0b101, 0b111],
        'I' => [0b111, 0b010, 0b010, 0b010, 0b111],
        'M' => [0b101, 0b111, 0b111, 0b101, 0b101],
        'N' => [0b110, 0b101, 0b101, 0b101, 0b101],
        'O' => [0b111, 0b101, 0b101, 0b101, 0b111],
        'P' => [0b111, 0b101, 0b111, 0b100, 0b100],
        'S' => [0b111, 0b100, 0b111, 0b001, 0b111],
        'T' => [0b111, 0b010, 0b010, 0b010, 0b010],
        'U' => [0b101, 0b101, 0b101, 0b101, 0b111],
        'V' => [0b101, 0b101, 0b101, 0b101, 0b010],
        'W' => [0b101, 0b101, 0b111, 0b111, 0b101],
        _ => [0; 5],
    }
}

fn text(img: &mut [u8], x: usize, y: usize, s: &str) {
    for (k, ch) in s.chars().enumerate() {
        let g = glyph(ch);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (0b100 >> col) != 0 {
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        put(img, x + 8 * k + 2 * col + dx, y + 2 * row + dy, [0, 0, 0]);
                    }
                }
            }
        }
    }
}
