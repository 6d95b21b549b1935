//! The cladding paper's slab method (§2.2–2.4), kept faithful as the baseline.
//!
//! - §2.2: the first track is a "point-cloud beam" (the scan points within δ/2 of a section
//!   plane through the hatch direction) fitted as a function of the along coordinate `y`
//!   (`solve(y)`: a local quadratic fit), and processing points are placed along it by the
//!   equal-distance step method (advance `y` by a small ∂_c until the 3D distance reaches ∂_m).
//! - §2.3 steps 1–3: for each processing point `p_sc`, the scan points within radius `r`
//!   (kd-tree); the plane `E` through `p_sc` normal to the track; the slabs `E_l`, `E_r` at δ/2
//!   either side; each point of the left slab joined to its nearest in the right slab, and the
//!   join cut with `E`; the cut points fitted (a cubic in `E`) and the point (1 − η)·d = pitch
//!   along the fitted contour taken for the next track.
//! - §2.3 step 4: the new points are fitted (local quadratic in `y`), those outside the boundary
//!   are removed by ray casting, and the ends are extended along the fitted curve (projected on
//!   the scan by a local plane fit) up to the boundary, cut exactly at it.
//! - §2.3 step 5: repeat until a new track has no point inside the boundary.
//! - §2.4: each point's posture V = P_sa × P_se (P_se along the track, P_sa to the nearest point
//!   of the next track; the previous track, reversed, for the last), oriented to the patch side.
//!
//! Choices the paper leaves open, made here: the first section lies pitch/2 (in the plane)
//! inside the boundary's extreme point; processing points are placed every pitch/2 (at most
//! the output step) and the output points are placed along the fitted polyline; the slab width
//! δ is three mean point spacings; the distance along the contour is its arc length.

use trim_geom::normals::plane_normal;
use trim_geom::{KdTree, Point3, Vector3};

use super::polygon::Polygon;
use super::surface::Surface;
use super::{HatchError, HatchSettings, PointSpacing, Track, TrackKind};

/// Slab width δ as a multiple of the mean point spacing.
const SLAB_WIDTH_PER_SPACING: f64 = 3.0;
/// Half window of the local quadratic track fits, in mean point spacings (at least a pitch).
const FIT_HALF_WINDOW_SPACINGS: f64 = 6.0;
/// The computation step ∂_c as a fraction of the processing step ∂_m (paper §2.2).
const COMPUTE_STEP_FRACTION: f64 = 0.02;
/// Scan points for the local plane that projects an extended end onto the scan.
const EXTEND_NEIGHBOURS: usize = 12;
/// The most tracks the iteration makes, as a multiple of the region's width over the pitch.
const MAX_TRACKS_FACTOR: f64 = 4.0;

struct Ctx<'a> {
    surface: &'a Surface,
    polygon: &'a Polygon,
    points: &'a [Point3],
    tree: KdTree,
    along: [f64; 2],
    across: [f64; 2],
    pitch: f64,
    delta: f64,
    step_m: f64,
    window: f64,
}

impl Ctx<'_> {
    fn plane(&self, p: &Point3) -> [f64; 2] {
        self.surface.frame().to_plane(p)
    }
    fn y(&self, p: &Point3) -> f64 {
        let st = self.plane(p);
        st[0] * self.along[0] + st[1] * self.along[1]
    }
    fn c(&self, p: &Point3) -> f64 {
        let st = self.plane(p);
        st[0] * self.across[0] + st[1] * self.across[1]
    }
    fn st(&self, y: f64, c: f64) -> [f64; 2] {
        [
            y * self.along[0] + c * self.across[0],
            y * self.along[1] + c * self.across[1],
        ]
    }
}

