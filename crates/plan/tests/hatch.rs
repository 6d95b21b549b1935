//! Surface hatching on seeded synthetic surfaces with 10 µm noise: a cylinder, a saddle, a
//! twisted cambered blade-like patch and the top face of a scanned synthetic core.
//!
//! Everything is checked against the *analytic* surface, independently of how the tracks were
//! built: neighbour spacing is the length of the straight chord between a track point and the
//! foot on the next track, subdivided and projected onto the true surface (a path across the
//! surface); coverage is the distance from noise-free surface samples inside the boundary to the
//! nearest track segment; the boundary error is the distance of track points outside the
//! boundary's parameter polygon, mapped back through the parametrisation.
//!
//! `cargo test -p trim-plan --test hatch -- --nocapture` prints the slab-vs-default table.
#![expect(
    clippy::unwrap_used,
    reason = "test fixtures: a fixture that fails to build is a failed test"
)]

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{KdTree, Point3, PointCloud, Vector3};
use trim_plan::hatch::{Hatch, HatchError, HatchMethod, HatchSettings, TrackKind, hatch, measure};
use trim_synth::{SynthParams, design_point, generate};

/// Scan noise per coordinate, mm.
const NOISE_MM: f64 = 0.01;
/// Acceptance: mean spacing within 1 % of the pitch.
const MEAN_TOL: f64 = 0.01;
/// Acceptance: spacing CV.
const CV_MAX: f64 = 0.03;
/// Acceptance: boundary error, mm.
const BOUNDARY_TOL_MM: f64 = 0.02;

/// A parametric test surface `X(u, v)` (u, v in mm, near-isometric).
struct Surf {
    name: &'static str,
    map: Box<dyn Fn(f64, f64) -> Point3 + Sync>,
    /// The boundary polygon in (u, v).
    polygon_uv: Vec<[f64; 2]>,
    /// The sampled (u, v) box: the polygon's box plus a margin.
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Surf {
    fn x(&self, uv: [f64; 2]) -> Point3 {
        (self.map)(uv[0], uv[1])
    }

    /// Gauss–Newton projection of `p` onto the surface, from `guess` (u, v).
    fn project(&self, p: &Point3, guess: [f64; 2]) -> ([f64; 2], Point3) {
        let mut uv = guess;
        let e = 1e-5;
        for _ in 0..20 {
            let x = self.x(uv);
            let xu = (self.x([uv[0] + e, uv[1]]) - self.x([uv[0] - e, uv[1]])) / (2.0 * e);
            let xv = (self.x([uv[0], uv[1] + e]) - self.x([uv[0], uv[1] - e])) / (2.0 * e);
            let r = p - x;
            let (a, b, c) = (xu.dot(&xu), xu.dot(&xv), xv.dot(&xv));
            let (g0, g1) = (xu.dot(&r), xv.dot(&r));
            let det = a * c - b * b;
            let du = (c * g0 - b * g1) / det;
            let dv = (a * g1 - b * g0) / det;
            uv = [uv[0] + du, uv[1] + dv];
            if du.abs() + dv.abs() < 1e-12 {
                break;
            }
        }
        (uv, self.x(uv))
    }

    /// `n` noisy scan points over the box, seeded.
    fn cloud(&self, n: usize, seed: u64) -> PointCloud {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let pts = (0..n)
            .map(|_| {
                let uv = [
                    rng.random_range(self.lo[0]..self.hi[0]),
                    rng.random_range(self.lo[1]..self.hi[1]),
                ];
                self.x(uv) + gaussian3(&mut rng) * NOISE_MM
            })
            .collect();
        PointCloud::new(pts).unwrap()
    }

    /// The boundary on the surface: polygon edges sampled every 0.2 mm, closed.
    fn boundary(&self) -> Vec<Point3> {
        let mut out = Vec::new();
        let n = self.polygon_uv.len();
        for k in 0..n {
            let (a, b) = (self.polygon_uv[k], self.polygon_uv[(k + 1) % n]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            let m = (len / 0.2).ceil() as usize;
            for j in 0..m {
                let u = j as f64 / m as f64;
                out.push(self.x([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])]));
            }
        }
        out.push(out[0]);
        out
    }
}

