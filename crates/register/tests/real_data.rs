//! Registration on peers' real test data (tests/data, see each folder's README).

use std::path::PathBuf;

use nalgebra::Matrix4;
use trim_geom::formats::read_points;
use trim_geom::normals::{Orientation, estimate_normals};
use trim_geom::transform::{rotation_angle_between, similarity_from_matrix, translation_distance};
use trim_geom::voxel::voxel_downsample;
use trim_geom::{Point3, PointCloud, Similarity3};
use trim_register::RobustKernel;
use trim_register::icp::{IcpMethod, IcpSettings, IcpTarget, icp};
use trim_register::umeyama::umeyama;

fn data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(rel)
}

/// PCL's test accepts each entry within 1e-3 and (0,1) within 1e-2 (README); it does not say
/// why, and a 1e-2 slack on a 0.036 entry would let a visibly different rotation pass. The matrix
/// is printed to four decimals (rounding ≤ 5e-5 per entry) and Open3D matches it to four
/// decimals; trimctl's result differs by at most 4.4e-5 (entry (2,2)) and 7.7e-7 at (0,1). So
/// every entry is held to the printed precision.
const PCL_MATRIX_TOL: f64 = 1e-4;

/// PCL's `IterativeClosestPoint` settings (README): point-to-point from the identity, at most 50
/// iterations, correspondences within 0.05, transformation epsilon 1e-8.
fn pcl_settings(method: IcpMethod) -> IcpSettings {
    IcpSettings {
        method,
        with_scale: false,
        max_correspondence_distance_mm: 0.05,
        max_iterations: 50,
        translation_epsilon_mm: 1e-4, // √1e-8: PCL compares the squared translation.
        rotation_epsilon_rad: 1e-6,
        ..IcpSettings::default()
    }
}

#[test]
fn bunny_point_to_point_gives_pcls_matrix() {
    let source = read_points(&data("bunny/bun0.pcd")).unwrap();
    let target = read_points(&data("bunny/bun4.pcd")).unwrap();
    assert_eq!((source.len(), target.len()), (397, 361));
    let target = IcpTarget::new(target).unwrap();
    let r = icp(
        &source,
        &target,
        &Similarity3::identity(),
        &pcl_settings(IcpMethod::PointToPoint),
    )
    .unwrap();
    let expected = Matrix4::new(
        0.8806, 0.03648, -0.4724, 0.03453, //
        -0.02354, 0.9992, 0.03326, -0.001519, //
        0.4732, -0.01817, 0.8808, 0.04116, //
        0.0, 0.0, 0.0, 1.0,
    );
    let got = r.target_from_source.to_homogeneous();
    for i in 0..4 {
        for j in 0..4 {
            assert!(
                (got[(i, j)] - expected[(i, j)]).abs() < PCL_MATRIX_TOL,
                "entry ({i},{j}): got {} expected {}\n{got}",
                got[(i, j)],
                expected[(i, j)]
            );
        }
    }
}

#[test]
fn bunny_point_to_plane_converges() {
    let source = read_points(&data("bunny/bun0.pcd")).unwrap();
    let target = read_points(&data("bunny/bun4.pcd")).unwrap();
    // Normals from 10 neighbours (PCL's test), oriented toward the scanner at the origin.
    let normals = estimate_normals(
        target.points(),
        10,
        Orientation::TowardViewpoint(Point3::origin()),
    )
    .unwrap();
    let target = PointCloud::with_normals(target.points().to_vec(), normals).unwrap();
    let target = IcpTarget::new(target).unwrap();
    let r = icp(
        &source,
        &target,
        &Similarity3::identity(),
        &pcl_settings(IcpMethod::PointToPlane),
    )
    .unwrap();
    assert!(r.converged, "{r:?}");
    assert!(r.mean_squared_distance_mm2 < 1e-3, "{r:?}");
    // And it lands in the same basin as point-to-point: the two metrics weigh the partial
    // overlap differently (they end 2.9° apart), so the check is 1 cm and 0.1 rad (5.7°); a
    // wrong minimum on the bunny is tens of degrees away.
    let p2p = icp(
        &source,
        &target,
        &Similarity3::identity(),
        &pcl_settings(IcpMethod::PointToPoint),
    )
    .unwrap();
    assert!(translation_distance(&r.target_from_source, &p2p.target_from_source) < 0.01);
    let angle = rotation_angle_between(&r.target_from_source, &p2p.target_from_source);
    assert!(angle < 0.1, "{angle} rad apart; {r:?}");
}

