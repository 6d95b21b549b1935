//! `trimctl info` on good and bad files, through the built binary.
#![expect(
    clippy::unwrap_used,
    reason = "fixture helpers: a fixture that fails to build is a failed test"
)]

use std::path::{Path as FsPath, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;
use trim_geom::formats::{self, PcdEncoding, PlyEncoding};
use trim_geom::mesh::Mesh;
use trim_geom::{Contour, Path, Point3, PointCloud, Vector3};

fn trimctl_info(file: &FsPath) -> Output {
    Command::new(env!("CARGO_BIN_EXE_trimctl"))
        .arg("info")
        .arg(file)
        .output()
        .unwrap()
}

/// Runs `trimctl info` on a good file: exit 0, one JSON object on stdout.
fn info_ok(file: &FsPath) -> Value {
    let out = trimctl_info(file);
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        out.status.success(),
        "{}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    serde_json::from_str(&stdout).unwrap()
}

/// Runs `trimctl info` on a bad file: exit 1, nothing on stdout, one line on stderr.
fn info_err(file: &FsPath) -> String {
    let out = trimctl_info(file);
    assert_eq!(out.status.code(), Some(1), "{}", file.display());
    assert!(out.stdout.is_empty());
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    stderr
}

/// A file of the repository's real test data (tests/data).
fn test_data(rel: &str) -> PathBuf {
    FsPath::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(rel)
}

fn cloud() -> PointCloud {
    PointCloud::with_normals(
        vec![Point3::new(-1.0, 2.0, 3.5), Point3::new(4.0, -5.0, 0.25)],
        vec![Vector3::z(), Vector3::x()],
    )
    .unwrap()
}

#[test]
fn describes_points_meshes_and_paths() {
    let dir = tempfile::tempdir().unwrap();
    let c = cloud();
    let cases = [
        ("c.ply", PlyEncoding::BinaryBigEndian),
        ("c_ascii.ply", PlyEncoding::Ascii),
    ];
    for (name, encoding) in cases {
        let file = dir.path().join(name);
        formats::write_ply(&file, &c, encoding).unwrap();
        let v = info_ok(&file);
        assert_eq!(v["kind"], "points");
        assert_eq!(v["points"], 2);
        assert_eq!(v["has_normals"], true);
        assert_eq!(v["bounds_min"], serde_json::json!([-1.0, -5.0, 0.25]));
        assert_eq!(v["bounds_max"], serde_json::json!([4.0, 2.0, 3.5]));
    }
    let pcd = dir.path().join("c.pcd");
    formats::write_pcd(&pcd, &c, PcdEncoding::Binary).unwrap();
    assert_eq!(info_ok(&pcd)["points"], 2);
    let mut plain = c.clone();
    plain.clear_normals();
    let xyz = dir.path().join("c.xyz");
    formats::write_xyz(&xyz, &plain).unwrap();
    assert_eq!(info_ok(&xyz)["has_normals"], false);

    let mesh = Mesh::new(
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(0.0, 2.0, 0.0),
        ],
        vec![[0, 1, 2]],
    )
    .unwrap();
    let stl = dir.path().join("m.stl");
    formats::write_stl(&stl, &mesh).unwrap();
    let v = info_ok(&stl);
    assert_eq!(v["kind"], "mesh");
    assert_eq!(v["points"], 3);
    assert_eq!(v["triangles"], 1);
    assert_eq!(v["area_mm2"], 2.0);
    assert_eq!(v["bounds_max"], serde_json::json!([2.0, 2.0, 0.0]));

    let ply_mesh = dir.path().join("m.ply");
    std::fs::write(
        &ply_mesh,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
         property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    )
    .unwrap();
    assert_eq!(info_ok(&ply_mesh)["kind"], "mesh");

    let path = Path::new(vec![
        Contour::new(
            1,
            vec![Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)],
            Vector3::z(),
        )
        .unwrap(),
        Contour::new(
            2,
            vec![
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(1.0, 1.0, 0.0),
                Point3::new(1.0, 2.0, -1.0),
            ],
            Vector3::z(),
        )
        .unwrap(),
    ])
    .unwrap();
    let csv = dir.path().join("p.csv");
    formats::write_path(&csv, &path).unwrap();
    let v = info_ok(&csv);
    assert_eq!(v["kind"], "path");
    assert_eq!(v["points"], 5);
    assert_eq!(v["contours"], 2);
    assert_eq!(v["bounds_min"], serde_json::json!([0.0, 0.0, -1.0]));
}