/// Plans the slab-method tracks, sampled and in serpentine order.
pub(crate) fn slab_tracks(
    surface: &Surface,
    polygon: &Polygon,
    settings: &HatchSettings,
    along: [f64; 2],
    across: [f64; 2],
) -> Result<Vec<Track>, HatchError> {
    let points = surface.near_points();
    let spacing = surface.point_spacing_mm();
    let pitch = settings.pitch_mm;
    let step_out = match settings.point_spacing() {
        PointSpacing::Pitch { step_mm } => step_mm,
        PointSpacing::Chord { .. } => pitch,
    };
    let ctx = Ctx {
        surface,
        polygon,
        points,
        tree: KdTree::build(points),
        along,
        across,
        pitch,
        delta: SLAB_WIDTH_PER_SPACING * spacing,
        step_m: (0.5 * pitch).min(step_out),
        window: (FIT_HALF_WINDOW_SPACINGS * spacing).max(pitch),
    };
    let cs: Vec<f64> = polygon
        .vertices()
        .iter()
        .map(|v| v[0] * across[0] + v[1] * across[1])
        .collect();
    let cmin = cs.iter().copied().fold(f64::INFINITY, f64::min);
    let cmax = cs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if pitch > cmax - cmin {
        return Err(HatchError::PitchTooLarge {
            pitch_mm: pitch,
            width_mm: cmax - cmin,
        });
    }
    // §2.2: the first track.
    let mut current: Vec<Vec<Point3>> = first_track(&ctx, cmin + 0.5 * pitch);
    if current.is_empty() {
        return Err(HatchError::TooFewPoints {
            what: "scan points on the first section (slab method)",
            needed: 3,
            got: 0,
        });
    }
    let mut levels: Vec<Vec<Vec<Point3>>> = Vec::new();
    let max_tracks = (MAX_TRACKS_FACTOR * (cmax - cmin) / pitch).ceil() as usize + 4;
    while !current.is_empty() && levels.len() < max_tracks {
        let next: Vec<Vec<Point3>> = current
            .iter()
            .flat_map(|piece| next_track(&ctx, piece))
            .collect();
        levels.push(current);
        current = next;
    }
    // Output: serpentine order, points along the fitted polylines, posture V = P_sa × P_se.
    let mut tracks = Vec::new();
    for (level, pieces) in levels.iter().enumerate() {
        let neighbour: Vec<Point3> = levels
            .get(level + 1)
            .or_else(|| level.checked_sub(1).and_then(|l| levels.get(l)))
            .map(|p| p.iter().flatten().copied().collect())
            .unwrap_or_default();
        let toward_next = level + 1 < levels.len();
        let neighbour_tree = KdTree::build(&neighbour);
        let mut group: Vec<Vec<Point3>> = pieces
            .iter()
            .map(|piece| resample(piece, settings.point_spacing()))
            .collect();
        if level % 2 == 1 {
            group.reverse();
            for g in &mut group {
                g.reverse();
            }
        }
        for pts in group {
            if pts.len() < 2 {
                continue;
            }
            let e3 = surface.frame().e3;
            let normals = pts
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let p_se = if i + 1 < pts.len() {
                        pts[i + 1] - p
                    } else {
                        p - pts[i - 1]
                    };
                    let p_sa = neighbour_tree.nearest(p).map_or(Vector3::zeros(), |n| {
                        let v = neighbour[n.index] - p;
                        if toward_next { v } else { -v }
                    });
                    let v = p_sa.cross(&p_se);
                    match v.try_normalize(1e-12) {
                        Some(v) if v.dot(&e3) < 0.0 => -v,
                        Some(v) => v,
                        None => e3,
                    }
                })
                .collect();
            tracks.push(Track {
                id: 0,
                kind: TrackKind::Hatch { level },
                points: pts,
                normals,
            });
        }
    }
    Ok(tracks)
}

/// §2.2: the point-cloud beam on the section `c = c_first`, fitted and stepped.
fn first_track(ctx: &Ctx<'_>, c_first: f64) -> Vec<Vec<Point3>> {
    let beam: Vec<(f64, f64)> = ctx
        .points
        .iter()
        .filter(|p| (ctx.c(p) - c_first).abs() <= 0.5 * ctx.delta)
        .map(|p| (ctx.y(p), ctx.surface.frame().height(p)))
        .collect();
    let (lo, hi) = ctx.polygon.bounds();
    let span = (hi[0] - lo[0]).hypot(hi[1] - lo[1]) + 1.0;
    let a = ctx.st(-span, c_first);
    let b = ctx.st(span, c_first);
    let crossings = ctx.polygon.crossings(a, b);
    let mut out = Vec::new();
    for pair in crossings.chunks(2) {
        let [u0, u1] = pair else { continue };
        let (y0, y1) = (-span + 2.0 * span * u0, -span + 2.0 * span * u1);
        let solve = |y: f64| -> Option<Point3> {
            let f = local_quadratic(&beam, y, ctx.window)?;
            Some(ctx.surface.frame().to_world(ctx.st(y, c_first), f))
        };
        let piece = equal_steps(y0, y1, ctx.step_m, solve);
        if piece.len() >= 2 {
            out.push(piece);
        }
    }
    out
}

