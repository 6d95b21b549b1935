//! Each point of a contour is marked once: the planned polylines of a contour, carried back from
//! the Job to the work-piece frame (galvo point + height along the zone axis), partition it.
//! Checked independently of the planner's own validation, in space: sample points along every
//! contour (its vertices and points inside each segment) each lie strictly inside exactly one
//! polyline, or at the ends of polylines only (a junction, or the contour's own ends); and no
//! polyline's end lies strictly inside another (which catches an overlap shorter than the
//! sample spacing).
//! Issue 24 point 12: a plan put one point strictly inside two layers. With kerf compensation
//! the line partitioned is the path offset out of the material (`trim_plan::kerf`). The
//! adversarial shapes below (layer-boundary ties, seams at zone changes, cuts on repeated
//! vertices, random contours under both zonings, both lenses, small fields, kerf on and off)
//! are also checked against the planner's own arc-length partition check
//! (`trim_plan::partition`).

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_cell::job::{Job, workpiece_from_galvo};
use trim_geom::{Contour, Path, Point3, Vector3};
use trim_plan::hatch::{HatchSettings, hatch};
use trim_plan::planner::{PlanSettings, plan_with_report};
use trim_plan::zoning::{ZoningMethod, ZoningSettings};
use trim_synth::testing::synthetic_core_path;

/// A point this close (mm) to a polyline is on it; the round trip is exact to ~1e-14 mm.
const ON_MM: f64 = 1e-6;

/// Where samples are taken inside each contour segment (fractions of it).
const FRACTIONS: [f64; 4] = [0.0, 0.25, 0.5, 0.75];

/// The built-in demo part's path (`trimctl run` without a job file).
fn demo_path() -> Path {
    let params = trim_synth::SynthParams {
        scan_points: 2_000,
        cad_points: 2_000,
        ..trim_synth::SynthParams::default()
    };
    trim_synth::generate(&params).expect("demo part").path
}

/// The distance from `p` to the segment `a`–`b` and the parameter of its foot (0 at `a`).
fn to_segment(p: &Point3, a: &Point3, b: &Point3) -> (f64, f64) {
    let d = b - a;
    let len2 = d.norm_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((a + d * t - p).norm(), t)
}

/// How a polyline holds a point: strictly inside it, at one of its ends, or not at all.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Holds {
    Inside,
    End,
    No,
}

fn holds(polyline: &[Point3], p: &Point3) -> Holds {
    let near = |q: &Point3| (q - p).norm() <= ON_MM;
    if near(&polyline[0]) || near(&polyline[polyline.len() - 1]) {
        return Holds::End;
    }
    if polyline
        .windows(2)
        .any(|w| to_segment(p, &w[0], &w[1]).0 <= ON_MM)
    {
        Holds::Inside
    } else {
        Holds::No
    }
}

