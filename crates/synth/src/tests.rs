//! The generator's own tests: determinism, shape, normals, files, the mesh and visibility.

use crate::blockage::Film;
use crate::case::*;
use crate::part::*;
use nalgebra::Matrix3;
use trim_geom::{Point3, Vector3};

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
    // With every effect on: the same seed, the same case.
    let all = |seed| SynthParams {
        scanner_views: 3,
        pressing_tilt_deg: 20.0,
        burr_fraction: 0.3,
        path_spacing_mm: 0.1,
        ..small(seed)
    };
    let (a, b) = (generate(&all(3)).unwrap(), generate(&all(3)).unwrap());
    assert_eq!(a.scan.points(), b.scan.points());
    assert_eq!(
        (&a.views, &a.burrs, &a.truth),
        (&b.views, &b.burrs, &b.truth)
    );
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
    let case = generate(&SynthParams {
        scanner_views: 2,
        burr_fraction: 0.2,
        ..small(6)
    })
    .unwrap();
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
    assert_eq!(info.views, case.views);
    assert_eq!(info.burrs, case.burrs);
}

#[test]
fn mesh_is_closed() {
    let case = generate(&small(1)).unwrap();
    assert_closed(&case.cad_triangles);
}

fn assert_closed(triangles: &[[u32; 3]]) {
    let mut edges = std::collections::HashMap::new();
    for t in triangles {
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
    // No outliers: one could fall on the bottom face's plane.
    let params = SynthParams {
        outlier_fraction: 0.0,
        ..undeformed(5)
    };
    let case = generate(&params).unwrap();
    let (top, bottom) = faces_seen(&case);
    assert!(top > 10_000, "{top} points on the top face");
    assert_eq!(bottom, 0, "{bottom} scan points on the bottom face");
}

/// Domain coordinates `(u, v, w)` of a scan point of an undeformed case (identity deformation):
/// the placement and the design map undone.
fn domain_of(case: &SynthCase, p: &Point3) -> Point3 {
    let q = case.scan_from_cad_true.inverse() * *p;
    let theta_per_mm = DESIGN_TWIST_DEG.to_radians() / LENGTH_MM;
    let (sin, cos) = (theta_per_mm * q.y).sin_cos();
    let u = cos * q.x + sin * q.z;
    let z0 = -sin * q.x + cos * q.z;
    let c = 2.0 * u / WIDTH_MM;
    Point3::new(u, q.y, z0 - CAMBER_MM * (1.0 - c * c))
}

/// Scan points on the top and the bottom face (0.2 mm clear of every edge) of an undeformed case.
fn faces_seen(case: &SynthCase) -> (usize, usize) {
    let all = cutouts();
    let (mut top, mut bottom) = (0, 0);
    for p in case.scan.points() {
        let d = domain_of(case, p);
        let clear = all
            .iter()
            .all(|k| k.distance_to_axis(d.x, d.y) > k.radius_mm + 0.2);
        if clear && d.x.abs() < 19.5 && d.y.abs() < 49.5 {
            if (d.z - THICKNESS_MM / 2.0).abs() < 0.05 {
                top += 1;
            } else if (d.z + THICKNESS_MM / 2.0).abs() < 0.05 {
                bottom += 1;
            }
        }
    }
    (top, bottom)
}

fn undeformed(seed: u64) -> SynthParams {
    SynthParams {
        sag_mm: 0.0,
        twist_deg: 0.0,
        scale_range: 0.0,
        ..small(seed)
    }
}

#[test]
fn views_are_fixed_to_the_machine_not_to_the_part() {
    let params = |pose_deg, pose_mm| SynthParams {
        scanner_views: 4,
        pose_deg,
        pose_mm,
        ..undeformed(8)
    };
    let a = generate(&params(0.0, 0.0)).unwrap();
    let b = generate(&params(20.0, 20.0)).unwrap();
    assert_ne!(a.scan_from_cad_true, b.scan_from_cad_true);
    assert_eq!(a.views, b.views, "the true pose moved the views");
    assert_eq!(a.views.len(), 4);
    assert_eq!(a.scanner_in_scan, a.views[0].scanner_in_scan_mm);
    // Each view: at the scanner distance from the nominal centre, looking at it, at its tilt
    // from the scan frame's ±z (the nominal thickness axis), top and bottom alternating.
    let aim = a.scan_from_cad_nominal * design_point(0.0, 0.0, 0.0);
    for (k, v) in a.views.iter().enumerate() {
        let offset = v.scanner_in_scan_mm - aim;
        assert!((offset.norm() - 300.0).abs() < 1e-9, "{v:?}");
        assert!((offset.normalize() - v.toward_scanner_in_scan).norm() < 1e-12);
        let side = if k % 2 == 0 { 1.0 } else { -1.0 };
        assert_eq!(v.top_side, k % 2 == 0);
        let tilt = (side * v.toward_scanner_in_scan.z).acos().to_degrees();
        assert!((tilt - v.tilt_deg).abs() < 1e-9, "{tilt} vs {v:?}");
        if k == 0 {
            assert_eq!(v.tilt_deg, 25.0);
        } else {
            assert!((10.0..=55.0).contains(&v.tilt_deg), "{v:?}");
        }
    }
    // Given tilts are used.
    let c = generate(&SynthParams {
        view_tilts_deg: vec![40.0, 12.0, 50.0],
        ..params(0.0, 0.0)
    })
    .unwrap();
    let tilts: Vec<f64> = c.views.iter().map(|v| v.tilt_deg).collect();
    assert_eq!(tilts, [25.0, 40.0, 12.0, 50.0]);
    // Both sides are seen with two or more views; the top alone with one.
    let (top, bottom) = faces_seen(&a);
    assert!(top > 3_000 && bottom > 3_000, "{top} top, {bottom} bottom");
    // A large fixture error turns the part under the fixed view: it sees the part from another
    // direction than the nominal one (the part's +z, which the old carried view followed).
    let one = |pose_deg| {
        generate(&SynthParams {
            pose_deg,
            pose_mm: 0.0,
            ..undeformed(8)
        })
        .unwrap()
    };
    let (tilted, level) = (one(20.0), one(0.0));
    assert_eq!(tilted.views, level.views);
    // What the old view, carried by the true pose, would have looked along.
    let carried =
        tilted.scan_from_cad_true.isometry.rotation * level.views[0].toward_scanner_in_scan;
    let moved = carried
        .angle(&tilted.views[0].toward_scanner_in_scan)
        .to_degrees();
    assert!(moved > 1.0, "the view follows the part: {moved}°");
}

#[test]
fn shrinkage_along_tilted_pressing_axes_maps_the_truth() {
    let params = SynthParams {
        scale_range: 0.02,
        pressing_tilt_deg: 30.0,
        ..undeformed(9)
    };
    let case = generate(&params).unwrap();
    let d = case.deformation;
    // The pressing axes: a rotation, tilted 15–30° from the CAD axes.
    let r = Matrix3::from_columns(&d.pressing_axes.map(Vector3::from));
    assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
    assert!((r.determinant() - 1.0).abs() < 1e-12);
    let angle = ((r.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    assert!((15.0 - 1e-9..=30.0 + 1e-9).contains(&angle), "{angle}°");
    // Independent: the scale matrix built from the axes and scales, then the placement.
    let m = r * Matrix3::from_diagonal(&d.scale) * r.transpose();
    let off_diagonal = (m - Matrix3::from_diagonal(&m.diagonal())).amax();
    assert!(off_diagonal > 1e-4, "the tilt does not act: {m}");
    let rotation = case.scan_from_cad_true.isometry.rotation;
    let normal_map = m.try_inverse().unwrap().transpose();
    for (c, t) in case.path.contours().iter().zip(case.truth.contours()) {
        for (k, (p, q)) in c.points().iter().zip(t.points()).enumerate() {
            let expected = case.scan_from_cad_true * Point3::from(m * p.coords);
            assert!((expected - q).norm() < 1e-9, "contour {} point {k}", c.id());
            let n = (rotation * (normal_map * c.features()[k])).normalize();
            assert!(
                (n - t.features()[k]).norm() < 1e-7,
                "contour {} feature {k}: {n} vs {}",
                c.id(),
                t.features()[k]
            );
        }
    }
    // No tilt: the CAD axes exactly, and the same scan as a case without the key.
    let plain = generate(&SynthParams {
        pressing_tilt_deg: 0.0,
        ..params.clone()
    })
    .unwrap();
    assert_eq!(
        plain.deformation.pressing_axes,
        Deformation::identity().pressing_axes
    );
}

#[test]
fn shrinkage_that_changes_along_the_span_maps_the_truth_and_no_affine_map_undoes_it() {
    let g = 0.004;
    let params = SynthParams {
        shrink_gradient: g,
        ..undeformed(9)
    };
    let case = generate(&params).unwrap();
    assert_eq!(case.deformation.shrink_gradient, g);
    // Independent: the local scale 1 + g·y/L integrated along the span, the section scaled by it.
    let grown = |p: &Point3| {
        let k = 1.0 + g * p.y / LENGTH_MM;
        Point3::new(p.x * k, p.y + g * p.y * p.y / (2.0 * LENGTH_MM), p.z * k)
    };
    let mut template = Vec::new();
    let mut truth_cad = Vec::new();
    let cad_from_scan = case.scan_from_cad_true.inverse();
    for (c, t) in case.path.contours().iter().zip(case.truth.contours()) {
        for (k, (p, q)) in c.points().iter().zip(t.points()).enumerate() {
            let expected = case.scan_from_cad_true * grown(p);
            assert!((expected - q).norm() < 1e-9, "contour {} point {k}", c.id());
            template.push(*p);
            truth_cad.push(cad_from_scan * q);
        }
    }
    // The best affine map of the template onto the truth (least squares, per coordinate) leaves
    // the quadratic along the span: g·L/2·(1/4 − 1/12)·… about g·L/12 at the ends.
    let rows =
        nalgebra::DMatrix::from_fn(
            template.len(),
            4,
            |i, j| {
                if j < 3 { template[i][j] } else { 1.0 }
            },
        );
    let svd = rows.clone().svd(true, true);
    let mut worst: f64 = 0.0;
    for axis in 0..3 {
        let b = nalgebra::DVector::from_fn(truth_cad.len(), |i, _| truth_cad[i][axis]);
        let x = svd.solve(&b, 1e-12).unwrap();
        worst = worst.max((&rows * x - b).amax());
    }
    let extent = template.iter().map(|p| p.y.abs()).fold(0.0, f64::max);
    let quadratic = g * extent * extent / (2.0 * LENGTH_MM);
    assert!(
        worst > 0.3 * quadratic && worst > 0.01,
        "an affine map leaves {worst} mm (the span's quadratic is {quadratic} mm)"
    );
    // A case written before the key existed reads as no gradient.
    let mut json = serde_json::to_value(case.deformation).unwrap();
    json.as_object_mut().unwrap().remove("shrink_gradient");
    let old: Deformation = serde_json::from_value(json).unwrap();
    assert_eq!(old.shrink_gradient, 0.0);
}

#[test]
fn burr_points_stand_off_the_true_edges_within_their_size() {
    let params = SynthParams {
        noise_mm: 0.0,
        outlier_fraction: 0.0,
        dropouts: 0,
        burr_fraction: 0.5,
        scanner_views: 2,
        scan_points: 60_000,
        ..undeformed(10)
    };
    let case = generate(&params).unwrap();
    let n_contours = case.path.len();
    let burred: std::collections::BTreeSet<i64> = case.burrs.iter().map(|b| b.contour).collect();
    assert_eq!(burred.len(), n_contours / 2, "{:?}", case.burrs);
    let edges = contour_edges(&cutouts());
    let all = cutouts();
    let top = THICKNESS_MM / 2.0;
    let tol = 1e-6;
    let mut on_burr = vec![0usize; case.burrs.len()];
    for p in case.scan.points() {
        let d = domain_of(&case, p);
        let in_part = d.x.abs() <= WIDTH_MM / 2.0 + tol
            && d.y.abs() <= LENGTH_MM / 2.0 + tol
            && all
                .iter()
                .all(|k| k.distance_to_axis(d.x, d.y) >= k.radius_mm - tol);
        if in_part {
            continue;
        }
        // Out of the material: on a burr's web, within its stretch, height and thickness.
        let hit = case.burrs.iter().position(|b| {
            let edge = &edges[usize::try_from(b.contour - 1).unwrap()];
            let (s, t) = edge.locate(d.x, d.y);
            s >= b.start_mm - tol
                && s <= b.end_mm + tol
                && t >= -tol
                && t <= b.height_mm + tol
                && d.z <= top + tol
                && d.z >= top - b.thickness_mm - tol
        });
        match hit {
            Some(i) => on_burr[i] += 1,
            None => panic!("scan point {p} (domain {d}) is off the part and off every burr"),
        }
    }
    for (b, n) in case.burrs.iter().zip(&on_burr) {
        if (b.end_mm - b.start_mm) * b.height_mm >= 1.0 {
            assert!(*n > 0, "no scan point on {b:?}");
        }
        // The recorded point indices are the contour's points within the stretch.
        let c = case
            .path
            .contours()
            .iter()
            .find(|c| c.id() == b.contour)
            .unwrap();
        assert!(b.first_point <= b.last_point && b.last_point < c.points().len());
        let length = b.end_mm - b.start_mm;
        assert!(length > 0.0 && length <= 15.0 + tol, "{b:?}");
        assert!((0.1..=0.5).contains(&b.height_mm) && (0.02..=0.1).contains(&b.thickness_mm));
    }
    assert!(on_burr.iter().sum::<usize>() > 100, "{on_burr:?}");
    // Without burrs the scan has none (and no extra draws: the same scan as before burrs).
    let clean = generate(&SynthParams {
        burr_fraction: 0.0,
        ..params
    })
    .unwrap();
    assert!(clean.burrs.is_empty());
}

#[test]
fn path_spacing_is_honoured() {
    for spacing in [0.05, 0.25] {
        let case = generate(&SynthParams {
            path_spacing_mm: spacing,
            ..small(11)
        })
        .unwrap();
        let (mut longest, mut total, mut segments) = (0.0f64, 0.0, 0usize);
        for c in case.path.contours() {
            for w in c.points().windows(2) {
                let step = (w[1] - w[0]).norm();
                longest = longest.max(step);
                total += step;
                segments += 1;
            }
        }
        // Spaced in the domain plane; the camber and design twist stretch it by ≤ 4 %.
        assert!(longest <= 1.04 * spacing, "{spacing}: longest {longest}");
        let mean = total / segments as f64;
        assert!(mean >= 0.9 * spacing, "{spacing}: mean {mean}");
        if spacing == 0.05 {
            assert!(
                case.path.points().count() > 18_000,
                "{}",
                case.path.points().count()
            );
        }
    }
}

#[test]
fn the_mesh_step_sets_the_triangle_count_and_stays_closed() {
    // The speed benchmarks' "120k-triangle STL" (measured 121,964) and the default (27,008).
    let fine = generate(&SynthParams {
        mesh_step_mm: 0.35,
        ..small(13)
    })
    .unwrap();
    let n = fine.cad_triangles.len();
    assert!((115_000..=130_000).contains(&n), "{n} triangles");
    assert_closed(&fine.cad_triangles);
    let coarse = crate::mesh::domain_mesh(&cutouts(), 1.0).unwrap();
    assert!(
        (25_000..30_000).contains(&coarse.triangles.len()),
        "{}",
        coarse.triangles.len()
    );
}

#[test]
fn large_fixture_errors_are_accepted() {
    let case = generate(&SynthParams {
        pose_deg: 20.0,
        pose_mm: 20.0,
        ..small(12)
    })
    .unwrap();
    let angle = case
        .scan_from_cad_true
        .isometry
        .rotation
        .angle()
        .to_degrees();
    let shift = case.scan_from_cad_true.isometry.translation.vector.norm();
    assert!((10.0..=20.0 + 1e-9).contains(&angle), "{angle}");
    assert!((10.0..=20.0 + 1e-9).contains(&shift), "{shift}");
}

#[test]
fn validation_names_the_field() {
    let bad: Vec<(&str, SynthParams)> = vec![
        (
            "scanner_views",
            SynthParams {
                scanner_views: 0,
                ..SynthParams::default()
            },
        ),
        (
            "scanner_views",
            SynthParams {
                scanner_views: 5,
                ..SynthParams::default()
            },
        ),
        (
            "view_tilts_deg",
            SynthParams {
                scanner_views: 2,
                view_tilts_deg: vec![10.0, 20.0],
                ..SynthParams::default()
            },
        ),
        (
            "view_tilts_deg",
            SynthParams {
                scanner_views: 2,
                view_tilts_deg: vec![70.0],
                ..SynthParams::default()
            },
        ),
        (
            "scanner_tilt_deg",
            SynthParams {
                scanner_tilt_deg: f64::NAN,
                ..SynthParams::default()
            },
        ),
        (
            "pressing_tilt_deg",
            SynthParams {
                pressing_tilt_deg: 31.0,
                ..SynthParams::default()
            },
        ),
        (
            "pressing_tilt_deg",
            SynthParams {
                pressing_tilt_deg: -1.0,
                ..SynthParams::default()
            },
        ),
        (
            "path_spacing_mm",
            SynthParams {
                path_spacing_mm: 0.04,
                ..SynthParams::default()
            },
        ),
        (
            "path_spacing_mm",
            SynthParams {
                path_spacing_mm: 0.3,
                ..SynthParams::default()
            },
        ),
        (
            "mesh_step_mm",
            SynthParams {
                mesh_step_mm: 0.1,
                ..SynthParams::default()
            },
        ),
        (
            "burr_fraction",
            SynthParams {
                burr_fraction: 1.5,
                ..SynthParams::default()
            },
        ),
        (
            "burr_height_mm",
            SynthParams {
                burr_height_mm: [0.5, 0.1],
                ..SynthParams::default()
            },
        ),
        (
            "burr_thickness_mm",
            SynthParams {
                burr_thickness_mm: [0.02, 1.0],
                ..SynthParams::default()
            },
        ),
        (
            "burr_length_mm",
            SynthParams {
                burr_length_mm: [0.0, 5.0],
                ..SynthParams::default()
            },
        ),
        (
            "pose_deg",
            SynthParams {
                pose_deg: 46.0,
                ..SynthParams::default()
            },
        ),
        (
            "dropouts",
            SynthParams {
                dropouts: 1000,
                ..SynthParams::default()
            },
        ),
        (
            "shrink_gradient",
            SynthParams {
                shrink_gradient: -0.03,
                ..SynthParams::default()
            },
        ),
        (
            "shrink_gradient",
            SynthParams {
                shrink_gradient: f64::NAN,
                ..SynthParams::default()
            },
        ),
    ];
    for (field, params) in bad {
        let e = params.validate().expect_err(field).to_string();
        assert!(e.contains(field), "{field}: {e}");
        assert!(generate(&params).is_err(), "{field}");
    }
    let good = SynthParams {
        scanner_views: 4,
        view_tilts_deg: vec![10.0, 55.0, 30.0],
        pressing_tilt_deg: 30.0,
        scale_range: 0.02,
        path_spacing_mm: 0.05,
        mesh_step_mm: 0.4,
        burr_fraction: 1.0,
        pose_deg: 20.0,
        pose_mm: 20.0,
        ..SynthParams::default()
    };
    good.validate().unwrap();
}

#[test]
fn edges_locate_their_own_points() {
    for edge in contour_edges(&cutouts()) {
        let len = edge.length();
        for k in 0..50 {
            let s = len * (f64::from(k) + 0.5) / 50.0;
            let (e, m) = edge.at(s);
            for t in [-0.3, 0.0, 0.4] {
                let (s2, t2) = edge.locate(e[0] + t * m[0], e[1] + t * m[1]);
                assert!(
                    (s2 - s).abs() < 1e-9 && (t2 - t).abs() < 1e-9,
                    "{edge:?} {s} {t}: {s2} {t2}"
                );
            }
        }
    }
}

#[test]
fn blockage_points_lie_on_their_films_and_the_truth_says_how_much_is_covered() {
    let params = SynthParams {
        noise_mm: 0.0,
        outlier_fraction: 0.0,
        dropouts: 0,
        blockage_fraction: 0.25,
        scanner_views: 2,
        scan_points: 60_000,
        ..undeformed(12)
    };
    let case = generate(&params).unwrap();
    let all = cutouts();
    assert_eq!(
        case.blockages.len(),
        (0.25 * all.len() as f64).round() as usize
    );
    let top = THICKNESS_MM / 2.0;
    let tol = 1e-6;
    let mut on_film = vec![0usize; case.blockages.len()];
    for p in case.scan.points() {
        let d = domain_of(&case, p);
        let in_part = d.x.abs() <= WIDTH_MM / 2.0 + tol
            && d.y.abs() <= LENGTH_MM / 2.0 + tol
            && all
                .iter()
                .all(|k| k.distance_to_axis(d.x, d.y) >= k.radius_mm - tol);
        if in_part {
            continue;
        }
        let hit = case.blockages.iter().position(|b| {
            let c = &all[usize::try_from(b.contour - 1).unwrap()];
            let proj = (d.x - c.u_mm) * b.direction[0] + (d.y - c.v_mm) * b.direction[1];
            c.distance_to_axis(d.x, d.y) <= c.radius_mm + tol
                && proj <= b.offset_mm + 1e-6
                && d.z <= top + tol
                && d.z >= top - b.thickness_mm - tol
        });
        match hit {
            Some(i) => on_film[i] += 1,
            None => panic!("scan point {p} (domain {d}) is off the part and off every film"),
        }
    }
    for (b, n) in case.blockages.iter().zip(&on_film) {
        assert!(*n > 10, "few scan points on {b:?}: {n}");
        assert!((0.3..=1.0).contains(&b.covered_share), "{b:?}");
        assert!((0.05..=0.2).contains(&b.thickness_mm), "{b:?}");
        // The covered share is the film's area over the opening's, checked on a finer grid.
        let c = &all[usize::try_from(b.contour - 1).unwrap()];
        let (mut inside, mut covered) = (0usize, 0usize);
        let (hu, hv) = (c.radius_mm, c.radius_mm + c.half_length_mm);
        for i in 0..300 {
            for j in 0..300 {
                let u = c.u_mm - hu + 2.0 * hu * (f64::from(i) + 0.25) / 300.0;
                let v = c.v_mm - hv + 2.0 * hv * (f64::from(j) + 0.25) / 300.0;
                if c.contains(u, v) {
                    inside += 1;
                    covered += usize::from(b.covers(c, u, v));
                }
            }
        }
        let share = covered as f64 / inside as f64;
        assert!((share - b.covered_share).abs() < 0.01, "{share} {b:?}");
    }
    // The truth reads back from case.json; without blockages the key is not written at all.
    let dir = tempfile::tempdir().unwrap();
    case.write_case(dir.path()).unwrap();
    let text = std::fs::read_to_string(dir.path().join("case.json")).unwrap();
    let info: CaseInfo = serde_json::from_str(&text).unwrap();
    assert_eq!(info.blockages, case.blockages);
    assert_eq!(info.params, case.params);
    let clean = generate(&small(12)).unwrap();
    clean.write_case(dir.path()).unwrap();
    let text = std::fs::read_to_string(dir.path().join("case.json")).unwrap();
    assert!(!text.contains("blockage"), "{text}");
}

#[test]
fn a_film_scans_only_where_it_stands_thinned_where_cut_and_untouched_as_before() {
    let params = SynthParams {
        noise_mm: 0.0,
        outlier_fraction: 0.0,
        dropouts: 0,
        blockage_fraction: 0.25,
        blockage_share: [1.0, 1.0],
        scanner_views: 2,
        scan_points: 60_000,
        ..undeformed(12)
    };
    let case = generate(&params).unwrap();
    // Untouched films scan with the draws of the blockages they are.
    let films = Film::of(&case.blockages);
    assert_eq!(films.len(), case.blockages.len());
    assert_eq!(
        case.rescan_films(&case.burrs, &films, 5).unwrap().points(),
        case.rescan(&case.burrs, &case.blockages, 5)
            .unwrap()
            .points()
    );
    assert!(films.iter().all(|f| f.standing_share() == 1.0));
    // The first film: its u < centre half cleared through, its other half thinned by a third.
    let mut films = films;
    let f = &mut films[0];
    let c = cutouts()[usize::try_from(f.contour() - 1).unwrap()];
    let t = f.blockage.thickness_mm;
    let (cols, rows) = f.grid();
    for j in 0..rows {
        for i in 0..cols {
            let [u, _] = f.cell_centre(i, j);
            f.remove(i, j, if u < c.u_mm { t } else { t / 3.0 });
        }
    }
    assert!(
        (f.standing_share() - 0.5).abs() < 0.02,
        "{}",
        f.standing_share()
    );
    assert!((f.covered_share() - 0.5 * f.blockage.covered_share).abs() < 0.02);
    assert!(f.remaining_at(c.u_mm - 0.5, c.v_mm) == 0.0);
    assert!((f.remaining_at(c.u_mm + 0.5, c.v_mm) - 2.0 * t / 3.0).abs() < 1e-12);
    // Out of the grid or outside the opening: nothing stands, nothing is removed.
    assert_eq!(f.remaining_at(c.u_mm + 10.0, c.v_mm), 0.0);
    assert_eq!(f.removed_at(c.u_mm + 10.0, c.v_mm), 0.0);
    let (is, js) = f.cells_in([c.u_mm - 0.05, c.u_mm + 0.05], [c.v_mm, c.v_mm + 0.02]);
    assert_eq!((is.len(), js.len()), (10, 2), "{is:?} {js:?}");
    let (is, _) = f.cells_in([c.u_mm + 50.0, c.u_mm + 51.0], [c.v_mm, c.v_mm]);
    assert!(is.is_empty());
    let rescan = case.rescan_films(&case.burrs, &films, 5).unwrap();
    let top = THICKNESS_MM / 2.0;
    let (mut cleared_side, mut upper, mut thinned_upper) = (0usize, 0usize, 0usize);
    for p in rescan.points() {
        let d = domain_of(&case, p);
        if c.distance_to_axis(d.x, d.y) > c.radius_mm - 1e-3 {
            continue;
        }
        if d.x < c.u_mm - 1e-6 {
            cleared_side += 1;
        } else if (d.z - (top - t / 3.0)).abs() < 1e-6 {
            thinned_upper += 1;
        } else if (d.z - top).abs() < 1e-6 {
            upper += 1;
        }
    }
    assert_eq!(cleared_side, 0, "points scanned where the film is cleared");
    assert!(thinned_upper > 10, "{thinned_upper}");
    assert_eq!(upper, 0, "the thinned half's top is lower");
}

#[test]
fn blockage_parameters_are_validated_by_name() {
    for (params, key) in [
        (
            SynthParams {
                blockage_fraction: -0.1,
                ..small(1)
            },
            "blockage_fraction",
        ),
        (
            SynthParams {
                blockage_thickness_mm: [0.2, 0.05],
                ..small(1)
            },
            "blockage_thickness_mm",
        ),
        (
            SynthParams {
                blockage_share: [0.0, 1.0],
                ..small(1)
            },
            "blockage_share",
        ),
    ] {
        let e = params.validate().unwrap_err().to_string();
        assert!(e.contains(key), "{e}");
    }
}