fn gaussian3(rng: &mut impl Rng) -> Vector3 {
    let mut g = || {
        let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    Vector3::new(g(), g(), g())
}

fn inside_uv(poly: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a[1] > p[1]) != (b[1] > p[1])
            && p[0] < a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
        {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// A hexagon-like convex region in (u, v), scaled.
fn hexagon(scale: f64) -> Vec<[f64; 2]> {
    [
        [-10.0, -9.0],
        [9.0, -10.0],
        [10.5, 2.0],
        [6.0, 10.0],
        [-7.0, 10.5],
        [-10.5, 1.0],
    ]
    .iter()
    .map(|p| [p[0] * scale, p[1] * scale])
    .collect()
}

fn boxed(polygon_uv: Vec<[f64; 2]>, margin: f64) -> ([f64; 2], [f64; 2]) {
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in &polygon_uv {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    (
        [lo[0] - margin, lo[1] - margin],
        [hi[0] + margin, hi[1] + margin],
    )
}

fn cylinder() -> Surf {
    let r = 15.0;
    let polygon_uv = hexagon(1.0);
    let (lo, hi) = boxed(polygon_uv.clone(), 1.5);
    Surf {
        name: "cylinder R15",
        map: Box::new(move |u, v| Point3::new(r * (u / r).sin(), v, r * (u / r).cos())),
        polygon_uv,
        lo,
        hi,
    }
}

fn saddle() -> Surf {
    let polygon_uv = hexagon(1.0);
    let (lo, hi) = boxed(polygon_uv.clone(), 1.5);
    Surf {
        name: "saddle R25",
        map: Box::new(|u, v| Point3::new(u, v, (u * u - v * v) / 50.0)),
        polygon_uv,
        lo,
        hi,
    }
}

fn blade() -> Surf {
    let polygon_uv = hexagon(1.0);
    let (lo, hi) = boxed(polygon_uv.clone(), 1.5);
    Surf {
        name: "twisted blade",
        map: Box::new(|u, v| {
            let theta = (30.0_f64).to_radians() * v / 24.0;
            let camber = 3.0 * (1.0 - (u / 15.0).powi(2));
            let (s, c) = theta.sin_cos();
            Point3::new(u * c - camber * s, v, u * s + camber * c)
        }),
        polygon_uv,
        lo,
        hi,
    }
}

/// The top face of the synthetic core, deformed and re-posed as scanned; the region lies
/// between the slot ends and the end holes (u ∈ [−13, 13], v ∈ [−33.3, −29]), at least 1 mm
/// from every hole wall (a wall within the fit radius of the boundary biases the height field).
fn core() -> (Surf, PointCloud) {
    let params = SynthParams {
        seed: 7,
        noise_mm: NOISE_MM,
        outlier_fraction: 0.0,
        dropouts: 0,
        scan_points: 300_000,
        cad_points: 1000,
        ..SynthParams::default()
    };
    let case = generate(&params).unwrap();
    let top = trim_synth::THICKNESS_MM / 2.0;
    let (sfc, def) = (case.scan_from_cad_true, case.deformation);
    let map = move |u: f64, v: f64| sfc * def.apply(&design_point(u, v, top));
    let polygon_uv = vec![
        [-13.0, -33.3],
        [13.0, -33.3],
        [13.0, -29.8],
        [9.0, -29.0],
        [-11.0, -29.0],
        [-13.0, -30.0],
    ];
    let (lo, hi) = boxed(polygon_uv.clone(), 0.5);
    let surf = Surf {
        name: "core top face",
        map: Box::new(map),
        polygon_uv,
        lo,
        hi,
    };
    // The scan points near the region (the face and whatever else the scanner saw there).
    let b = surf.boundary();
    let centre = b.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / b.len() as f64;
    let pts: Vec<Point3> = case
        .scan
        .points()
        .iter()
        .filter(|p| (p.coords - centre).norm() < 20.0)
        .copied()
        .collect();
    (surf, PointCloud::new(pts).unwrap())
}

/// Independent measurements against the analytic surface.
struct Truth {
    spacing: Vec<f64>,
    coverage: f64,
    max_gap_mm: f64,
    boundary_error_mm: f64,
}

fn truth(surf: &Surf, h: &Hatch) -> Truth {
    let pitch = h.pitch_mm;
    // Track points back in (u, v).
    let guess = |p: &Point3| -> [f64; 2] {
        // Nearest of a coarse lattice, then Gauss–Newton.
        let mut best = ([0.0, 0.0], f64::INFINITY);
        let n = 40;
        for i in 0..=n {
            for j in 0..=n {
                let uv = [
                    surf.lo[0] + (surf.hi[0] - surf.lo[0]) * i as f64 / n as f64,
                    surf.lo[1] + (surf.hi[1] - surf.lo[1]) * j as f64 / n as f64,
                ];
                let d = (surf.x(uv) - p).norm_squared();
                if d < best.1 {
                    best = (uv, d);
                }
            }
        }
        best.0
    };
    let mut levels: Vec<Vec<&[Point3]>> = Vec::new();
    for t in h.hatch_tracks() {
        if let TrackKind::Hatch { level } = t.kind {
            if levels.len() <= level {
                levels.resize(level + 1, Vec::new());
            }
            levels[level].push(&t.points);
        }
    }
    let mut spacing = Vec::new();
    for k in 0..levels.len().saturating_sub(1) {
        for line in &levels[k] {
            let mut uv = guess(&line[0]);
            for p in line.iter() {
                // Foot on the next level by 3D point-segment distance.
                let mut best: Option<(f64, Point3, bool)> = None;
                for next in &levels[k + 1] {
                    for (j, w) in next.windows(2).enumerate() {
                        let ab = w[1] - w[0];
                        let t = (p - w[0]).dot(&ab) / ab.norm_squared().max(1e-300);
                        let at_end = (j == 0 && t <= 0.0) || (j + 2 == next.len() && t >= 1.0);
                        let q = w[0] + ab * t.clamp(0.0, 1.0);
                        let d = (q - p).norm();
                        if best.is_none_or(|b| d < b.0) {
                            best = Some((d, q, at_end));
                        }
                    }
                }
                let Some((d, q, at_end)) = best else { continue };
                if at_end || d > 2.0 * pitch {
                    continue;
                }
                // The chord subdivided and projected onto the true surface.
                let (uv0, mut prev) = surf.project(p, uv);
                uv = uv0;
                let mut g = uv0;
                let mut len = 0.0;
                for s in 1..=16 {
                    let x = p + (q - p) * (s as f64 / 16.0);
                    let (g1, y) = surf.project(&x, g);
                    g = g1;
                    len += (y - prev).norm();
                    prev = y;
                }
                spacing.push(len);
            }
        }
    }
    // Coverage on noise-free samples inside the boundary.
    let mut all = Vec::new();
    let mut owner = Vec::new();
    for (k, t) in h.tracks.iter().enumerate() {
        for (i, p) in t.points.iter().enumerate() {
            all.push(*p);
            owner.push((k, i));
        }
    }
    let tree = KdTree::build(&all);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(99);
    let (mut covered, mut total, mut max_gap) = (0usize, 0usize, 0.0_f64);
    while total < 20_000 {
        let uv = [
            rng.random_range(surf.lo[0]..surf.hi[0]),
            rng.random_range(surf.lo[1]..surf.hi[1]),
        ];
        if !inside_uv(&surf.polygon_uv, uv) {
            continue;
        }
        let x = surf.x(uv);
        let mut d = f64::INFINITY;
        for n in tree.knn(&x, 4) {
            let (k, i) = owner[n.index];
            let t = &h.tracks[k].points;
            for j in [i.saturating_sub(1), i] {
                if j + 1 < t.len() {
                    let ab = t[j + 1] - t[j];
                    let s = ((x - t[j]).dot(&ab) / ab.norm_squared().max(1e-300)).clamp(0.0, 1.0);
                    d = d.min((x - (t[j] + ab * s)).norm());
                }
            }
        }
        total += 1;
        if d <= 0.5 * pitch * 1.05 {
            covered += 1;
        }
        max_gap = max_gap.max(d);
    }
    // Boundary error: track points mapped back into (u, v), outside the polygon → distance to
    // its edges (a near-isometric parametrisation, so mm).
    let mut boundary_error: f64 = 0.0;
    for t in &h.tracks {
        let mut uv = guess(&t.points[0]);
        for p in &t.points {
            uv = surf.project(p, uv).0;
            if !inside_uv(&surf.polygon_uv, uv) {
                let n = surf.polygon_uv.len();
                let d = (0..n)
                    .map(|k| {
                        let (a, b) = (surf.polygon_uv[k], surf.polygon_uv[(k + 1) % n]);
                        let (a3, b3) = (surf.x(a), surf.x(b));
                        let _ = (a3, b3);
                        let ab = [b[0] - a[0], b[1] - a[1]];
                        let s = (((uv[0] - a[0]) * ab[0] + (uv[1] - a[1]) * ab[1])
                            / (ab[0] * ab[0] + ab[1] * ab[1]))
                            .clamp(0.0, 1.0);
                        (uv[0] - a[0] - s * ab[0]).hypot(uv[1] - a[1] - s * ab[1])
                    })
                    .fold(f64::INFINITY, f64::min);
                boundary_error = boundary_error.max(d);
            }
        }
    }
    Truth {
        spacing,
        coverage: covered as f64 / total as f64,
        max_gap_mm: max_gap,
        boundary_error_mm: boundary_error,
    }
}

fn stats(v: &[f64]) -> (f64, f64, f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    let min = v.iter().copied().fold(f64::INFINITY, f64::min);
    let max = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (mean, sd / mean, min, max)
}

/// Runs both methods on a surface, prints the table row, and checks the default.
fn check(surf: &Surf, cloud: &PointCloud, pitch: f64, angle_deg: f64) {
    let boundary = surf.boundary();
    for method in [HatchMethod::Geodesic, HatchMethod::Slab] {
        let settings = HatchSettings {
            pitch_mm: pitch,
            angle_deg,
            method,
            step_mm: Some(0.1),
            ..HatchSettings::default()
        };
        let start = std::time::Instant::now();
        let h = hatch(cloud, &boundary, &settings).unwrap();
        let elapsed = start.elapsed();
        let report = measure(&h);
        let t = truth(surf, &h);
        let (mean, cv, min, max) = stats(&t.spacing);
        eprintln!(
            "| {} | {method} | {} tracks | true spacing mean {mean:.4} (err {:+.2} %) CV {:.2} % \
             min {min:.4} max {max:.4} (n {}) | measure(): mean {:.4} CV {:.2} % | coverage \
             {:.4} (max gap {:.4}) measure(): {:.4} / hatch only {:.4} | boundary {:.2e} mm | \
             {:.0} ms (debug) |",
            surf.name,
            report.hatch_tracks,
            100.0 * (mean / pitch - 1.0),
            100.0 * cv,
            t.spacing.len(),
            report.spacing.mean_mm,
            100.0 * report.spacing.cv,
            t.coverage,
            t.max_gap_mm,
            report.coverage,
            report.coverage_hatch_only,
            t.boundary_error_mm,
            elapsed.as_secs_f64() * 1e3,
        );
        // Every point carries a unit normal close to the true one (toward +e3).
        for tr in &h.tracks {
            assert_eq!(tr.points.len(), tr.normals.len());
            assert!(tr.normals.iter().all(|n| (n.norm() - 1.0).abs() < 1e-9));
        }
        assert!(
            t.boundary_error_mm <= BOUNDARY_TOL_MM,
            "{} {method}: boundary error {}",
            surf.name,
            t.boundary_error_mm
        );
        if method == HatchMethod::Geodesic {
            assert!(
                (mean / pitch - 1.0).abs() <= MEAN_TOL,
                "{}: mean {mean} vs pitch {pitch}",
                surf.name
            );
            assert!(cv <= CV_MAX, "{}: CV {cv}", surf.name);
            assert!(
                t.coverage >= 1.0,
                "{}: coverage {} (max gap {})",
                surf.name,
                t.coverage,
                t.max_gap_mm
            );
            assert!(report.boundary_error_mm <= BOUNDARY_TOL_MM);
            // Serpentine: consecutive hatch tracks start near where the previous one ended.
            let tracks: Vec<_> = h.hatch_tracks().collect();
            for w in tracks.windows(2) {
                let (end, start) = (w[0].points.last().unwrap(), w[1].points[0]);
                let other = w[1].points.last().unwrap();
                assert!((start - end).norm() <= (other - end).norm() + 1e-9);
            }
        }
    }
}

#[test]
fn cylinder_tracks_are_equally_spaced() {
    let s = cylinder();
    check(&s, &s.cloud(60_000, 1), 1.0, 30.0);
}

#[test]
fn saddle_tracks_are_equally_spaced() {
    let s = saddle();
    check(&s, &s.cloud(60_000, 2), 1.0, 0.0);
}

#[test]
fn blade_tracks_are_equally_spaced() {
    let s = blade();
    check(&s, &s.cloud(60_000, 3), 1.0, 90.0);
}

#[test]
fn core_face_tracks_are_equally_spaced() {
    let (s, cloud) = core();
    check(&s, &cloud, 0.4, 0.0);
}

#[test]
fn path_output_matches_the_contract() {
    let s = saddle();
    let cloud = s.cloud(20_000, 4);
    let settings = HatchSettings {
        pitch_mm: 2.0,
        chord_tolerance_mm: Some(0.005),
        ..HatchSettings::default()
    };
    let h = hatch(&cloud, &s.boundary(), &settings).unwrap();
    let path = h.to_path().unwrap();
    assert_eq!(path.len(), h.tracks.len());
    for (c, t) in path.contours().iter().zip(&h.tracks) {
        assert_eq!(c.id(), t.id);
    }
    assert!(matches!(h.tracks.last().unwrap().kind, TrackKind::Outline));
    // Chord mode: straight-ish saddle tracks need far fewer points than a 0.05 mm step.
    let n: usize = h.hatch_tracks().map(|t| t.points.len()).sum();
    assert!(n < 2000, "{n} points");
}

/// A boundary is a polygon: without its repeated first point (a gap of one 0.2 mm sample step)
/// it is closed implicitly and hatched exactly as the closed ring.
#[test]
fn a_boundary_without_its_closing_point_is_closed_implicitly() {
    let s = saddle();
    let cloud = s.cloud(10_000, 5);
    let b = s.boundary();
    let open_by_one = &b[..b.len() - 1];
    assert!((open_by_one[open_by_one.len() - 1] - b[0]).norm() > 0.1);
    let ok = HatchSettings::with_pitch(1.0);
    let closed = hatch(&cloud, &b, &ok).unwrap();
    let implicit = hatch(&cloud, open_by_one, &ok).unwrap();
    assert!(closed.tracks.len() > 5);
    assert_eq!(implicit.tracks.len(), closed.tracks.len());
    for (a, c) in implicit.tracks.iter().zip(&closed.tracks) {
        assert_eq!(a.points, c.points);
    }
}

#[test]
fn bad_input_is_refused() {
    let s = saddle();
    let cloud = s.cloud(10_000, 5);
    let b = s.boundary();
    let ok = HatchSettings::with_pitch(1.0);
    let empty = PointCloud::new(Vec::new()).unwrap();
    assert!(matches!(hatch(&empty, &b, &ok), Err(HatchError::EmptyScan)));
    assert!(matches!(
        hatch(&cloud, &b[..3], &ok),
        Err(HatchError::BoundaryTooShort { .. } | HatchError::BoundaryNotClosed { .. })
    ));
    // Half the ring: an open curve, its gap far longer than its 0.2 mm point spacing.
    assert!(matches!(
        hatch(&cloud, &b[..b.len() / 2], &ok),
        Err(HatchError::BoundaryNotClosed { .. })
    ));
    let lifted: Vec<Point3> = b.iter().map(|p| p + Vector3::z() * 1.0).collect();
    assert!(matches!(
        hatch(&cloud, &lifted, &ok),
        Err(HatchError::BoundaryOffSurface { .. })
    ));
    let mut nan = b.clone();
    nan[4].x = f64::NAN;
    assert!(matches!(
        hatch(&cloud, &nan, &ok),
        Err(HatchError::NonFinite { index: 4, .. })
    ));
    for pitch in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            hatch(&cloud, &b, &HatchSettings::with_pitch(pitch)),
            Err(HatchError::InvalidSetting { .. })
        ));
    }
    for method in [HatchMethod::Geodesic, HatchMethod::Slab] {
        let wide = HatchSettings {
            method,
            ..HatchSettings::with_pitch(100.0)
        };
        assert!(matches!(
            hatch(&cloud, &b, &wide),
            Err(HatchError::PitchTooLarge { .. })
        ));
    }
    // A boundary away from the scan.
    let far: Vec<Point3> = b.iter().map(|p| p + Vector3::x() * 200.0).collect();
    assert!(hatch(&cloud, &far, &ok).is_err());
}

