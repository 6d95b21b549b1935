//! The generator's own tests: determinism, shape, normals, files, the mesh and visibility.

use crate::case::*;
use crate::part::*;

fn small(seed: u64) -> SynthParams {
    SynthParams {
        seed,
        scan_points: 20_000,
        cad_points: 20_000,
        ..SynthParams::default()
    }
}

#[test]
fn is_deterministic_in_the_seed() {
    let a = generate(&small(3)).unwrap();
    let b = generate(&small(3)).unwrap();
    let c = generate(&small(4)).unwrap();
    assert_eq!(a.scan.points(), b.scan.points());
    assert_ne!(a.scan.points(), c.scan.points());
}

#[test]
fn has_the_advertised_shape() {
    let case = generate(&small(1)).unwrap();
    assert!((50..=60).contains(&case.path.len()), "{}", case.path.len());
    assert_eq!(case.truth.len(), case.path.len());
    // Outliers: 1 % of the inliers (within rounding).
    let n = case.scan.len();
    assert!(n > 19_000 && n < 20_300, "{n}");
    // CAD points lie on the mesh surface: every mesh vertex has a CAD point within 0.5 mm.
    let b = case.cad_points.bounds().unwrap();
    assert!((b.extent().y - LENGTH_MM).abs() < 0.5, "{b:?}");
    // Truth is the template under the true map.
    let p = case.path.contours()[0].points()[3];
    let t = case.truth.contours()[0].points()[3];
    assert!((case.scan_from_cad_point(&p) - t).norm() < 1e-12);
    // The slot rims are 40–55 mm long straight-ish contours: their perimeter ≥ 80 mm.
    assert!(case.path.contours()[1].length() > 100.0);
}

#[test]
fn cad_normals_point_out_of_the_material() {
    let case = generate(&small(2)).unwrap();
    // A point pushed along its normal leaves the part: it is farther from the mid-surface
    // for top and bottom samples, or outside the footprint for wall samples. Check top ones:
    // their normals have a positive z after the design twist (≤ 6°) and camber (≤ 15°).
    let ns = case.cad_points.normals().unwrap();
    let ups = ns.iter().filter(|n| n.z > 0.9).count();
    let downs = ns.iter().filter(|n| n.z < -0.9).count();
    let ratio = ups as f64 / downs as f64;
    assert!((ratio - 1.0).abs() < 0.05, "{ups} up, {downs} down");
}

#[test]
fn writes_a_case_that_reads_back() {
    let case = generate(&small(6)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    case.write_case(dir.path()).unwrap();
    let scan = trim_geom::formats::read_points(&dir.path().join("scan.ply")).unwrap();
    assert_eq!(scan.len(), case.scan.len());
    let truth = trim_geom::formats::read_path(&dir.path().join("truth.csv")).unwrap();
    assert_eq!(truth.len(), case.truth.len());
    let mesh = trim_geom::formats::read_mesh(&dir.path().join("cad.stl")).unwrap();
    assert_eq!(mesh.triangles().len(), case.cad_triangles.len());
    let info: CaseInfo =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("case.json")).unwrap())
            .unwrap();
    assert_eq!(info.params, case.params);
}

#[test]
fn mesh_is_closed() {
    let case = generate(&small(1)).unwrap();
    let mut edges = std::collections::HashMap::new();
    for t in &case.cad_triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a, b)).or_insert(0i32) += 1;
        }
    }
    // Every directed edge has exactly one opposite: closed and consistently oriented.
    for (&(a, b), &count) in &edges {
        assert_eq!(count, 1, "edge {a}-{b} used {count} times");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
    }
}

#[test]
fn scan_sees_the_top_and_not_the_bottom() {
    let params = SynthParams {
        sag_mm: 0.0,
        twist_deg: 0.0,
        scale_range: 0.0,
        ..small(5)
    };
    let case = generate(&params).unwrap();
    let cad_from_scan = case.scan_from_cad_true.inverse();
    let theta_per_mm = DESIGN_TWIST_DEG.to_radians() / LENGTH_MM;
    let all = cutouts();
    let (mut top, mut bottom) = (0, 0);
    for p in case.scan.points() {
        // Undo the (identity) deformation and the design map: back to (u, v, w).
        let q = cad_from_scan * *p;
        let (sin, cos) = (theta_per_mm * q.y).sin_cos();
        let u = cos * q.x + sin * q.z;
        let z0 = -sin * q.x + cos * q.z;
        let c = 2.0 * u / WIDTH_MM;
        let w = z0 - CAMBER_MM * (1.0 - c * c);
        let clear = all
            .iter()
            .all(|k| k.distance_to_axis(u, q.y) > k.radius_mm + 0.2);
        if clear && u.abs() < 19.5 && q.y.abs() < 49.5 {
            if (w - THICKNESS_MM / 2.0).abs() < 0.05 {
                top += 1;
            } else if (w + THICKNESS_MM / 2.0).abs() < 0.05 {
                bottom += 1;
            }
        }
    }
    assert!(top > 10_000, "{top} points on the top face");
    assert_eq!(bottom, 0, "{bottom} scan points on the bottom face");
}