/// The equal-distance step method (paper §2.2, Fig. 2): from `solve(y0)`, advance `y` by ∂_c
/// until the 3D distance reaches ∂_m, emit, repeat; `solve(y1)` closes the track.
fn equal_steps(
    y0: f64,
    y1: f64,
    step_m: f64,
    solve: impl Fn(f64) -> Option<Point3>,
) -> Vec<Point3> {
    let dc = step_m * COMPUTE_STEP_FRACTION;
    let mut out = Vec::new();
    let mut y = y0;
    let mut last: Option<Point3> = None;
    while y < y1 {
        if let Some(p) = solve(y) {
            match last {
                None => {
                    out.push(p);
                    last = Some(p);
                }
                Some(l) if (p - l).norm() >= step_m => {
                    out.push(p);
                    last = Some(p);
                }
                Some(_) => {}
            }
        }
        y += dc;
    }
    if let Some(p) = solve(y1)
        && last.is_none_or(|l| (p - l).norm() > 1e-3 * step_m)
    {
        out.push(p);
    }
    out
}

/// A local quadratic fit of `(x, value)` samples at `x0` (weights `(1 − d²/w²)²`).
fn local_quadratic(samples: &[(f64, f64)], x0: f64, w: f64) -> Option<f64> {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    let mut n = 0;
    for &(x, v) in samples {
        let d = (x - x0) / w;
        if d.abs() < 1.0 {
            let wt = (1.0 - d * d).powi(2);
            let row = nalgebra::Vector3::new(1.0, d, d * d);
            m += row * row.transpose() * wt;
            r += row * (wt * v);
            n += 1;
        }
    }
    if n < 4 {
        return None;
    }
    let c = m.cholesky()?.solve(&r);
    c[0].is_finite().then_some(c[0])
}

/// §2.3 steps 1–4: the next track from one piece of the previous one.
fn next_track(ctx: &Ctx<'_>, prev: &[Point3]) -> Vec<Vec<Point3>> {
    let across_world = ctx.surface.frame().plane_vector(ctx.across);
    let radius = 1.5 * ctx.pitch + ctx.delta;
    let mut found: Vec<Point3> = Vec::new();
    for i in 0..prev.len() {
        let p = prev[i];
        let t = match (i.checked_sub(1), prev.get(i + 1)) {
            (Some(a), Some(b)) => b - prev[a],
            (None, Some(b)) => b - p,
            (Some(a), None) => p - prev[a],
            (None, None) => continue,
        };
        let Some(t) = t.try_normalize(1e-12) else {
            continue;
        };
        let Some(u_e) = (across_world - t * across_world.dot(&t)).try_normalize(1e-12) else {
            continue;
        };
        let v_e = t.cross(&u_e);
        let local = ctx.tree.within_radius_unsorted(&p, radius);
        let mut left = Vec::new();
        let mut right = Vec::new();
        for n in &local {
            let q = ctx.points[n.index];
            let s = (q - p).dot(&t);
            if (-0.5 * ctx.delta..0.0).contains(&s) {
                left.push((q, s));
            } else if s > 0.0 && s <= 0.5 * ctx.delta {
                right.push((q, s));
            }
        }
        // Cut each left–right join with E.
        let mut cut: Vec<(f64, f64)> = Vec::with_capacity(left.len());
        for (l, sl) in &left {
            let Some((r, sr)) = right.iter().min_by(|a, b| {
                (a.0 - l)
                    .norm_squared()
                    .total_cmp(&(b.0 - l).norm_squared())
            }) else {
                continue;
            };
            let x = l + (r - l) * (-sl / (sr - sl));
            cut.push(((x - p).dot(&u_e), (x - p).dot(&v_e)));
        }
        let Some(next) = step_along_contour(&cut, ctx.pitch) else {
            continue;
        };
        found.push(p + u_e * next.0 + v_e * next.1);
    }
    // Step 4: fit, remove outside points, extend to the boundary.
    let fitted = fit_track(ctx, &found);
    let mut runs: Vec<Vec<Point3>> = Vec::new();
    let mut run: Vec<Point3> = Vec::new();
    for p in fitted {
        if ctx.polygon.contains(ctx.plane(&p)) {
            run.push(p);
        } else if !run.is_empty() {
            runs.push(std::mem::take(&mut run));
        }
    }
    if !run.is_empty() {
        runs.push(run);
    }
    runs.into_iter()
        .filter_map(|r| {
            let extended = extend(ctx, r)?;
            let ys: Vec<(f64, Point3)> = extended.iter().map(|p| (ctx.y(p), *p)).collect();
            let (y0, y1) = (ys.first()?.0, ys.last()?.0);
            let piece = equal_steps(y0, y1, ctx.step_m, |y| interpolate(&ys, y));
            (piece.len() >= 2).then_some(piece)
        })
        .collect()
}