/// A pitch, step or grid far below a spot is refused by its key before anything is allocated:
/// `pitch_mm = 1e-4`, `step_mm = 1e-6` and `grid_mm = 1e-4` aborted on memory (exit 134); what
/// a 1 µm setting would give a 21 mm region (10⁸ points or grid nodes) is refused with the count.
#[test]
fn settings_that_would_not_fit_in_memory_are_refused_by_key() {
    let s = saddle();
    let cloud = s.cloud(10_000, 5);
    let b = s.boundary();
    let refused = |settings: HatchSettings, key: &str, count: &str| {
        let t = std::time::Instant::now();
        let Err(e) = hatch(&cloud, &b, &settings) else {
            panic!("{key}: {settings:?} was not refused");
        };
        let e = e.to_string();
        assert!(e.contains(key) && e.contains(count), "{key}: {e}");
        assert!(t.elapsed().as_secs_f64() < 20.0, "{key}: {:?}", t.elapsed());
    };
    for pitch in [1e-4, 1e-5, 1e-6] {
        refused(HatchSettings::with_pitch(pitch), "hatch.pitch_mm", "1 µm");
    }
    let with = |step_mm: Option<f64>, grid_mm: Option<f64>| HatchSettings {
        step_mm,
        grid_mm,
        ..HatchSettings::with_pitch(0.5)
    };
    for step in [1e-6, 1e-7] {
        refused(with(Some(step), None), "hatch.step_mm", "1 µm");
    }
    refused(with(None, Some(1e-4)), "hatch.grid_mm", "1 µm");
    // At 1 µm each: refused by count.
    refused(
        HatchSettings::with_pitch(1e-3),
        "hatch.pitch_mm",
        "a region may have",
    );
    refused(
        HatchSettings {
            step_mm: Some(1e-3),
            ..HatchSettings::with_pitch(0.05)
        },
        "hatch.step_mm",
        "a region may have",
    );
    refused(with(None, Some(1e-3)), "hatch.grid_mm", "a region may have");
}