#[test]
fn describes_the_real_test_data() {
    let v = info_ok(&test_data("bunny/bun0.pcd"));
    assert_eq!(v["points"], 397);
    assert_eq!(v["has_normals"], true);
    let v = info_ok(&test_data("lidar-pair/target.ply"));
    assert_eq!(v["kind"], "points");
    assert_eq!(v["points"], 69_088);
}

#[test]
fn refuses_bad_files_with_one_line_naming_the_place() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("cut.ply");
    let bytes = formats::encode_ply(
        &cloud(),
        PlyEncoding::BinaryLittleEndian,
        formats::PlyScalar::Double,
    );
    std::fs::write(&ply, &bytes[..bytes.len() - 8]).unwrap();
    let e = info_err(&ply);
    assert!(e.contains("cut.ply: element 1: truncated"), "{e}");

    let csv = dir.path().join("bad.csv");
    std::fs::write(
        &csv,
        "contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,0,abc,0,0,0,1\n",
    )
    .unwrap();
    let e = info_err(&csv);
    assert!(e.contains("bad.csv: line 3: column y"), "{e}");

    let one = dir.path().join("one.csv");
    std::fs::write(&one, "contour,x,y,z,u,v,w\n4,0,0,0,0,0,1\n").unwrap();
    let e = info_err(&one);
    assert!(e.contains("one.csv: line 2: contour 4"), "{e}");

    let nan = dir.path().join("nan.xyz");
    std::fs::write(&nan, "1 2 3\nnan 2 3\n").unwrap();
    assert!(info_err(&nan).contains("nan.xyz: line 2: x: NaN is not finite"));

    let obj = dir.path().join("part.obj");
    std::fs::write(&obj, "v 0 0 0\n").unwrap();
    assert!(info_err(&obj).contains("unknown extension .obj"));

    assert!(info_err(&dir.path().join("missing.ply")).contains("missing.ply"));
}

#[test]
fn a_point_file_with_no_points_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let empty = PointCloud::default();
    let files = [
        ("empty.xyz", Vec::new()),
        ("blank.xyz", b"\n  \n".to_vec()),
        (
            "empty.ply",
            formats::encode_ply(&empty, PlyEncoding::Ascii, formats::PlyScalar::Double),
        ),
        (
            "empty_binary.ply",
            formats::encode_ply(
                &empty,
                PlyEncoding::BinaryLittleEndian,
                formats::PlyScalar::Float,
            ),
        ),
        ("empty.pcd", formats::encode_pcd(&empty, PcdEncoding::Ascii)),
        (
            "empty_binary.pcd",
            formats::encode_pcd(&empty, PcdEncoding::Binary),
        ),
    ];
    for (name, bytes) in files {
        let file = dir.path().join(name);
        std::fs::write(&file, bytes).unwrap();
        let e = info_err(&file);
        assert!(e.contains(&format!("{name}: no points")), "{name}: {e}");
        // Everything else that needs points refuses it the same way.
        let e = formats::read_points(&file).unwrap_err().to_string();
        assert!(e.ends_with(&format!("{name}: no points")), "{name}: {e}");
    }
    // `trimctl register` with an empty scan stops before registering, naming the file.
    let scan = dir.path().join("empty.xyz");
    let out = Command::new(env!("CARGO_BIN_EXE_trimctl"))
        .args(["register", "--cad"])
        .arg(dir.path().join("empty.ply"))
        .arg("--scan")
        .arg(&scan)
        .arg("--path")
        .arg(dir.path().join("none.csv"))
        .arg("--out")
        .arg(dir.path().join("out.csv"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains(": no points"), "{stderr}");
}

#[test]
fn a_path_cut_inside_its_last_number_reads_with_a_warning_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("path.csv");
    // The last row's w was 1.25 when the copy was cut.
    std::fs::write(&file, "contour,x,y,z,u,v,w\n3,0,0,0,0,0,1\n3,1,0,0,0,0,1.2").unwrap();
    let out = trimctl_info(&file);
    assert!(out.status.success());
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(
        stderr.contains("WARN")
            && stderr.contains("path.csv: line 3, the last, has no line end")
            && stderr.contains("its last value may be short (\"3,1,0,0,0,0,1.2\")"),
        "{stderr}"
    );
    assert!(!out.stdout.is_empty());
}