/// Fits a cubic `ζ(σ)` to the cut contour and walks it from σ = 0 by arc length `pitch`.
fn step_along_contour(cut: &[(f64, f64)], pitch: f64) -> Option<(f64, f64)> {
    if cut.len() < 5 {
        return None;
    }
    let smax = cut.iter().map(|c| c.0).fold(f64::NEG_INFINITY, f64::max);
    if smax < 0.8 * pitch {
        return None;
    }
    let scale = smax.max(1e-9);
    let mut m = nalgebra::Matrix4::<f64>::zeros();
    let mut r = nalgebra::Vector4::<f64>::zeros();
    for &(s, z) in cut {
        let x = s / scale;
        let row = nalgebra::Vector4::new(1.0, x, x * x, x * x * x);
        m += row * row.transpose();
        r += row * z;
    }
    for k in 0..4 {
        m[(k, k)] += 1e-12 * m.trace().max(1e-300);
    }
    let c = m.cholesky()?.solve(&r);
    let zeta = |s: f64| {
        let x = s / scale;
        c[0] + c[1] * x + c[2] * x * x + c[3] * x * x * x
    };
    let ds = pitch * COMPUTE_STEP_FRACTION * 0.1;
    let (mut s, mut z, mut arc) = (0.0, zeta(0.0), 0.0);
    while arc < pitch {
        let (s1, z1) = (s + ds, zeta(s + ds));
        let seg = (s1 - s).hypot(z1 - z);
        if arc + seg >= pitch {
            let u = (pitch - arc) / seg;
            return Some((s + u * ds, z + u * (z1 - z)));
        }
        arc += seg;
        s = s1;
        z = z1;
        if s > 2.0 * pitch + scale {
            return None;
        }
    }
    Some((s, z))
}

/// Fits the new track's points as functions of `y` (local quadratics of `c` and height),
/// returned in `y` order.
fn fit_track(ctx: &Ctx<'_>, found: &[Point3]) -> Vec<Point3> {
    let mut samples: Vec<(f64, f64, f64)> = found
        .iter()
        .map(|p| (ctx.y(p), ctx.c(p), ctx.surface.frame().height(p)))
        .collect();
    samples.sort_by(|a, b| a.0.total_cmp(&b.0));
    let cs: Vec<(f64, f64)> = samples.iter().map(|s| (s.0, s.1)).collect();
    let hs: Vec<(f64, f64)> = samples.iter().map(|s| (s.0, s.2)).collect();
    samples
        .iter()
        .filter_map(|&(y, _, _)| {
            let c = local_quadratic(&cs, y, ctx.window)?;
            let f = local_quadratic(&hs, y, ctx.window)?;
            Some(ctx.surface.frame().to_world(ctx.st(y, c), f))
        })
        .collect()
}