/// Every violation of "each point in exactly one layer", as text naming the contour, the
/// sample and the (zone, layer) pairs that hold it.
fn partition_violations(path: &Path, job: &Job) -> Vec<String> {
    let mut out = Vec::new();
    for c in path.contours() {
        // The contour's polylines in the work-piece frame, with where they are.
        let polylines: Vec<((usize, usize), Vec<Point3>)> = job
            .zones
            .iter()
            .flat_map(|z| z.layers.iter().map(move |l| (z, l)))
            .flat_map(|(z, l)| {
                l.polylines
                    .iter()
                    .filter(|pl| pl.contour == c.id())
                    .map(move |pl| {
                        let fz = z.frame.z_axis();
                        let pts = pl
                            .points
                            .iter()
                            .zip(&pl.heights_mm)
                            .map(|(xy, h)| workpiece_from_galvo(z, l, *xy) + fz * *h)
                            .collect();
                        ((z.id, l.index), pts)
                    })
            })
            .collect();
        let pts = c.points();
        for (i, w) in pts.windows(2).enumerate() {
            for f in FRACTIONS {
                let s = w[0] + (w[1] - w[0]) * f;
                let held: Vec<((usize, usize), Holds)> = polylines
                    .iter()
                    .map(|(at, pl)| (*at, holds(pl, &s)))
                    .filter(|(_, h)| *h != Holds::No)
                    .collect();
                let inside = held.iter().filter(|(_, h)| *h == Holds::Inside).count();
                let ok = if inside > 0 {
                    held.len() == 1
                } else {
                    !held.is_empty()
                };
                if !ok {
                    out.push(format!(
                        "contour {} at vertex {}{}: held by {held:?} (zone, layer)",
                        c.id(),
                        i,
                        if f > 0.0 {
                            format!(" + {f}")
                        } else {
                            String::new()
                        }
                    ));
                }
            }
        }
        // However short an overlap, one polyline's end lies strictly inside another.
        for (at, pl) in &polylines {
            for end in [pl[0], pl[pl.len() - 1]] {
                let inside: Vec<(usize, usize)> = polylines
                    .iter()
                    .filter(|(_, other)| holds(other, &end) == Holds::Inside)
                    .map(|(o, _)| *o)
                    .collect();
                if !inside.is_empty() {
                    out.push(format!(
                        "contour {}: an end of the polyline in (zone, layer) {at:?} lies strictly inside {inside:?}",
                        c.id()
                    ));
                }
            }
        }
        let last = pts[pts.len() - 1];
        if !polylines
            .iter()
            .any(|(_, pl)| holds(pl, &last) != Holds::No)
        {
            out.push(format!("contour {}: its last point is not planned", c.id()));
        }
    }
    out
}

fn settings_for(method: ZoningMethod) -> PlanSettings {
    PlanSettings {
        zoning: ZoningSettings {
            method,
            ..ZoningSettings::default()
        },
        ..PlanSettings::default()
    }
}

fn check(name: &str, path: &Path, settings: &PlanSettings) {
    let out = plan_with_report(path, settings).expect("plans");
    let v = &out.job.validation;
    assert!(v.passed, "{name}: {:?}", v.violations);
    assert_partitioned(name, path, settings, &out.job);
}

/// The spatial check on the line planned along `path`: the path offset out of the material by
/// kerf compensation (by its own material sides, as `plan_with_report` takes them).
fn assert_partitioned(name: &str, path: &Path, settings: &PlanSettings, job: &Job) {
    let line = trim_plan::kerf::intended_line(path, settings.kerf_offset_mm()).expect("offsets");
    let bad = partition_violations(&line, job);
    assert!(
        bad.is_empty(),
        "{name}: {} points not in exactly one layer, e.g. {:?}",
        bad.len(),
        &bad[..bad.len().min(5)]
    );
}

#[test]
fn the_demo_part_marks_each_point_once() {
    let path = demo_path();
    check("demo, cover", &path, &settings_for(ZoningMethod::Cover));
    check("demo, k-means", &path, &settings_for(ZoningMethod::Kmeans));
}

#[test]
fn seeded_synthetic_cores_mark_each_point_once() {
    for seed in [1, 2, 3, 0x5eed_0060] {
        let path = synthetic_core_path(52, seed);
        check(
            &format!("core seed {seed}, cover"),
            &path,
            &settings_for(ZoningMethod::Cover),
        );
        check(
            &format!("core seed {seed}, k-means"),
            &path,
            &settings_for(ZoningMethod::Kmeans),
        );
    }
}

