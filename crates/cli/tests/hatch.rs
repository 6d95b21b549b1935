//! `trimctl hatch` through the built binary: a seeded noisy cylinder patch, both methods, the
//! output contract, and refusals of bad input naming the file.
#![expect(
    clippy::unwrap_used,
    reason = "fixture helpers: a fixture that fails to build is a failed test"
)]

use std::path::{Path as FsPath, PathBuf};
use std::process::{Command, Output};

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::formats::{PlyEncoding, read_path, write_path, write_ply};
use trim_geom::{Contour, Path, Point3, PointCloud, Vector3};

const RADIUS_MM: f64 = 15.0;

fn on_cylinder(u: f64, v: f64) -> Point3 {
    Point3::new(
        RADIUS_MM * (u / RADIUS_MM).sin(),
        v,
        RADIUS_MM * (u / RADIUS_MM).cos(),
    )
}

/// A noisy (10 µm) cylinder patch and a closed square-ish boundary on it.
fn fixture(dir: &FsPath) -> (PathBuf, PathBuf) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let pts: Vec<Point3> = (0..30_000)
        .map(|_| {
            let p = on_cylinder(rng.random_range(-9.0..9.0), rng.random_range(-9.0..9.0));
            p + Vector3::new(
                rng.random_range(-0.017..0.017),
                rng.random_range(-0.017..0.017),
                rng.random_range(-0.017..0.017),
            )
        })
        .collect();
    let scan = dir.join("scan.ply");
    write_ply(
        &scan,
        &PointCloud::new(pts).unwrap(),
        PlyEncoding::BinaryLittleEndian,
    )
    .unwrap();
    let corners = [[-7.0, -7.0], [7.0, -6.0], [6.5, 7.0], [-7.0, 6.0]];
    let mut ring = Vec::new();
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        for j in 0..50 {
            let t = f64::from(j) / 50.0;
            ring.push(on_cylinder(
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
            ));
        }
    }
    ring.push(ring[0]);
    let boundary = dir.join("boundary.csv");
    write_boundary(&boundary, vec![ring]);
    (scan, boundary)
}

fn write_boundary(file: &FsPath, rings: Vec<Vec<Point3>>) {
    let contours = rings
        .into_iter()
        .enumerate()
        .map(|(k, r)| Contour::new(k as i64 + 1, r, Vector3::z()).unwrap())
        .collect();
    write_path(file, &Path::new(contours).unwrap()).unwrap();
}

fn trimctl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_trimctl"))
        .arg("hatch")
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &FsPath) -> &str {
    p.to_str().unwrap()
}

#[test]
fn hatches_a_cylinder_patch() {
    let dir = tempfile::tempdir().unwrap();
    let (scan, boundary) = fixture(dir.path());
    for method in ["geodesic", "slab"] {
        let out = dir.path().join(format!("{method}.csv"));
        let svg = dir.path().join(format!("{method}.svg"));
        let o = trimctl(&[
            "--scan",
            s(&scan),
            "--boundary",
            s(&boundary),
            "--pitch",
            "0.8",
            "--angle",
            "20",
            "--method",
            method,
            "--out",
            s(&out),
            "--svg",
            s(&svg),
        ]);
        let stdout = String::from_utf8(o.stdout).unwrap();
        assert!(
            o.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        for key in ["tracks:", "spacing:", "coverage:", "boundary:", "time:"] {
            assert!(stdout.contains(key), "{stdout}");
        }
        let path = read_path(&out).unwrap();
        assert!(path.len() > 15, "{} tracks", path.len());
        // The normal of a cylinder about Y is radial in X–Z. The paper's posture
        // V = P_sa × P_se (slab) follows the noisy track geometry; the fitted normal does not.
        let mut worst_deg: f64 = 0.0;
        for c in path.contours() {
            for (p, n) in c.points().iter().zip(c.features()) {
                let radial = Vector3::new(p.x, 0.0, p.z).normalize();
                assert!((n.norm() - 1.0).abs() < 1e-9);
                let e = n.dot(&radial).clamp(-1.0, 1.0).acos().to_degrees();
                worst_deg = worst_deg.max(e);
            }
        }
        eprintln!("{method}: worst normal error {worst_deg:.3}°");
        let limit_deg = if method == "geodesic" { 2.0 } else { 30.0 }; // slab measured 22.5°
        assert!(worst_deg < limit_deg, "{method}: {worst_deg}°");
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.starts_with("<svg") && text.contains("<line"));
    }
}