/// Extends both ends of a run along its fitted direction, projected onto the scan, until the
/// boundary; the ends are cut exactly at it.
fn extend(ctx: &Ctx<'_>, mut run: Vec<Point3>) -> Option<Vec<Point3>> {
    if run.len() < 2 {
        return None;
    }
    let mut tail = extend_end(ctx, &run[run.len() - 2], &run[run.len() - 1]);
    let mut head = extend_end(ctx, &run[1], &run[0]);
    head.reverse();
    head.append(&mut run);
    head.append(&mut tail);
    Some(head)
}

fn extend_end(ctx: &Ctx<'_>, before: &Point3, end: &Point3) -> Vec<Point3> {
    let frame = ctx.surface.frame();
    let mut out = Vec::new();
    let (mut a, mut b) = (ctx.plane(before), ctx.plane(end));
    let mut last = *end;
    let (lo, hi) = ctx.polygon.bounds();
    let limit = (hi[0] - lo[0]).hypot(hi[1] - lo[1]) / ctx.step_m + 8.0;
    for _ in 0..limit.ceil() as usize {
        let d = [b[0] - a[0], b[1] - a[1]];
        let len = d[0].hypot(d[1]);
        if len <= 0.0 {
            break;
        }
        let next = [
            b[0] + d[0] / len * ctx.step_m,
            b[1] + d[1] / len * ctx.step_m,
        ];
        if let Some(u) = ctx.polygon.crossings(b, next).first() {
            let at = [b[0] + u * (next[0] - b[0]), b[1] + u * (next[1] - b[1])];
            if let Some(p) = project(ctx, at, &last) {
                out.push(p);
            }
            return out;
        }
        let Some(p) = project(ctx, next, &last) else {
            break;
        };
        out.push(p);
        last = p;
        a = b;
        b = frame.to_plane(&p);
    }
    out
}

/// The scan surface over plane point `st`: a plane fit to the nearest scan points.
fn project(ctx: &Ctx<'_>, st: [f64; 2], near: &Point3) -> Option<Point3> {
    let frame = ctx.surface.frame();
    let guess = frame.to_world(st, frame.height(near));
    let nn = ctx.tree.knn(&guess, EXTEND_NEIGHBOURS);
    if nn.len() < 3 {
        return None;
    }
    let pts: Vec<Point3> = nn.iter().map(|n| ctx.points[n.index]).collect();
    let centroid = Point3::from(pts.iter().map(|p| p.coords).sum::<Vector3>() / pts.len() as f64);
    let normal = plane_normal(pts.iter())?;
    let along_e3 = normal.dot(&frame.e3);
    if along_e3.abs() < 1e-6 {
        return None;
    }
    // The point over st on the local plane: height f with (P(st, f) − centroid)·n = 0.
    let base = frame.to_world(st, 0.0);
    let f = (centroid - base).dot(&normal) / along_e3;
    Some(frame.to_world(st, f))
}

/// Linear interpolation of a `y`-ordered polyline at `y`.
fn interpolate(ys: &[(f64, Point3)], y: f64) -> Option<Point3> {
    let k = ys.partition_point(|(v, _)| *v < y);
    if k == 0 {
        return ys.first().map(|p| p.1);
    }
    if k >= ys.len() {
        return ys.last().map(|p| p.1);
    }
    let (y0, p0) = ys[k - 1];
    let (y1, p1) = ys[k];
    let u = if y1 > y0 { (y - y0) / (y1 - y0) } else { 0.0 };
    Some(p0 + (p1 - p0) * u)
}

/// Output points along a fitted track polyline (linear between processing points).
fn resample(piece: &[Point3], spacing: PointSpacing) -> Vec<Point3> {
    match spacing {
        PointSpacing::Pitch { step_mm } => {
            let mut out = vec![piece[0]];
            let mut next = step_mm;
            let mut run = 0.0;
            for w in piece.windows(2) {
                let seg = (w[1] - w[0]).norm();
                while seg > 0.0 && run + seg >= next {
                    out.push(w[0] + (w[1] - w[0]) * ((next - run) / seg));
                    next += step_mm;
                }
                run += seg;
            }
            let end = piece[piece.len() - 1];
            if run - (next - step_mm) > 1e-3 * step_mm || out.len() == 1 {
                out.push(end);
            } else if let Some(l) = out.last_mut() {
                *l = end;
            }
            out
        }
        PointSpacing::Chord { .. } => piece.to_vec(),
    }
}