/// The demo run's plan: the demo part's true (registered) path plus the tracks of its hatched
/// region (0.05 mm pitch, 2 µm chord tolerance, on the scan), as `trimctl run` plans it: hatch
/// tracks split by the incidence limit across the cambered face.
#[test]
fn the_demo_part_with_its_hatched_region_marks_each_point_once() {
    // The demo's own part and scan (`trimctl run`'s parameters): the hatch fit is made on
    // that scan there.
    let case = trim_synth::generate(&trim_synth::SynthParams::default()).expect("demo part");
    let boundary: Vec<Point3> = trim_synth::demo_hatch_boundary()
        .expect("demo boundary")
        .points()
        .iter()
        .map(|p| case.scan_from_cad_point(p))
        .collect();
    let settings = HatchSettings {
        pitch_mm: 0.05,
        chord_tolerance_mm: Some(0.002),
        ..HatchSettings::default()
    };
    let tracks = hatch(&case.scan, &boundary, &settings)
        .expect("hatches")
        .to_path()
        .expect("tracks");
    let mut contours = case.truth.contours().to_vec();
    for (t, c) in tracks.contours().iter().enumerate() {
        contours.push(
            trim_geom::Contour::with_features(
                -1 - t as i64,
                c.points().to_vec(),
                c.features().to_vec(),
            )
            .expect("a track"),
        );
    }
    let path = Path::new(contours).expect("path");
    check(
        "demo + hatch, cover",
        &path,
        &settings_for(ZoningMethod::Cover),
    );
    check(
        "demo + hatch, k-means",
        &path,
        &settings_for(ZoningMethod::Kmeans),
    );
    for telecentric in [false, true] {
        let mut s = settings_for(ZoningMethod::Cover);
        s.field.telecentric = telecentric;
        s.galvo.field_mm = [20.0, 20.0];
        check(
            &format!("demo + hatch, 20 mm field, telecentric {telecentric}"),
            &path,
            &s,
        );
        s.zoning.method = ZoningMethod::Kmeans;
        check(
            &format!("demo + hatch, 20 mm field, k-means, telecentric {telecentric}"),
            &path,
            &s,
        );
    }
}

/// A seeded path of awkward contours: random walks with repeated points, 1e-10 mm steps,
/// 5 mm jumps and features that drift, some closed back onto their first point (never fewer than
/// six points, so no contour retraces itself: that one would be marked twice by definition).
fn awkward_path(seed: u64) -> Path {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut contours = Vec::new();
    for id in 0..rng.random_range(1..12) {
        let m = rng.random_range(2..80);
        let mut p = Point3::new(
            rng.random_range(-30.0..30.0),
            rng.random_range(-30.0..30.0),
            rng.random_range(-3.0..3.0),
        );
        let (mut a, mut b): (f64, f64) = (rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3));
        let (mut points, mut features) = (Vec::new(), Vec::new());
        for _ in 0..m {
            points.push(p);
            features.push(Vector3::new(a.sin(), b.sin(), 1.0).normalize());
            let step = match rng.random_range(0..10) {
                0 => 0.0,
                1 => 1e-10,
                2 => 5.0,
                _ => rng.random_range(0.01..1.5),
            };
            let d = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.6..0.6),
            )
            .normalize();
            p += d * step;
            a += rng.random_range(-0.08..0.08);
            b += rng.random_range(-0.08..0.08);
        }
        if m >= 6 && rng.random_bool(0.3) {
            points.push(points[0]);
            features.push(features[0]);
        }
        if let Ok(c) = Contour::with_features(id, points, features) {
            contours.push(c);
        }
    }
    if contours.is_empty() {
        contours.push(
            Contour::new(
                0,
                vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)],
                Vector3::z(),
            )
            .expect("a segment"),
        );
    }
    Path::new(contours).expect("distinct ids")
}

#[test]
fn seeded_awkward_paths_mark_each_point_once() {
    for seed in 0..40 {
        let path = awkward_path(seed);
        for method in [ZoningMethod::Cover, ZoningMethod::Kmeans] {
            let out = plan_with_report(&path, &settings_for(method)).expect("plans");
            let bad = partition_violations(&path, &out.job);
            assert!(
                bad.is_empty(),
                "seed {seed}, {method:?}: {} points not in exactly one layer, e.g. {:?}",
                bad.len(),
                &bad[..bad.len().min(5)]
            );
        }
    }
}