/// A boundary is a polygon: a file whose last row is one sample step (0.28 mm) short of its
/// first is closed implicitly and hatched exactly like the same ring with the first row
/// repeated.
#[test]
fn a_boundary_without_its_closing_row_is_closed_implicitly() {
    let dir = tempfile::tempdir().unwrap();
    let (scan, boundary) = fixture(dir.path());
    let mut ring = read_path(&boundary).unwrap().contours()[0]
        .points()
        .to_vec();
    assert_eq!(ring.first(), ring.last());
    ring.pop();
    let gap = (ring[ring.len() - 1] - ring[0]).norm();
    assert!(gap > 0.25, "one sample step: {gap}");
    let open_by_one = dir.path().join("open_by_one.csv");
    write_boundary(&open_by_one, vec![ring]);
    let hatched = |b: &FsPath, name: &str| {
        let out = dir.path().join(name);
        let o = trimctl(&[
            "--scan",
            s(&scan),
            "--boundary",
            s(b),
            "--pitch",
            "0.8",
            "--out",
            s(&out),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out).unwrap()
    };
    let closed = hatched(&boundary, "closed.csv");
    assert!(closed.lines().count() > 100);
    assert_eq!(hatched(&open_by_one, "implicit.csv"), closed);
}

/// Runs a bad case: exit 1, nothing on stdout, the message on stderr contains `needle`.
fn refused(args: &[&str], needle: &str) {
    let o = trimctl(args);
    let stderr = String::from_utf8(o.stderr).unwrap();
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(o.stdout.is_empty());
    assert!(stderr.contains(needle), "expected {needle:?} in {stderr}");
}

#[test]
fn refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let (scan, boundary) = fixture(dir.path());
    let out = dir.path().join("out.csv");
    let run = |b: &FsPath, pitch: &str, needle: &str| {
        refused(
            &[
                "--scan",
                s(&scan),
                "--boundary",
                s(b),
                "--pitch",
                pitch,
                "--out",
                s(&out),
            ],
            needle,
        );
    };
    // Open boundary.
    let open = dir.path().join("open.csv");
    let ring: Vec<Point3> = (0..10)
        .map(|k| on_cylinder(f64::from(k) * 0.5, 0.0))
        .chain((0..10).map(|k| on_cylinder(5.0, f64::from(k) * 0.5)))
        .collect();
    write_boundary(&open, vec![ring.clone()]);
    run(&open, "1", "open.csv");
    run(&open, "1", "not closed");
    // The message says why: the gap against the point spacing.
    run(&open, "1", "longest edge (0.5000 mm)");
    // Two contours.
    let two = dir.path().join("two.csv");
    let mut closed = ring.clone();
    closed.push(ring[0]);
    write_boundary(&two, vec![closed.clone(), closed]);
    run(&two, "1", "exactly one closed contour");
    // Pitch out of range.
    run(&boundary, "0", "pitch");
    run(&boundary, "100", "larger than the region");
    // Off the surface.
    let off = dir.path().join("off.csv");
    let lifted = read_path(&boundary).unwrap().contours()[0]
        .points()
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 2.0))
        .collect();
    write_boundary(&off, vec![lifted]);
    run(&off, "1", "off the scanned surface");
    // A scan with a NaN on line 3: the reader names the file and line.
    let bad_scan = dir.path().join("bad.xyz");
    std::fs::write(&bad_scan, "0 0 0\n1 0 0\nnan 1 0\n0 1 0\n").unwrap();
    refused(
        &[
            "--scan",
            s(&bad_scan),
            "--boundary",
            s(&boundary),
            "--pitch",
            "1",
            "--out",
            s(&out),
        ],
        "bad.xyz",
    );
    // Empty scan.
    let empty = dir.path().join("empty.xyz");
    std::fs::write(&empty, "").unwrap();
    refused(
        &[
            "--scan",
            s(&empty),
            "--boundary",
            s(&boundary),
            "--pitch",
            "1",
            "--out",
            s(&out),
        ],
        "empty",
    );
}
