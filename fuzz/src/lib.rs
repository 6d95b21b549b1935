//! What every fuzz target checks, beyond "no panic, no abort, no runaway allocation":
//! - an error names the file it was given;
//! - a cloud that was read writes to binary PLY and reads back identical (the reader returned
//!   only finite values, and the writer and reader agree);
//! - a mesh that was read has a finite positive area, encodes to STL, samples with unit normals
//!   and answers distance queries;
//! - a path that was read writes and reads back with the same points.

use std::path::Path as FsPath;

use trim_geom::formats::{self, PlyEncoding, PlyScalar};

/// Panics (a finding) when an error does not start with the file name.
fn check_error(e: &trim_geom::GeomError, name: &FsPath) {
    let message = e.to_string();
    assert!(
        message.starts_with(&name.display().to_string()),
        "an error that does not name the file: {message}"
    );
    assert!(!message.contains('\n'), "a multi-line error: {message}");
}

/// Reads `data` as a point cloud named `name` and checks the result.
pub fn check_points(data: &[u8], name: &str) {
    let name = FsPath::new(name);
    match formats::read_points_from_bytes(data, name) {
        Ok(cloud) => {
            let bytes =
                formats::encode_ply(&cloud, PlyEncoding::BinaryLittleEndian, PlyScalar::Double);
            let back = formats::read_points_from_bytes(&bytes, FsPath::new("again.ply"))
                .expect("a cloud that was read must write and read back");
            assert_eq!(back.points(), cloud.points());
            assert_eq!(back.has_normals(), cloud.has_normals());
        }
        Err(e) => check_error(&e, name),
    }
}

/// Reads `data` as a mesh named `name` and checks the result.
pub fn check_mesh(data: &[u8], name: &str) {
    let name = FsPath::new(name);
    match formats::read_mesh_from_bytes(data, name) {
        Ok(mesh) => {
            assert!(mesh.area().is_finite() && mesh.area() > 0.0);
            let bytes = formats::encode_stl(&mesh).expect("fewer than 2^32 triangles");
            assert_eq!(bytes.len(), 84 + 50 * mesh.triangles().len());
            // Sampling and distance queries on whatever the parser accepted must not panic
            // either, and sampled normals are unit.
            let samples = mesh.sample_area_weighted(8, 0);
            for n in samples.normals().expect("samples carry normals") {
                assert!((n.norm() - 1.0).abs() < 1e-9, "normal {n}");
            }
            let b = mesh.bounds();
            let d = mesh.distance(&b.center());
            assert!(d.is_finite() && d >= 0.0, "distance {d}");
        }
        Err(e) => check_error(&e, name),
    }
}

/// Reads `data` as a path CSV named `name` and checks the result.
pub fn check_path(data: &[u8], name: &str) {
    let name = FsPath::new(name);
    match formats::read_path_from_bytes(data, name) {
        Ok(path) => {
            let bytes = formats::encode_path(&path);
            let back = formats::read_path_from_bytes(&bytes, FsPath::new("again.csv"))
                .expect("a path that was read must write and read back");
            assert_eq!(back.len(), path.len());
            assert_eq!(back.num_points(), path.num_points());
            for (a, b) in back.contours().iter().zip(path.contours()) {
                assert_eq!(a.points(), b.points());
            }
        }
        Err(e) => check_error(&e, name),
    }
}