/// The check itself: a polyline that runs on past a junction, over the start of the next one,
/// is caught.
#[test]
fn an_overlap_between_two_layers_is_caught() {
    let path = synthetic_core_path(8, 1);
    let mut job = plan_with_report(&path, &settings_for(ZoningMethod::Cover))
        .expect("plans")
        .job;
    assert!(partition_violations(&path, &job).is_empty());
    // A junction: polyline A ends where polyline B (same contour) starts.
    let at = |z: usize, l: usize, k: usize, i: usize| {
        let zone = &job.zones[z];
        let layer = &zone.layers[l];
        let pl = &layer.polylines[k];
        workpiece_from_galvo(zone, layer, pl.points[i]) + zone.frame.z_axis() * pl.heights_mm[i]
    };
    let mut index = Vec::new();
    for (z, zone) in job.zones.iter().enumerate() {
        for (l, layer) in zone.layers.iter().enumerate() {
            for (k, pl) in layer.polylines.iter().enumerate() {
                index.push((z, l, k, pl.contour, pl.points.len()));
            }
        }
    }
    let (a, b_first, b_second) = index
        .iter()
        .flat_map(|a| index.iter().map(move |b| (a, b)))
        .find_map(|(&(za, la, ka, ca, na), &(zb, lb, kb, cb, _))| {
            let junction = ca == cb
                && (za, la, ka) != (zb, lb, kb)
                && (at(za, la, ka, na - 1) - at(zb, lb, kb, 0)).norm() < 1e-9;
            junction.then(|| ((za, la, ka), at(zb, lb, kb, 0), at(zb, lb, kb, 1)))
        })
        .expect("a contour split at a junction");
    // A runs on by half of B's first segment.
    let on = b_first + (b_second - b_first) * 0.5;
    let zone = &mut job.zones[a.0];
    let (fx, fy, fz) = (
        zone.frame.x_axis(),
        zone.frame.y_axis(),
        zone.frame.z_axis(),
    );
    let layer = &mut zone.layers[a.1];
    let d = on - Point3::from(layer.focus_point);
    let pl = &mut layer.polylines[a.2];
    pl.points.push([d.dot(&fx), d.dot(&fy)]);
    pl.heights_mm.push(d.dot(&fz));
    let bad = partition_violations(&path, &job);
    assert!(!bad.is_empty(), "an overlap went unseen");
    eprintln!("caught: {:?}", &bad[..bad.len().min(3)]);
}

// ---------------------------------------------------------------------------------------------
// Adversarial inputs for the mechanisms a junction overlap could come from (issue 24 point 12):
// points exactly on layer boundaries (ties), segments lying in a boundary plane, closed
// contours whose seam falls at a zone change, repeated points and cut points on vertices (the
// covering's equal-length atoms, the sectioning's halving), features that turn fast enough to
// make the k-means pieces split, small fields (sections), both zonings, both lenses, kerf on
// and off. Each plan must pass its own partition check (arc length, from the sources its
// round trip confirms) and the spatial check above.
// ---------------------------------------------------------------------------------------------

/// The planner's own partition findings of a plan: every line about a stretch marked twice or
/// not at all.
fn partition_findings(job: &Job) -> Vec<String> {
    const WORDS: [&str; 6] = [
        "marked twice",
        "not marked",
        "runs back",
        "skips its vertex",
        "off the contour",
        "not planned",
    ];
    job.validation
        .violations
        .iter()
        .filter(|l| WORDS.iter().any(|w| l.contains(w)))
        .cloned()
        .collect()
}

/// A ΔH that is a power of two (mm), within the beam's focus length, so heights that are
/// multiples of it sit exactly on layer boundaries.
fn exact_step_mm(settings: &PlanSettings) -> f64 {
    let step = settings
        .layers
        .step_for(settings.beam.focus_half_length_mm())
        .expect("a step");
    2f64.powi(step.log2().floor() as i32)
}

/// The settings the adversarial shapes are planned with: both zonings, both lenses, the
/// default and a small field (so zones are sectioned and pieces halved), kerf on and off.
fn adversarial_settings() -> Vec<(String, PlanSettings)> {
    let mut out = Vec::new();
    for method in [ZoningMethod::Cover, ZoningMethod::Kmeans] {
        for telecentric in [false, true] {
            for field_mm in [None, Some(6.0)] {
                for kerf in [true, false] {
                    let mut s = settings_for(method);
                    s.field.telecentric = telecentric;
                    if let Some(f) = field_mm {
                        s.galvo.field_mm = [f, f];
                    }
                    s.trim.kerf_compensation = kerf;
                    s.layers.step_mm = Some(exact_step_mm(&s));
                    out.push((
                        format!(
                            "{method:?}, telecentric {telecentric}, field {field_mm:?}, kerf {kerf}"
                        ),
                        s,
                    ));
                }
            }
        }
    }
    out
}