/// Reads libpointmatcher's CSV (`x,y,z,nx,ny,nz` header, " , " separators).
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a malformed data file must fail the test"
)]
fn read_car(name: &str) -> PointCloud {
    let text = std::fs::read_to_string(data(name)).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    assert_eq!(header, ["x", "y", "z", "nx", "ny", "nz"]);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: Vec<f64> = line
            .split(',')
            .map(|s| {
                s.trim()
                    .parse::<f64>()
                    .unwrap_or_else(|e| panic!("line {}: {e}", i + 2))
            })
            .collect();
        assert_eq!(v.len(), 6, "line {}", i + 2);
        points.push(Point3::new(v[0], v[1], v[2]));
        normals.push(nalgebra::Vector3::new(v[3], v[4], v[5]));
    }
    PointCloud::with_normals(points, normals).unwrap()
}

#[test]
fn car_umeyama_on_row_pairs_recovers_the_scale_to_1e9() {
    let a = read_car("car-similarity/car_cloud400.csv");
    let b = read_car("car-similarity/car_cloud400_scaled.csv");
    assert_eq!(a.len(), 24_989);
    let fit = umeyama(a.points(), b.points(), true).unwrap();
    assert!(
        (fit.target_from_source.scaling() - 1.04).abs() < 1e-9,
        "{}",
        fit.target_from_source.scaling()
    );
    assert!(fit.rms_mm < 1e-9, "{}", fit.rms_mm);
    let angle = fit
        .target_from_source
        .isometry
        .rotation
        .angle()
        .to_degrees();
    assert!((angle - 11.46).abs() < 0.01, "{angle}");
    let t = fit.target_from_source.isometry.translation.vector;
    assert!(
        (t - nalgebra::Vector3::new(2.0, 2.0, 2.0)).norm() < 1e-9,
        "{t}"
    );
}

#[test]
fn car_scaled_icp_recovers_the_scale_to_1e3() {
    let a = read_car("car-similarity/car_cloud400.csv");
    let b = read_car("car-similarity/car_cloud400_scaled.csv");
    // No pairing: scaled point-to-plane ICP from the translation-only initial guess that a
    // centroid alignment gives (as libpointmatcher's test starts near the answer).
    let ca = centroid(a.points());
    let cb = centroid(b.points());
    let initial = Similarity3::from_parts(
        nalgebra::Translation3::from(cb - ca),
        nalgebra::UnitQuaternion::identity(),
        1.0,
    );
    let extent = b.bounds().unwrap().diagonal();
    let target = IcpTarget::new(b).unwrap();
    let settings = IcpSettings {
        method: IcpMethod::PointToPlane,
        with_scale: true,
        max_correspondence_distance_mm: 0.5 * extent,
        max_iterations: 100,
        translation_epsilon_mm: 1e-9 * extent,
        rotation_epsilon_rad: 1e-9,
        ..IcpSettings::default()
    };
    let r = icp(&a, &target, &initial, &settings).unwrap();
    assert!((r.scale - 1.04).abs() < 1e-3, "{r:?}");
}

fn centroid(points: &[Point3]) -> nalgebra::Vector3<f64> {
    points
        .iter()
        .map(|p| p.coords)
        .sum::<nalgebra::Vector3<f64>>()
        / points.len() as f64
}

#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a malformed data file must fail the test"
)]
fn read_matrix(name: &str) -> Matrix4<f64> {
    let text = std::fs::read_to_string(data(name)).unwrap();
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    assert_eq!(v.len(), 16);
    Matrix4::from_row_slice(&v)
}

#[test]
fn lidar_pair_point_to_plane_meets_small_gicps_python_tolerance() {
    let source = read_points(&data("lidar-pair/source.ply")).unwrap();
    let target = read_points(&data("lidar-pair/target.ply")).unwrap();
    let truth = similarity_from_matrix(&read_matrix("lidar-pair/T_target_source.txt")).unwrap();
    // small_gicp's own test set-up: 0.25 m voxels, normals from 10 neighbours (the LiDAR sits
    // at the origin), correspondences within 1 m, from the identity.
    let source = voxel_downsample(&source, 0.25).unwrap();
    let target = voxel_downsample(&target, 0.25).unwrap();
    let normals = estimate_normals(
        target.points(),
        10,
        Orientation::TowardViewpoint(Point3::origin()),
    )
    .unwrap();
    let target =
        IcpTarget::new(PointCloud::with_normals(target.points().to_vec(), normals).unwrap())
            .unwrap();
    let settings = IcpSettings {
        method: IcpMethod::PointToPlane,
        max_correspondence_distance_mm: 1.0,
        max_iterations: 50,
        translation_epsilon_mm: 1e-4,
        rotation_epsilon_rad: 1e-5,
        kernel: RobustKernel::Huber { k_mm: 0.1 },
        ..IcpSettings::default()
    };
    let r = icp(&source, &target, &Similarity3::identity(), &settings).unwrap();
    let dr = rotation_angle_between(&r.target_from_source, &truth);
    let dt = translation_distance(&r.target_from_source, &truth);
    // small_gicp's Python tolerance: 0.05 rad and 0.05 m (its C++ one: 2.5° and 0.2 m).
    assert!(
        dr < 0.05 && dt < 0.05,
        "rotation error {dr} rad, translation error {dt} m"
    );
}