/// A boundary that crosses itself encloses no one region: it is refused naming its crossing
/// edges, not as a grid of 10¹⁸ nodes (a figure eight's halves cancel in its area, so the scan
/// spacing worked out from it was 10⁻⁹ mm). A step longer than a third of the outline, which
/// left the outline as its start twice, is refused naming `hatch.step_mm`.
#[test]
fn a_boundary_crossing_itself_and_a_step_longer_than_the_outline_are_refused_by_what_they_are() {
    let s = saddle();
    let cloud = s.cloud(10_000, 5);
    let eight: Vec<Point3> = (0..=200)
        .map(|i| {
            let t = f64::from(i % 200) / 200.0 * std::f64::consts::TAU;
            s.x([6.0 * t.sin(), 6.0 * t.sin() * t.cos()])
        })
        .collect();
    for method in [HatchMethod::Geodesic, HatchMethod::Slab] {
        let settings = HatchSettings {
            method,
            ..HatchSettings::with_pitch(0.5)
        };
        let Err(e) = hatch(&cloud, &eight, &settings) else {
            panic!("{method:?}: the figure eight was hatched");
        };
        assert!(
            matches!(e, HatchError::BoundaryCrossesItself { .. }),
            "{method:?}: {e}"
        );
        let e = e.to_string();
        assert!(
            e.contains("crosses itself") && e.contains("from point"),
            "{e}"
        );
    }
    let b = s.boundary();
    let perimeter: f64 = b.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    let with_step = |step_mm: f64, outline: bool| HatchSettings {
        step_mm: Some(step_mm),
        outline,
        ..HatchSettings::with_pitch(0.5)
    };
    for step in [perimeter / 2.0, 1e300] {
        let e = hatch(&cloud, &b, &with_step(step, true))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("hatch.step_mm") && e.contains("outline"),
            "{step}: {e}"
        );
    }
    // Without the outline, or with a step a third of it, the tracks are planned.
    hatch(&cloud, &b, &with_step(perimeter / 2.0, false)).unwrap();
    let h = hatch(&cloud, &b, &with_step(perimeter / 3.5, true)).unwrap();
    let outline = h
        .tracks
        .iter()
        .find(|t| t.kind == TrackKind::Outline)
        .unwrap();
    assert!(outline.points.len() >= 4, "{}", outline.points.len());
}