/// Plans `path` with every adversarial setting; the plan's own partition findings and the
/// spatial check must both be empty.
fn check_adversarial(name: &str, path: &Path) {
    for (what, settings) in adversarial_settings() {
        let out = plan_with_report(path, &settings).expect("plans");
        let v = &out.job.validation;
        let own = partition_findings(&out.job);
        assert!(
            own.is_empty() && v.double_marked_contours.is_empty(),
            "{name}, {what}: {own:?}"
        );
        assert!(
            v.max_round_trip_error_mm <= 1e-3,
            "{name}, {what}: round trip {}",
            v.max_round_trip_error_mm
        );
        assert_partitioned(&format!("{name}, {what}"), path, &settings, &out.job);
    }
}

/// A staircase along x whose heights are multiples of half of ΔH: vertices on layer
/// boundaries, treads lying in boundary planes, risers crossing several boundaries at once.
fn staircase(step_mm: f64) -> Path {
    let heights = [0.0, 0.0, 1.0, 1.0, 3.0, 2.0, 2.0, 0.5, 4.0, 4.0, 1.5, 0.0];
    let mut points = Vec::new();
    for (i, h) in heights.iter().enumerate() {
        points.push(Point3::new(
            i as f64 * 0.7,
            0.3 * i as f64,
            h * 0.5 * step_mm,
        ));
        // A repeated point on the boundary.
        if i % 3 == 1 {
            points.push(*points.last().expect("a point"));
        }
    }
    let c = Contour::new(1, points, Vector3::z()).expect("a staircase");
    Path::new(vec![c]).expect("a path")
}

#[test]
fn points_and_segments_on_layer_boundaries_mark_each_point_once() {
    for (_, settings) in adversarial_settings().into_iter().take(1) {
        let step = settings.layers.step_mm.expect("exact");
        check_adversarial("staircase on the boundaries", &staircase(step));
    }
}

/// A closed ring of radius `r` (mm) whose feature vectors lean `tilt_deg` outward (a hole's rim
/// on a cone), starting at angle `start_deg`: the features turn a full circle, so the ring is
/// split into zones, and the seam (last point = first) falls wherever `start_deg` puts it. The
/// ring rises and falls `wave_mm` so the layers cut it near the seam too.
fn tilted_ring(id: i64, r: f64, tilt_deg: f64, start_deg: f64, wave_mm: f64, n: usize) -> Contour {
    let tilt = tilt_deg.to_radians();
    let mut points = Vec::with_capacity(n + 1);
    let mut features = Vec::with_capacity(n + 1);
    for k in 0..=n {
        let a = start_deg.to_radians() + std::f64::consts::TAU * (k % n) as f64 / n as f64;
        points.push(Point3::new(
            r * a.cos(),
            r * a.sin(),
            wave_mm * (2.0 * a).sin(),
        ));
        features.push(Vector3::new(
            tilt.sin() * a.cos(),
            tilt.sin() * a.sin(),
            tilt.cos(),
        ));
    }
    Contour::with_features(id, points, features).expect("a ring")
}

#[test]
fn closed_rings_whose_seam_falls_at_a_zone_change_mark_each_point_once() {
    for start_deg in [0.0, 7.5, 22.5, 45.0, 90.0, 133.0] {
        let path = Path::new(vec![
            tilted_ring(1, 3.0, 20.0, start_deg, 0.05, 48),
            tilted_ring(2, 1.0, 12.0, -start_deg, 0.0, 24),
        ])
        .expect("rings");
        check_adversarial(&format!("tilted rings from {start_deg}°"), &path);
    }
}

/// Straight contours of exactly two atoms' length whose vertices sit on the covering's cut
/// points and at their halves (the sectioning's cut), some repeated there; features that
/// turn by more than the limit along them, so the k-means pieces split between vertices.
#[test]
fn cuts_that_fall_on_vertices_and_repeated_points_mark_each_point_once() {
    let atom = trim_plan::cover::ATOM_MAX_LENGTH_MM;
    let mut contours = Vec::new();
    for (id, turn_deg) in [(1i64, 0.0), (2, 12.0), (3, 31.0)] {
        let xs = [
            0.0,
            0.25 * atom,
            0.5 * atom,
            0.5 * atom,
            atom,
            atom,
            atom,
            1.5 * atom,
            2.0 * atom,
        ];
        let points: Vec<Point3> = xs
            .iter()
            .map(|x| Point3::new(*x, 3.0 * id as f64, 0.001 * x))
            .collect();
        let features = xs
            .iter()
            .map(|x| {
                let a = (turn_deg * x / (2.0 * atom)).to_radians();
                Vector3::new(a.sin(), 0.0, a.cos())
            })
            .collect();
        contours.push(Contour::with_features(id, points, features).expect("a contour"));
    }
    check_adversarial("cuts on vertices", &Path::new(contours).expect("a path"));
}

mod property {
    use super::*;
    use proptest::prelude::*;

    /// A contour from proptest's draws: steps (some zero, some tiny), heights snapped to
    /// quarters of ΔH or free, features drifting by up to `turn` per point; closed when asked.
    /// It never retraces itself (that one would be marked twice by definition): x never goes
    /// back, the height changes only over a full step, and a closed one comes back above
    /// every point it passed.
    fn contour_from(
        id: i64,
        steps: &[(f64, f64, f64, u8)],
        turn_rad: f64,
        closed: bool,
        step_mm: f64,
    ) -> Option<Contour> {
        let mut p = Point3::new(0.0, 3.0 * id as f64, 0.0);
        let (mut a, mut b) = (0.0f64, 0.0f64);
        let (mut points, mut features) = (Vec::new(), Vec::new());
        for (i, &(dx, dy, dz, kind)) in steps.iter().enumerate() {
            points.push(p);
            features.push(Vector3::new(a.sin(), b.sin(), 1.0).normalize());
            let scale = match kind % 8 {
                0 => 0.0,
                1 => 1e-10,
                2 => 2.5,
                _ => 0.6,
            };
            p += Vector3::new(dx.abs() + 0.05, dy, 0.0) * scale;
            // Heights on quarter steps (layer boundaries and their middles) or anywhere.
            if scale >= 0.6 {
                p.z = if kind % 2 == 0 {
                    (dz / (0.25 * step_mm)).round() * 0.25 * step_mm
                } else {
                    dz
                };
            }
            a += turn_rad * ((i % 5) as f64 - 2.0) / 2.0;
            b += turn_rad * dy.signum() * 0.5;
        }
        if closed && points.len() >= 6 {
            let above = points.iter().map(|q| q.y).fold(f64::NEG_INFINITY, f64::max) + 1.0;
            let (first, last) = (points[0], points[points.len() - 1]);
            let (f_first, f_last) = (features[0], features[features.len() - 1]);
            points.extend([
                Point3::new(last.x, above, last.z),
                Point3::new(first.x, above, first.z),
                first,
            ]);
            features.extend([f_last, f_first, f_first]);
        }
        Contour::with_features(id, points, features).ok()
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

        /// Random contours under every adversarial setting: the plan's own partition check
        /// and the spatial check find nothing.
        #[test]
        fn random_contours_mark_each_point_once(
            contours in proptest::collection::vec(
                (
                    proptest::collection::vec(
                        (0.0..1.0f64, -0.3..0.3f64, -0.4..0.4f64, any::<u8>()),
                        2..40,
                    ),
                    0.0..0.15f64,
                    any::<bool>(),
                ),
                1..4,
            ),
        ) {
            let step_mm = exact_step_mm(&settings_for(ZoningMethod::Cover));
            let built: Vec<Contour> = contours
                .iter()
                .enumerate()
                .filter_map(|(i, (steps, turn, closed))| {
                    contour_from(i as i64 + 1, steps, *turn, *closed, step_mm)
                })
                .collect();
            prop_assume!(!built.is_empty());
            let path = Path::new(built).expect("distinct ids");
            check_adversarial("random", &path);
        }
    }
}
